"""The ``localize`` interface: a localizer's pose estimate (Player's ``localize``; thesis
eq. 3.3-3.4, the ``amcl`` driver).

Messages :class:`LocalizeData` (``data``) of :class:`Hypothesis`, :class:`ObstaclesCmd` (``cmd``:
known moving obstacles, the fire-and-forget form of ``rpc/set_obstacles``); proxy :class:`Localize`.
Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..data import Position
from ..msgs import MessageError, _Msg, get_float, get_int, get_list, get_vec
from .base import Device, Interface

__all__ = ["Hypothesis", "LocalizeData", "ObstaclesCmd", "first_bad_disc", "is_disc", "Localize", "INTERFACE"]


def _cov9(m: dict, name: str) -> tuple[float, ...]:
    c = get_vec(m, name, 9)
    if c[0] < 0 or c[4] < 0 or c[8] < 0:
        raise MessageError(f"field {name!r} must be a covariance (non-negative diagonal)")
    return c


@dataclass(frozen=True)
class Hypothesis(_Msg):
    """One pose hypothesis of a localizer: ``weight`` in [0, 1], ``pose`` mean (x, y, yaw) in the map
    frame, ``cov`` its 3x3 covariance row-major (m², rad²)."""

    weight: float
    pose: tuple[float, float, float]
    cov: tuple[float, ...]

    @classmethod
    def from_dict(cls, m: dict) -> Hypothesis:
        if not isinstance(m, dict):
            raise MessageError("each hypothesis must be a map")
        return cls(get_float(m, "weight", lo=0.0, hi=1.0 + 1e-9), get_vec(m, "pose", 3), _cov9(m, "cov"))


@dataclass(frozen=True)
class LocalizeData(_Msg):
    """localize ``data`` (Player's localize interface; thesis eq. 3.3-3.4): the best estimate ``pose``
    with covariance ``cov`` (row-major 3x3), every ``hypotheses`` entry heaviest first, the number of
    ``particles``, and ``pending`` sensor updates skipped (0 when keeping up)."""

    t: float
    pose: tuple[float, float, float]
    cov: tuple[float, ...]
    hypotheses: list[Hypothesis] = field(default_factory=list)
    particles: int = 0
    pending: int = 0

    @classmethod
    def from_dict(cls, m: dict) -> LocalizeData:
        return cls(
            get_float(m, "t"),
            get_vec(m, "pose", 3),
            _cov9(m, "cov"),
            get_list(m, "hypotheses", Hypothesis.from_dict, False),
            get_int(m, "particles", 0, lo=0),
            get_int(m, "pending", 0, lo=0),
        )


def is_disc(v) -> bool:
    """Whether ``v`` is a known obstacle's ``[x, y, radius]``: three finite numbers, radius > 0 (m)."""
    return (
        isinstance(v, list | tuple)
        and len(v) == 3
        and all(isinstance(e, int | float) and not isinstance(e, bool) and math.isfinite(e) for e in v)
        and v[2] > 0
    )


def first_bad_disc(discs) -> int | None:
    """The index of the first entry of ``discs`` that is not :func:`is_disc`, or None."""
    return next((i for i, v in enumerate(discs) if not is_disc(v)), None)


@dataclass(frozen=True)
class ObstaclesCmd(_Msg):
    """localize ``cmd``: known moving obstacles, ``obstacles`` ``((x, y, radius), ...)`` (m, map
    frame; a swarm's neighbours where their broadcasts put them), kept for ``ttl`` s (default 1.5)
    or until the next declaration; the fire-and-forget form of ``rpc/set_obstacles`` (no reply)."""

    obstacles: tuple[tuple[float, float, float], ...]
    ttl: float = 1.5

    @classmethod
    def from_dict(cls, m: dict) -> ObstaclesCmd:
        raw = m.get("obstacles")
        if not isinstance(raw, list | tuple):
            raise MessageError("field 'obstacles' must be a list of [x, y, radius] (m, map frame)")
        bad = first_bad_disc(raw)
        if bad is not None:
            raise MessageError(f"field 'obstacles'[{bad}] = {raw[bad]!r} must be [x, y, radius] with radius > 0 (m)")
        discs = tuple((float(v[0]), float(v[1]), float(v[2])) for v in raw)
        ttl = get_float(m, "ttl", 1.5)
        if not ttl > 0:
            raise MessageError(f"field 'ttl' {ttl!r} must be a positive number of s")
        return cls(discs, ttl)


class Localize(Device):
    """A localizer (Player's localize; the ``amcl`` driver): the robot's pose on the map with its
    covariance (thesis eq. 3.3-3.4) and the hypotheses behind it."""

    data_type = LocalizeData

    def get_position(self) -> Position | None:
        """The best pose estimate, or None before the first update."""
        m = self.latest
        return Position(*m.pose) if m is not None else None

    position = property(get_position)

    def covariance(self) -> np.ndarray | None:
        m = self.latest
        return np.asarray(m.cov, dtype=float).reshape(3, 3) if m is not None else None

    def hypotheses(self) -> list[Hypothesis]:
        m = self.latest
        return list(m.hypotheses) if m is not None else []

    def set_position(self, pose: Position, cov=(0.25, 0.25, 0.0685), timeout: float = 5.0) -> dict:
        """Re-initialise the filter around ``pose``; ``cov`` is a 3x3 matrix or its diagonal
        (m², m², rad²; default 0.5 m and 15 deg standard deviations). The thesis's way to help a robot
        that cannot find itself (3.4.2)."""
        c = np.asarray(cov, dtype=float)
        if c.shape == (3,):
            c = np.diag(c)
        if c.shape != (3, 3):
            raise ValueError("cov must be a 3x3 matrix or its diagonal (3 values)")
        return self.rpc("set_pose", timeout=timeout, pose=list(pose.as_tuple()), cov=[float(x) for x in c.ravel()])

    def set_obstacles(self, discs, ttl: float = 1.5, timeout: float = 5.0):
        """Declare known moving obstacles, ``discs`` ``[(x, y, radius), ...]`` (m, map frame): a
        swarm's neighbours where their broadcasts put them. The localizer leaves out the readings
        they explain until ``ttl`` s have passed or the next call replaces them. Returns the
        request's future (a swarm declares at its broadcast rate and does not wait)."""
        obstacles = [[float(x), float(y), float(r)] for x, y, r in discs]
        return self.rpc_async("set_obstacles", timeout=timeout, obstacles=obstacles, ttl=float(ttl))

    def declare_obstacles(self, discs, ttl: float = 1.5) -> None:
        """:meth:`set_obstacles` as a command (``cmd``, :class:`ObstaclesCmd`): fire and forget, no
        query and no reply; a malformed declaration is dropped by the server with a warning."""
        self.send(ObstaclesCmd(tuple((float(x), float(y), float(r)) for x, y, r in discs), float(ttl)))

    def set_global(self, timeout: float = 5.0) -> dict:
        """Forget the pose: global localization over all free space."""
        return self.rpc("set_global", timeout=timeout)


def _summary(m: LocalizeData) -> str:
    x, y, a = m.pose
    sx, sy = m.cov[0] ** 0.5, m.cov[4] ** 0.5
    return f"pose=({x:.2f}, {y:.2f}, {a:.2f}) sd=({sx:.2f}, {sy:.2f}) m hypotheses={len(m.hypotheses)}"


INTERFACE = Interface(
    "localize",
    proxy=Localize,
    data=LocalizeData,
    cmds=(ObstaclesCmd,),
    summary=_summary,
    doc="pose on the map with covariance and hypotheses",
)
