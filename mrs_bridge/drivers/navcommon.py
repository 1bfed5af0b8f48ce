"""What the navigation drivers (``amcl``, ``wavefront``, ``vfh``/``nd``/``snd``) share.

- The hand-over of a target between the map frame of the localizer and the odometry frame of a
  base (Player's wavefront does the same), with the SE(2) algebra of :mod:`rsal.geometry`.
- Beam geometry of a range device: :class:`~rsal.interfaces.ranger.RangerGeometry`, re-exported
  here as ``BeamGeometry`` (the name the drivers used before it moved to the ranger interface).
- Player configuration units: lengths in metres, angles in **degrees** in the config file; drivers
  convert with :func:`deg_param`.
"""

from __future__ import annotations

import math

from rsal.geometry import compose, relative, wrap
from rsal.interfaces.ranger import RangerGeometry

from ..config import ConfigError

__all__ = ["BeamGeometry", "Handover", "deg_param", "num_param"]

BeamGeometry = RangerGeometry  # the name before it moved to rsal/interfaces/ranger.py


class Handover:
    """Moves a global planner's target from the map frame into a base's odometry frame, as Player's
    wavefront does: ``odom ⊕ (localized⁻¹ ⊕ target)``. :meth:`due` says whether to (re-)send it: when
    it moved by ``dist`` metres or ``angle`` radians in the odometry frame (localization corrected
    itself), or ``period`` seconds passed."""

    def __init__(self, dist: float = 0.05, angle: float = math.radians(3), period: float = 1.0):
        self.dist, self.angle, self.period = dist, angle, period
        self.sent: tuple[tuple[float, float, float], float] | None = None

    def reset(self) -> None:
        self.sent = None

    def due(self, localized, odom, target_map, now: float) -> tuple[float, float, float] | None:
        t = compose(odom, relative(localized, target_map))
        last = self.sent
        if (
            last is None
            or math.dist(last[0][:2], t[:2]) > self.dist
            or abs(wrap(last[0][2] - t[2])) > self.angle
            or now - last[1] > self.period
        ):
            self.sent = (t, now)
            return t
        return None


def num_param(cfg, key: str, default: float, *, lo: float = -math.inf, hi: float = math.inf) -> float:
    v = cfg.param(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ConfigError(f"{cfg.where}: {key} = {v!r} must be a number in [{lo:g}, {hi:g}]")
    return float(v)


def deg_param(cfg, key: str, default_deg: float, *, lo: float = 0.0, hi: float = 360.0) -> float:
    """An angle given in degrees in the config (Player's unit), returned in radians."""
    return math.radians(num_param(cfg, key, default_deg, lo=lo, hi=hi))
