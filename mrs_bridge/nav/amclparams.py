"""The parameters of the AMCL filter (:mod:`mrs_bridge.nav.amcl`): Player's ``amcl`` names and
defaults, checked once.

:class:`AmclParams` holds Player's ``amcl`` driver options (Player manual, "amcl") in SI units;
its ``__post_init__`` checks every value (whole numbers, positive, in [0, 1], lists of numbers) and
the pairs that must be ordered, each failure a ``ValueError`` naming the key, the value and an
example. :meth:`AmclParams.from_dict` answers an unknown key with "did you mean" and a Player key
that is no filter parameter here with where its meaning went.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from ..params import unknown_key

__all__ = ["AmclParams"]


# Player amcl keys that are not filter parameters, with where their meaning went.
_MOVED_KEYS = {
    "odom_drift": "Player 1.x's drift matrix; set odom_alpha1..odom_alpha4 instead",
    "laser_pose": "the sensor pose comes with each scan (Amcl.sensor's beam origins and bearings)",
    "laser_range_max": "range_max comes with each scan (Amcl.sensor)",
    "laser_range_var": "set laser_sigma_hit, the standard deviation of a hit in metres",
    "laser_range_bad": "set laser_z_rand, the weight of random readings",
}


@dataclass
class AmclParams:
    """Filter parameters with Player's ``amcl`` names and defaults; SI units (m, rad)."""

    pf_min_samples: int = 100
    pf_max_samples: int = 10000
    pf_err: float = 0.01  # KLD bound on the histogram error
    pf_z: float = 3.0  # upper standard normal quantile of the bound's confidence
    odom_alpha1: float = 0.2  # rotation noise from rotation
    odom_alpha2: float = 0.2  # rotation noise from translation
    odom_alpha3: float = 0.2  # translation noise from translation
    odom_alpha4: float = 0.2  # translation noise from rotation
    laser_max_beams: int = 30
    laser_z_hit: float = 0.95
    laser_z_rand: float = 0.05
    laser_sigma_hit: float = 0.2  # m
    laser_likelihood_max_dist: float = 2.0  # m, cap of the distance field
    update_thresh: tuple[float, float] = (0.2, math.radians(30.0))  # m, rad of odometry between updates
    resample_interval: int = 2  # sensor updates between resamplings
    recover_alpha_slow: float = 0.001
    recover_alpha_fast: float = 0.1
    init_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m, m, rad
    init_pose_var: tuple[float, float, float] = (1.0, 1.0, (math.pi / 6) ** 2)  # m^2, m^2, rad^2
    seed: int | None = None
    # Not a Player parameter: adaptive tempering of the scan likelihood (nav.amcl's docstring); 0 = off.
    pf_temper_ess: float = 0.5
    # Not a Player parameter: the distance filter (nav.distfilter); a laser reading this many metres
    # shorter than the map predicts at the estimate is left out; 0 = off (Player's behaviour).
    laser_unmodeled_margin: float = 0.0  # m
    # Not a Player parameter: how readings a declared neighbour explains count (nav.landmarks). 0 =
    # left out (nav.knownobstacles); > 0 = scored against the neighbour's body as a landmark, this
    # many metres of standard deviation added (in quadrature) for the neighbour's own uncertainty.
    known_obstacle_sigma: float = 0.0  # m
    known_obstacle_body: float = 0.3  # m, a neighbour's body radius when scored as a landmark

    def __post_init__(self) -> None:
        for f in fields(self):
            setattr(self, f.name, _check(f.name, getattr(self, f.name)))
        if self.pf_max_samples < self.pf_min_samples:
            raise ValueError(
                f"amcl parameter pf_max_samples={self.pf_max_samples} is below pf_min_samples="
                f"{self.pf_min_samples}; raise pf_max_samples or lower pf_min_samples"
            )
        if self.recover_alpha_fast < self.recover_alpha_slow:
            raise ValueError(
                f"amcl parameter recover_alpha_fast={self.recover_alpha_fast:g} is below recover_alpha_slow="
                f"{self.recover_alpha_slow:g}; the fast average must adapt faster (Player: 0.1 and 0.001), "
                "or set both to 0 to turn recovery off"
            )

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AmclParams:
        """Parameters from a driver block's mapping (SI units: m, rad); raises ``ValueError`` naming
        the bad key and a fix, for an unknown key the closest known name."""
        names = [f.name for f in fields(cls)]
        for key in d:
            if key in names:
                continue
            if key in _MOVED_KEYS:
                raise ValueError(f"amcl parameter {key!r} is not a filter parameter: {_MOVED_KEYS[key]}")
            raise ValueError(unknown_key(str(key), names, what="amcl parameter"))
        return cls(**dict(d))


_INT_MIN = {"pf_min_samples": 1, "pf_max_samples": 1, "laser_max_beams": 1, "resample_interval": 1}
_POSITIVE = {"pf_err", "pf_z", "laser_z_hit", "laser_sigma_hit", "laser_likelihood_max_dist", "known_obstacle_body"}
_NON_NEGATIVE = {
    "odom_alpha1",
    "odom_alpha2",
    "odom_alpha3",
    "odom_alpha4",
    "laser_z_rand",
    "laser_unmodeled_margin",
    "known_obstacle_sigma",
}
_UNIT = {"recover_alpha_slow", "recover_alpha_fast", "pf_temper_ess"}
_TUPLES = {"update_thresh": (2, True), "init_pose": (3, False), "init_pose_var": (3, True)}


def _number(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"amcl parameter {key}={value!r} must be a number; e.g. {key} = {_default(key)}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"amcl parameter {key}={value!r} must be finite; e.g. {key} = {_default(key)}")
    return v


def _default(key: str) -> Any:
    for f in fields(AmclParams):
        if f.name == key:
            d = f.default
            return list(d) if isinstance(d, tuple) else d
    return None


def _check(key: str, value: Any) -> Any:
    """Validate and normalise one parameter value (ints, floats, tuples of floats)."""
    if key == "seed":
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise ValueError(f"amcl parameter seed={value!r} must be an integer or None")
        return int(value)
    if key in _INT_MIN:
        v = _number(key, value)
        if v != int(v) or v < _INT_MIN[key]:
            raise ValueError(
                f"amcl parameter {key}={value!r} must be a whole number >= {_INT_MIN[key]}; "
                f"e.g. {key} = {_default(key)}"
            )
        return int(v)
    if key in _TUPLES:
        n, non_negative = _TUPLES[key]
        if isinstance(value, str | bytes) or not hasattr(value, "__len__") or len(value) != n:
            raise ValueError(
                f"amcl parameter {key}={value!r} must be a list of {n} numbers; e.g. {key} = {_default(key)}"
            )
        vals = tuple(_number(key, v) for v in value)
        if non_negative and any(v < 0 for v in vals):
            raise ValueError(f"amcl parameter {key}={value!r} must not be negative; e.g. {key} = {_default(key)}")
        return vals
    v = _number(key, value)
    if key in _POSITIVE and not v > 0:
        raise ValueError(f"amcl parameter {key}={value!r} must be > 0; e.g. {key} = {_default(key)}")
    if key in _NON_NEGATIVE and v < 0:
        raise ValueError(f"amcl parameter {key}={value!r} must be >= 0; e.g. {key} = {_default(key)}")
    if key in _UNIT and not 0.0 <= v <= 1.0:
        raise ValueError(f"amcl parameter {key}={value!r} must be in [0, 1]; e.g. {key} = {_default(key)}")
    return v
