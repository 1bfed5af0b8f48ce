"""Obstacle points around a robot, as the local planners see them: polar helpers, the motion
guard's free path length, and the scan memory.

Shared by :mod:`~mrs_bridge.nav.vfh`, :mod:`~mrs_bridge.nav.nd` and :mod:`~mrs_bridge.nav.snd`
through :class:`~mrs_bridge.nav.local.LocalPlanner` (which re-exports these names). Points are an
``(n, 2)`` array in the robot frame (metres, x ahead, y left); every function is one vectorised
numpy pass over them. :func:`free_path_length` is the clearance of a disc swept along circular
arcs (the arc-based collision check of the dynamic window approach, Fox, Burgard and Thrun 1997,
"The Dynamic Window Approach to Collision Avoidance"), for many curvatures at once.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from rsal.geometry import TWO_PI

__all__ = ["ScanMemory", "as_points", "corridor_clear", "free_path_length", "polar_ranges"]

_GUARD_HORIZON = 4.0  # m: default look-ahead of free_path_length


def as_points(points) -> np.ndarray:
    """Obstacle points as a float64 ``(n, 2)`` array; rows with a non-finite value are dropped."""
    if points is None:
        return np.empty((0, 2))
    p = np.asarray(points, dtype=np.float64)
    if p.size == 0:
        return np.empty((0, 2))
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"points must be an (n, 2) array of robot-frame x, y in metres, not shape {p.shape}")
    ok = np.isfinite(p).all(axis=1)
    return p if ok.all() else p[ok]


def polar_ranges(points: np.ndarray, n_sectors: int, *, empty: float = math.inf) -> np.ndarray:
    """Minimum range of the points in each of ``n_sectors`` equal sectors around the robot.

    Sector ``k`` is centred on the direction ``k * 2 pi / n_sectors`` (robot frame, counter-
    clockwise from straight ahead). Sectors without a point get ``empty``.
    """
    out = np.full(n_sectors, empty, dtype=np.float64)
    if len(points) == 0:
        return out
    r = np.hypot(points[:, 0], points[:, 1])
    k = np.rint(np.arctan2(points[:, 1], points[:, 0]) * (n_sectors / TWO_PI)).astype(np.int64) % n_sectors
    np.minimum.at(out, k, r)
    return out


def corridor_clear(points: np.ndarray, angle: float, length: float, half_width: float) -> bool:
    """True if no point lies in the rectangle swept by a disc of radius ``half_width`` moving
    ``length`` metres from the robot's centre in direction ``angle`` (robot frame)."""
    if len(points) == 0:
        return True
    c, s = math.cos(angle), math.sin(angle)
    along = points[:, 0] * c + points[:, 1] * s
    across = -points[:, 0] * s + points[:, 1] * c
    near = np.abs(across) < half_width
    reach = along - np.sqrt(np.maximum(half_width * half_width - across * across, 0.0))
    return not bool(np.any(near & (along > 0.0) & (reach < length)))


def free_path_length(points: np.ndarray, curvature, radius: float, horizon: float = _GUARD_HORIZON) -> np.ndarray:
    """How far (m, along the path of the robot's centre) the robot can drive forward on arcs of
    the given curvatures (1/m, positive to the left; an array of ``K``) before a disc of ``radius``
    around its centre touches any of the points. ``horizon`` where nothing is in the way within it.

    Points already inside the disc and ahead of the centre (``x > 0``) stop the robot at once (0);
    ones inside it and behind are left behind and ignored. One vectorised pass over ``K x n``.
    """
    kap = np.atleast_1d(np.asarray(curvature, dtype=np.float64))
    out = np.full(kap.shape, float(horizon))
    if len(points) == 0:
        return out
    px, py = points[:, 0], points[:, 1]
    r2 = radius * radius
    d2 = px * px + py * py
    if np.any((d2 < r2) & (px > 0.0)):
        return np.zeros(kap.shape)
    # Only points the disc can reach within the horizon matter (and not those already inside it,
    # which are behind the centre and left behind).
    reach_r = horizon + radius
    keep = (d2 >= r2) & (d2 < reach_r * reach_r)
    if not keep.any():
        return out
    px, py = px[keep], py[keep]
    straight = np.abs(kap) < 1e-6
    if straight.any():
        hit = (np.abs(py) < radius) & (px > 0.0)
        if hit.any():
            d = px[hit] - np.sqrt(r2 - py[hit] ** 2)
            out[straight] = min(float(horizon), float(d.min()))
    turn = ~straight
    if turn.any():
        k = kap[turn][:, None]
        rho = 1.0 / k  # signed turning radius; centre of the turn at (0, rho)
        arho = np.abs(rho)
        qy = py[None, :] - rho
        q = np.hypot(px[None, :], qy)
        reach = np.abs(q - arho) < radius  # the centre's circle passes within `radius` of the point
        if reach.any():
            # The disc touches the point where the centre is `radius` from it: at +-delta around the
            # point's own angle about the turn centre (law of cosines).
            cos_d = (arho * arho + q * q - r2) / (2.0 * arho * np.maximum(q, 1e-12))
            delta = np.arccos(np.clip(cos_d, -1.0, 1.0))
            # Angle travelled (in the direction of the turn) from the start to the point's angle.
            ang = np.arctan2(qy, px[None, :])
            start = np.where(k > 0, -0.5 * math.pi, 0.5 * math.pi)
            travel = np.where(k > 0, ang - start, start - ang) % TWO_PI
            contact = np.clip(travel - delta, 0.0, None)
            length = np.where(reach & (contact <= math.pi), arho * contact, np.inf)
            out[turn] = np.minimum(float(horizon), length.min(axis=1))
    return out


class ScanMemory:
    """Recent obstacle points, kept in the odometry frame, for the directions the sensors do not see.

    A 240-degree laser is blind behind the robot: a planner that turns in place next to an obstacle
    forgets it, and a robot backing up cannot see what it backs into. The memory keeps the points
    of the last ``keep`` seconds within ``reach`` metres and learns the sensors' coverage from where
    hits appear (a direction without a hit for ``coverage_time`` seconds counts as unseen). Recalled
    points lie only in unseen directions, so the live scan always wins where there is one.
    """

    def __init__(
        self,
        keep: float = 3.0,
        reach: float = 2.0,
        coverage_time: float = 10.0,
        interval: float = 0.3,
        decimate: int = 3,
        sectors: int = 72,
    ):
        self.keep, self.reach, self.coverage_time = keep, reach, coverage_time
        self.interval, self.decimate, self.sectors = interval, decimate, sectors  # every `interval` s, every
        # `decimate`-th point of a scan is stored
        self.clear()

    def clear(self) -> None:
        self._scans: deque[tuple[float, np.ndarray]] = deque()
        self._seen = np.full(self.sectors, -math.inf)  # robot frame: last hit per direction
        self._looked = np.full(self.sectors, -math.inf)  # odometry frame: last time in view
        self._stored = -math.inf

    def _sector(self, pts: np.ndarray) -> np.ndarray:
        a = np.arctan2(pts[:, 1], pts[:, 0])
        return np.floor((a + math.pi) * (self.sectors / TWO_PI)).astype(np.int64) % self.sectors

    def update(self, t: float, pose: tuple[float, float, float], pts: np.ndarray) -> None:
        """Add a scan (robot-frame points) taken at time ``t`` from odometry pose ``pose``."""
        while self._scans and self._scans[0][0] < t - self.keep:
            self._scans.popleft()
        if t - self._stored < self.interval or not len(pts):
            return
        self._stored = t
        self._seen[self._sector(pts)] = t
        covered = np.flatnonzero(self._seen >= t - self.coverage_time)
        self._looked[(covered + int(round(pose[2] * self.sectors / TWO_PI))) % self.sectors] = t
        few = pts[:: self.decimate]
        near = few[(few[:, 0] ** 2 + few[:, 1] ** 2) < self.reach * self.reach]
        if len(near):
            c, s = math.cos(pose[2]), math.sin(pose[2])
            xy = np.column_stack((pose[0] + c * near[:, 0] - s * near[:, 1], pose[1] + s * near[:, 0] + c * near[:, 1]))
            self._scans.append((t, xy))

    def looked(self, t: float, pose: tuple[float, float, float], direction: float, half_width: float) -> bool:
        """Whether every direction within ``half_width`` of ``direction`` (robot frame at ``pose``)
        was in the sensors' view in the last ``keep`` seconds -- so the memory knows what is there."""
        w = self.sectors / TWO_PI
        lo = int(math.floor((pose[2] + direction - half_width + math.pi) * w))
        hi = int(math.ceil((pose[2] + direction + half_width + math.pi) * w))
        idx = np.arange(lo, hi + 1) % self.sectors
        return bool(np.all(self._looked[idx] >= t - self.keep))

    def recall(self, t: float, pose: tuple[float, float, float]) -> np.ndarray:
        """Remembered points (robot frame at ``pose``) in the directions not covered by the sensors."""
        unseen = self._seen < t - self.coverage_time
        if not self._scans or not unseen.any():
            return np.empty((0, 2))
        xy = np.concatenate([s for _, s in self._scans]) if len(self._scans) > 1 else self._scans[0][1]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        dx, dy = xy[:, 0] - pose[0], xy[:, 1] - pose[1]
        local = np.column_stack((c * dx + s * dy, -s * dx + c * dy))
        local = local[(local[:, 0] ** 2 + local[:, 1] ** 2) < self.reach * self.reach]
        if not len(local):
            return local
        return local[unseen[self._sector(local)]]
