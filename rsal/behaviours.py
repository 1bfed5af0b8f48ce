"""Subsumption behaviours of the Pioneer (thesis 3.6.2.4, fig. 3.23; Brooks 1986).

Laser and sonar ranges are fused by taking the minimum per direction ("for reasons of safety",
fig. 3.23): every beam is turned into a point in the robot frame and the points are binned into
sectors around the robot, each sector keeping its nearest point. Behaviours read the sectors; a
higher layer that triggers overrides the motor output of every layer below it:

1. **escape** (highest): the robot is stalled, or something is closer than ``stop_dist`` ahead for
   longer than ``stuck_time``: back up while turning towards the more open side for
   ``escape_time`` seconds.
2. **avoid**: an obstacle within ``avoid_dist`` in the front sectors: slow down and turn away
   from the nearer side.
3. **wallfollow** (when enabled): keep the wall on ``side`` at ``wall_dist``: a proportional
   controller on the side distance and its angle, turning towards open space at inner corners
   and round outer corners to find the wall again.
4. **command** (lowest): the user's ``set_command(v, w)``.

Two body-aware checks are off by default (0) and on where a scenario asks (the thesis swarm's
Pioneer 3-AT): with ``corridor`` > 0 the front is the nearest obstacle in the lane the body sweeps
driving straight (:func:`lane_distance`), not within +-30 deg, and escape backs up only into a clear
lane; with ``sweep`` > 0 no layer's turn swings a corner of the body towards an obstacle within
that radius (:meth:`Subsumption.guard_turn`).

:class:`Subsumption` is a pure state machine (ranges and time in, ``(v, w)`` and the active
layer out) so it is unit-tested without a network; :class:`rsal.robot.Pioneer` feeds it. For rangers
of few beams (a sonar ring) :func:`fuse_beams` and :class:`ListSectors` do the same fusion in plain
Python, which beats numpy's per-call overhead at that size (a crowd of robots runs it 1000 times a
second on one host).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "BehaviourParams",
    "ListSectors",
    "Sectors",
    "Subsumption",
    "beam_points",
    "fuse",
    "fuse_beams",
    "lane_distance",
]

SECTOR_COUNT = 36  # 10 degrees each, sector 0 centred straight ahead, counter-clockwise
_SECTOR = 360.0 / SECTOR_COUNT
_HALF_SECTOR = _SECTOR / 2


@dataclass
class BehaviourParams:
    """Distances in metres, speeds in m/s and rad/s, times in seconds; Pioneer defaults."""

    radius: float = 0.25  # robot's half width, used to judge clearance
    cruise_speed: float = 0.4
    turn_rate: float = 0.8
    stop_dist: float = 0.35  # from the robot centre
    avoid_dist: float = 0.7
    wall_dist: float = 0.6
    stuck_time: float = 2.0
    escape_time: float = 1.5
    escape_speed: float = -0.15
    side: str = "left"  # wall to follow
    # Body-aware checks (0: off, the thesis's plain cones). ``corridor`` > 0: the front distance is
    # the nearest obstacle ahead within that half-width of the robot's lane (the body's corners
    # included), not within +-30 deg; and escape backs up only while the lane behind is clear.
    # ``sweep`` > 0: the radius the body's corners sweep when it turns; no turn swings a corner
    # towards an obstacle nearer than that (the robot drives straight, or waits).
    corridor: float = 0.0
    sweep: float = 0.0


class Sectors:
    """Nearest obstacle distance (from the robot centre) in each of ``SECTOR_COUNT`` directions."""

    def __init__(self, dist: np.ndarray):
        self.dist = dist

    @classmethod
    def empty(cls, far: float = math.inf) -> Sectors:
        return cls(np.full(SECTOR_COUNT, far))

    def min_between(self, a0_deg: float, a1_deg: float) -> float:
        """Minimum over the directions from ``a0`` to ``a1`` degrees (counter-clockwise)."""
        width = 360.0 / SECTOR_COUNT
        i0 = int(math.floor((a0_deg + width / 2) / width))
        i1 = int(math.floor((a1_deg + width / 2) / width))
        idx = np.arange(i0, i1 + 1) % SECTOR_COUNT
        return float(self.dist[idx].min())


# (sector index, cos, sin) of the sector centres within +-40 deg ahead and behind: farther round,
# a point within a lane's half-width lies beside the body, not in its way
_LANE_DEG = 40.0
_AHEAD = [
    (i % SECTOR_COUNT, math.cos(math.radians(i * _SECTOR)), math.sin(math.radians(i * _SECTOR)))
    for i in range(-int(_LANE_DEG // _SECTOR), int(_LANE_DEG // _SECTOR) + 1)
]
_BEHIND = [((i + SECTOR_COUNT // 2) % SECTOR_COUNT, c, sn) for i, c, sn in _AHEAD]


def lane_distance(s: Sectors, half_width: float, behind: bool = False) -> float:
    """How far (m, from the robot centre along its heading; ``behind``: backwards) the nearest
    obstacle lies in the lane of ``half_width`` m that driving straight sweeps: each sector's
    nearest point within 40 deg of the heading, taken at the sector's centre direction, counts
    when it lies within ``half_width`` of the robot's axis (the sectors cover the lane from just
    beyond the body's front corners). Infinite when the lane is clear."""
    best = math.inf
    dist = s.dist
    for i, c, sn in _BEHIND if behind else _AHEAD:
        d = dist[i]
        if d < best and c > 0.0 and abs(d * sn) < half_width:
            x = d * c
            if x < best:
                best = x
    return float(best)


def fuse(points_xy: list[np.ndarray], far: float = math.inf) -> Sectors:
    """Bin obstacle points (each an (n, 2) array in the robot frame) into sectors by minimum."""
    d = np.full(SECTOR_COUNT, far)
    pts = [p for p in points_xy if p is not None and len(p)]
    if not pts:
        return Sectors(d)
    p = np.concatenate(pts)
    r = np.hypot(p[:, 0], p[:, 1])
    ang = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    width = 360.0 / SECTOR_COUNT
    idx = np.floor((ang + width / 2) / width).astype(int) % SECTOR_COUNT
    np.minimum.at(d, idx, r)
    return Sectors(d)


def beam_points(poses: np.ndarray, ranges: np.ndarray, range_max: float) -> np.ndarray:
    """End points (robot frame) of the beams that hit something (range < range_max)."""
    n = min(len(poses), len(ranges))
    poses, ranges = poses[:n], np.asarray(ranges[:n], dtype=float)
    hit = np.isfinite(ranges) & (ranges < range_max * 0.999)
    p = poses[hit]
    r = ranges[hit]
    return np.column_stack([p[:, 0] + r * np.cos(p[:, 2]), p[:, 1] + r * np.sin(p[:, 2])])


class ListSectors(Sectors):
    """:class:`Sectors` over a plain list: for a handful of beams, Python's own
    arithmetic beats numpy's per-call overhead (the behaviour reads a sector range 7 times a cycle)."""

    def __init__(self, dist: list[float]):
        self.dist = dist  # a list here, not an array

    def min_between(self, a0_deg: float, a1_deg: float) -> float:
        i0 = math.floor((a0_deg + _HALF_SECTOR) / _SECTOR)
        n = math.floor((a1_deg + _HALF_SECTOR) / _SECTOR) - i0 + 1
        v = self.dist
        if n >= SECTOR_COUNT:
            return min(v)
        i0 %= SECTOR_COUNT
        if i0 + n <= SECTOR_COUNT:
            return min(v[i0 : i0 + n])
        return min(min(v[i0:]), min(v[: i0 + n - SECTOR_COUNT]))


def fuse_beams(beams: list[tuple[float, float, float, float]], ranges, range_max: float) -> list[float]:
    """:func:`fuse` of :func:`beam_points` for few beams, in plain
    Python: ``beams`` are (x, y, cos yaw, sin yaw) of each beam's origin in the robot frame; a beam
    counts when its range is finite and below ``range_max`` (the nearest point per sector)."""
    d = [math.inf] * SECTOR_COUNT
    lim = range_max * 0.999
    for (bx, by, c, sn), r in zip(beams, ranges.tolist(), strict=False):
        if not r < lim:  # also NaN
            continue
        x, y = bx + r * c, by + r * sn
        i = math.floor((math.degrees(math.atan2(y, x)) + _HALF_SECTOR) / _SECTOR) % SECTOR_COUNT
        dist = math.hypot(x, y)
        if dist < d[i]:
            d[i] = dist
    return d


class Subsumption:
    """The behaviour layers as a state machine; call :meth:`step` at about 10 Hz."""

    def __init__(self, params: BehaviourParams | None = None):
        self.p = params or BehaviourParams()
        self.command = (0.0, 0.0)
        self.wallfollow = False
        self.state = "idle"
        self._blocked_since: float | None = None
        self._escape_until = -math.inf
        self._escape_turn = 1.0
        self.escapes = 0

    def set_command(self, v: float, w: float) -> None:
        self.command = (float(v), float(w))
        self.wallfollow = False

    def set_wallfollow(self, on: bool = True, side: str | None = None) -> None:
        self.wallfollow = bool(on)
        if side is not None:
            if side not in ("left", "right"):
                raise ValueError(f"side {side!r} must be 'left' or 'right'")
            self.p.side = side

    def guard_turn(self, s: Sectors, v: float, w: float) -> tuple[float, float]:
        """``(v, w)`` without its turn when the turn would swing the body into something
        (``sweep`` > 0). A turning rectangle enters new ground wherever its outline's distance
        from the centre grows against the turn: turning left the front-left and rear-right
        quarters (the long sides and the corners swinging out), and also the front-right and
        rear-left corners' slivers beside the heading and the tail (the corner of a 3-AT, 39 deg
        off its axis, swings to 0 deg through the sectors within 30 deg of the axis); turning right the
        mirror image. While any of those holds an obstacle within ``sweep`` the robot drives
        straight (or waits). (Checking the two quarters alone let a robot turning right in place
        swing its front-left corner into a neighbour just ahead-left.)"""
        r = self.p.sweep
        if r <= 0 or w == 0.0:
            return (v, w)
        if w > 0:
            near = min(s.min_between(-30, 90), s.min_between(-180, -90), s.min_between(150, 180))
        else:
            near = min(s.min_between(-90, 30), s.min_between(90, 180), s.min_between(-180, -150))
        return (v, w) if near >= r else (v, 0.0)

    def _escape(self, s: Sectors) -> tuple[float, float]:
        """The escape layer's output: back up turning towards the more open side; with
        ``corridor`` > 0 only while the lane behind is clear (else turn in place), and with
        ``sweep`` > 0 no turn in place while something is that near (then it waits)."""
        p = self.p
        v, w = p.escape_speed, p.turn_rate * self._escape_turn
        if p.corridor > 0 and lane_distance(s, p.corridor, behind=True) < p.stop_dist:
            v = 0.0
        return self.guard_turn(s, v, w)

    def step(self, s: Sectors, now: float, stalled: bool = False) -> tuple[float, float]:
        p = self.p
        front = lane_distance(s, p.corridor) if p.corridor > 0 else s.min_between(-30, 30)
        left = s.min_between(30, 100)
        right = s.min_between(-100, -30)
        moving_intent = self.wallfollow or abs(self.command[0]) > 1e-3

        # 1. escape
        if now < self._escape_until:
            self.state = "escape"
            return self._escape(s)
        blocked = moving_intent and (stalled or front < p.stop_dist)
        if blocked:
            if self._blocked_since is None:
                self._blocked_since = now
            elif now - self._blocked_since >= p.stuck_time:
                self._blocked_since = None
                self._escape_until = now + p.escape_time
                self._escape_turn = 1.0 if left > right else -1.0
                self.escapes += 1
                self.state = "escape"
                return self._escape(s)
        else:
            self._blocked_since = None

        # 2. avoid
        if moving_intent and front < p.avoid_dist:
            self.state = "avoid"
            turn = 1.0 if left >= right else -1.0
            if self.wallfollow:  # turn away from the followed wall
                turn = -1.0 if p.side == "left" else 1.0
            v = (
                0.0
                if front < p.stop_dist
                else p.cruise_speed * (front - p.stop_dist) / (p.avoid_dist - p.stop_dist) * 0.5
            )
            return self.guard_turn(s, v, p.turn_rate * turn)  # boxed in: waits, escape after stuck_time

        # 3. wall-follow
        if self.wallfollow:
            self.state = "wallfollow"
            sign = 1.0 if p.side == "left" else -1.0
            side_d = s.min_between(60, 120) if sign > 0 else s.min_between(-120, -60)
            diag = s.min_between(30, 60) if sign > 0 else s.min_between(-60, -30)
            if min(side_d, diag) > 2.5 * p.wall_dist:
                # no wall: curve towards the side to find one
                return (p.cruise_speed * 0.8, sign * p.turn_rate * 0.4)
            # The nearest point of a parallel wall in the diagonal sectors (25..65 degrees) lies on
            # their outer edge, at wall distance / sin(65 deg): scale it back to a wall distance.
            diag_d = diag * math.sin(math.radians(65))
            err = min(side_d, diag_d) - p.wall_dist
            # diag_d < side_d: heading into the wall; diag_d > side_d: heading away (or a corner).
            w = sign * float(np.clip(1.5 * err + 4.0 * (diag_d - side_d), -p.turn_rate, p.turn_rate))
            v = p.cruise_speed * (0.6 if abs(err) > 0.3 else 1.0)
            return self.guard_turn(s, v, w)

        # 4. command
        self.state = "command" if moving_intent or self.command[1] else "idle"
        return self.command
