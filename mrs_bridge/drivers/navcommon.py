"""What the navigation drivers (``amcl``, ``wavefront``, ``vfh``/``nd``/``snd``) share.

- The hand-over of a target between the map frame of the localizer and the odometry frame of a
  base (Player's wavefront does the same), with the SE(2) algebra of :mod:`rsal.geometry`.
- Beam geometry of a range device: :class:`~rsal.interfaces.ranger.RangerGeometry`, re-exported
  here as ``BeamGeometry`` (the name the drivers used before it moved to the ranger interface).
- Player configuration units: lengths in metres, angles in **degrees** in the config file; drivers
  declare them in their parameter dataclass (:mod:`mrs_bridge.params`) and convert to radians.
"""

from __future__ import annotations

import math

from rsal.geometry import compose, relative, wrap
from rsal.interfaces.ranger import RangerGeometry

__all__ = ["BeamGeometry", "Handover"]

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
