"""What the navigation drivers (``amcl``, ``wavefront``, ``vfh``/``nd``/``snd``) share.

- The hand-over of a target between the map frame of the localizer and the odometry frame of a
  base (Player's wavefront does the same), with the SE(2) algebra of :mod:`rsal.geometry`.
- Beam geometry of a range device from its ``rpc/describe`` geometry (as the ``sim`` driver and
  real drivers describe it: a mount ``pose`` and one entry per sensor) and a scan: every beam's
  origin and bearing in the robot frame, for a laser (one sensor, many samples) and a sonar ring
  (one reading per transducer) alike.
- Player configuration units: lengths in metres, angles in **degrees** in the config file; drivers
  convert with :func:`deg_param`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rsal.geometry import compose, relative, wrap
from rsal.msgs import RangerData

from ..config import ConfigError

__all__ = ["BeamGeometry", "Handover", "deg_param", "num_param"]


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


class BeamGeometry:
    """Origins ``(n, 2)`` and bearings ``(n,)`` of a range device's beams in the robot frame.

    ``geometry`` is the device's describe geometry: ``pose`` (mount on the robot) and ``sensors``
    (each with ``pose``, ``fov``, ``samples``). The scan decides the layout: as many readings as
    sensors means one beam per sensor (sonar); one sensor with many readings a laser whose beam
    ``i`` points at ``angle_min + i * angle_step`` from the mount; several multi-sample sensors are
    laid out in order, each over its own field of view.
    """

    def __init__(self, geometry: dict[str, Any], override_pose: tuple[float, float, float] | None = None):
        mount = override_pose if override_pose is not None else tuple(geometry.get("pose", (0.0, 0.0, 0.0)))[:3]
        self.mount = tuple(float(v) for v in mount) if len(mount) == 3 else (0.0, 0.0, 0.0)
        self.sensors = [s for s in geometry.get("sensors", []) if isinstance(s, dict)]
        self._cache: tuple[tuple, np.ndarray, np.ndarray] | None = None

    def beams(self, scan: RangerData) -> tuple[np.ndarray, np.ndarray]:
        n = int(scan.ranges.shape[0])
        key = (n, scan.angle_min, scan.angle_step)
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1], self._cache[2]
        mx, my, ma = self.mount
        cm, sm = math.cos(ma), math.sin(ma)
        sens = self.sensors
        if sens and len(sens) == n and n > 0 and (n > 1 or scan.angle_step == 0.0):
            poses = np.array([[float(v) for v in s.get("pose", (0, 0, 0))[:3]] for s in sens], dtype=float)
            ox = mx + cm * poses[:, 0] - sm * poses[:, 1]
            oy = my + sm * poses[:, 0] + cm * poses[:, 1]
            bearings = ma + poses[:, 2]
        elif len(sens) > 1 and sum(int(s.get("samples", 1)) for s in sens) == n:
            ox_l, oy_l, b_l = [], [], []
            for s in sens:
                k = int(s.get("samples", 1))
                px, py, pa = (float(v) for v in s.get("pose", (0, 0, 0))[:3])
                fov = float(s.get("fov", 0.0))
                rel = np.linspace(-fov / 2, fov / 2, k) if k > 1 else np.zeros(1)
                ox_l.append(np.full(k, mx + cm * px - sm * py))
                oy_l.append(np.full(k, my + sm * px + cm * py))
                b_l.append(ma + pa + rel)
            ox, oy, bearings = np.concatenate(ox_l), np.concatenate(oy_l), np.concatenate(b_l)
        else:
            px, py = (float(v) for v in (sens[0].get("pose", (0, 0, 0))[:2] if sens else (0.0, 0.0)))
            ox = np.full(n, mx + cm * px - sm * py)
            oy = np.full(n, my + sm * px + cm * py)
            bearings = ma + scan.angle_min + scan.angle_step * np.arange(n)
        origins = np.column_stack([ox, oy]).astype(float)
        bearings = np.asarray(bearings, dtype=float)
        self._cache = (key, origins, bearings)
        return origins, bearings

    def beam_width(self, scan: RangerData) -> float:
        """The cone width (rad) of one-reading-per-sensor devices (sonar), 0 for a laser's beams."""
        sens = self.sensors
        if sens and len(sens) == int(scan.ranges.shape[0]) and all(int(s.get("samples", 1)) == 1 for s in sens):
            return float(np.mean([float(s.get("fov", 0.0)) for s in sens]))
        return 0.0

    def points(self, scan: RangerData, *, max_range: float | None = None) -> np.ndarray:
        """Obstacle points ``(m, 2)`` in the robot frame; max-range and invalid readings dropped."""
        origins, bearings = self.beams(scan)
        r = np.asarray(scan.ranges, dtype=float)
        top = scan.range_max if scan.range_max > 0 else np.inf
        if max_range is not None:
            top = min(top, max_range)
        ok = np.isfinite(r) & (r < top - 1e-3) & (r > max(scan.range_min, 0.0))
        r = r[ok]
        return np.column_stack([origins[ok, 0] + r * np.cos(bearings[ok]), origins[ok, 1] + r * np.sin(bearings[ok])])


def num_param(cfg, key: str, default: float, *, lo: float = -math.inf, hi: float = math.inf) -> float:
    v = cfg.param(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ConfigError(f"{cfg.where}: {key} = {v!r} must be a number in [{lo:g}, {hi:g}]")
    return float(v)


def deg_param(cfg, key: str, default_deg: float, *, lo: float = 0.0, hi: float = 360.0) -> float:
    """An angle given in degrees in the config (Player's unit), returned in radians."""
    return math.radians(num_param(cfg, key, default_deg, lo=lo, hi=hi))
