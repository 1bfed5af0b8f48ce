"""SND: Smooth Nearness-Diagram navigation (Player's ``snd`` driver, thesis 3.4.1).

Durham & Bullo 2008, "Smooth Nearness-Diagram Navigation" (IEEE/RSJ IROS, 690-695): ND's gap and
valley analysis without its switching between situations. One motion law blends every close
obstacle into the heading, so the robot does not oscillate where ND would switch. Each cycle:

1. **Depth per sector.** The obstacle points are binned into 720 half-degree sectors around the
   robot's centre (nearest point per sector, empty sectors free) -- fine enough that a wall seen at
   a grazing angle does not look like a gap.
2. **Gaps.** A gap is a jump in depth between neighbouring sectors of more than the robot's
   diameter, or between an obstacle and free space. It *rises* towards its deeper side.
3. **Valleys.** The sectors between two gaps form a region; one with a gap rising into it is a
   valley. A valley is *navigable* through a rising gap when the distance from the gap's near
   obstacle point to the nearest obstacle point across it is at least ``min_gap_width``.
4. **Safe direction** ``theta_s``. If a disc of ``robot_radius`` can travel straight to the goal,
   the goal direction. Otherwise the navigable rising gap nearest the goal direction (of two
   about equally near, the one clockwise of it: keep right; and each gap is charged 0.5 rad per
   radian it lies from the one taken last cycle, so two gaps do not take turns): aim past its
   near point with a clearance of half the gap's width, but no more than the robot's radius plus
   half of ``obstacle_avoid_dist``.
5. **Smooth avoidance.** Every sector with an obstacle closer to the robot's body than
   ``obstacle_avoid_dist`` has a nearness ``a = 1 - gap / obstacle_avoid_dist`` and asks to turn
   the heading until it is at least 90 degrees from that obstacle. The heading is ``theta_s`` plus
   the ``a^2``-weighted mean of these requests, scaled by the largest ``a``: far obstacles bend the
   path a little, close ones a lot, and obstacles on both sides balance. An obstacle dead ahead
   counts as on the left, so it pushes to the right (keep right).
6. **Motion.** Speed ``max_speed`` scaled by the nearness of the closest obstacle in the way
   (within 45 degrees of the heading) and by the angle still to turn (none beyond 90 degrees);
   turn rate ``max_turn_rate`` scaled by that angle over 45 degrees.

Player's driver has no stuck or escape options; here no navigable valley for 2 s, or under 0.15 m
of net progress (and under 20 deg of net turn) in 10 s, is status ``blocked`` and the robot turns
for 2 s at 30 deg/s towards the more open side, backing up at 0.1 m/s where the space behind has
been in view. A fixed 0.1 m clearance (:data:`GUARD_MARGIN`) is the safety distance of the motion
guard.

Parameters are Player's, in its units (m, m/s, deg, deg/s): ``robot_radius`` (default: half the
diagonal of the base's geometry given to the constructor, else 0.25 m), ``min_gap_width``
(project: the guard's disc, ``2 (robot_radius + GUARD_MARGIN)``, plus 0.1 m; Player 2 radii),
``obstacle_avoid_dist`` (4 radii, as Player; 2 radii is about 15% faster but failed 1-2 runs in
100 of the sweep where 4 radii failed none), ``max_speed`` (project 0.4; Player 0.5),
``max_turn_rate``, ``goal_position_tol`` (half a radius, at least 0.1 m), ``goal_angle_tol``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rsal.geometry import TWO_PI, wrap

from .local import KEEP_RIGHT, LocalPlanner, Param, corridor_clear

__all__ = ["SND", "GUARD_MARGIN"]

_SECTORS = 720
_TURN_SCALE = math.radians(45.0)
_BLOCKED_AFTER = 2.0  # s
_STUCK = (10.0, 0.15, math.radians(20.0), 20.0)  # s, m, rad, s
_ESCAPE = (0.1, math.radians(30.0), 2.0)  # m/s, rad/s, s
GUARD_MARGIN = 0.1  # m kept clear by the motion guard
_GAP_SPARE = 0.1  # m: the default min_gap_width leaves this much room beyond the guard's disc
_STICKY = 0.5  # cost per radian between a gap and the one taken last cycle (against dithering)


class SND(LocalPlanner):
    """Smooth Nearness-Diagram navigation with Player's ``snd`` driver's parameters."""

    name = "snd"
    PARAMS = {
        "robot_radius": Param(None, 0.05, 5.0, "m", "radius of the smallest circle holding the robot"),
        "min_gap_width": Param(
            None, 0.0, 10.0, "m", "narrowest passage tried (project: guard disc + 0.1 m; Player 2 radii)"
        ),
        "obstacle_avoid_dist": Param(None, 0.05, 10.0, "m", "obstacles nearer the body than this push (4 radii)"),
        "max_speed": Param(0.4, 0.0, 5.0, "m/s", "top forward speed (project; Player 0.5)"),
        "max_turn_rate": Param(60.0, 1.0, 720.0, "deg/s", "top turn rate"),
        "goal_position_tol": Param(None, 0.01, 10.0, "m", "goal position tolerance"),
        "goal_angle_tol": Param(30.0, 0.1, 180.0, "deg", "goal yaw tolerance"),
    }

    def _configure(self, p: dict[str, Any]) -> None:
        r = p["robot_radius"] if p["robot_radius"] is not None else self._radius(0.25)
        self.robot_radius = r
        default_gap = 2.0 * (r + GUARD_MARGIN) + _GAP_SPARE
        self.min_gap = p["min_gap_width"] if p["min_gap_width"] is not None else default_gap
        self.avoid = p["obstacle_avoid_dist"] if p["obstacle_avoid_dist"] is not None else 4.0 * r
        self.v_max = p["max_speed"]
        self.w_max = math.radians(p["max_turn_rate"])
        self.pos_tol = p["goal_position_tol"] if p["goal_position_tol"] is not None else max(0.5 * r, 0.1)
        self.ang_tol = math.radians(p["goal_angle_tol"])
        self.turn_min = math.radians(5.0)
        self.accel = None
        self.brake = 0.5
        self.escape_speed, self.escape_turnrate, self.escape_time = _ESCAPE
        self.blocked_after = _BLOCKED_AFTER
        self.stuck_time, self.stuck_dist, self.stuck_angle, self.rotate_stuck_time = _STUCK
        self.params = {
            **self.params,
            "robot_radius": r,
            "min_gap_width": self.min_gap,
            "obstacle_avoid_dist": self.avoid,
            "goal_position_tol": self.pos_tol,
        }
        n = _SECTORS
        self._angles = wrap(np.arange(n) * (TWO_PI / n))
        self._cos, self._sin = np.cos(self._angles), np.sin(self._angles)

    def safety(self, speed: float) -> float:
        return GUARD_MARGIN

    # ------------------------------------------------------------------ the algorithm
    def _plan(self, goal, dist, pts, speed, pose, dt):
        n = _SECTORS
        R = self.robot_radius
        r = np.hypot(pts[:, 0], pts[:, 1])
        k = np.rint(np.arctan2(pts[:, 1], pts[:, 0]) * (n / TWO_PI)).astype(np.int64) % n
        d = np.full(n, np.inf)
        np.minimum.at(d, k, r)
        goal_dir = math.atan2(goal[1], goal[0])
        if corridor_clear(pts, goal_dir, dist, R + GUARD_MARGIN):
            theta_s = goal_dir
        else:
            last = None if self._last_gap is None else float(wrap(self._last_gap - pose[2]))
            theta_s = self._safe_direction(d, k, pts, goal_dir, last)
            self._last_gap = None if theta_s is None else float(wrap(theta_s + pose[2]))
            if theta_s is None:
                return 0.0, math.copysign(self.turn_min, goal_dir), False
        # Smooth avoidance: every close sector bends the heading away from itself.
        gap = d - R
        near = gap < self.avoid
        theta = theta_s
        v_scale = 1.0
        if near.any():
            a = np.clip(1.0 - gap[near] / self.avoid, 0.0, 1.0)
            # Keep right: an obstacle dead ahead counts as on the left, so it pushes to the right.
            rel = wrap(self._angles[near] - theta_s + KEEP_RIGHT)
            req = -np.sign(rel) * np.maximum(0.0, 0.5 * math.pi - np.abs(rel))
            a2 = a * a
            theta = wrap(theta_s + float(a.max()) * float(a2 @ req) / float(a2.sum()))
            ahead = np.abs(wrap(self._angles[near] - theta)) < 0.25 * math.pi  # in the way
            if ahead.any():
                v_scale = float(np.clip(1.0 - a[ahead].max(), 0.1, 1.0))
        self.heading_wanted = theta
        v = self.v_max * v_scale * max(0.0, 1.0 - abs(theta) / (0.5 * math.pi))
        w = self.w_max * float(np.clip(theta / _TURN_SCALE, -1.0, 1.0))
        return v, w, True

    def _reset_algorithm(self) -> None:
        self._last_gap: float | None = None  # odometry-frame direction of the gap taken last cycle

    def _safe_direction(
        self, d: np.ndarray, k: np.ndarray, pts: np.ndarray, goal_dir: float, last: float | None
    ) -> float | None:
        """``theta_s`` through the navigable rising gap nearest the goal direction."""
        n = _SECTORS
        R = self.robot_radius
        fin = np.isfinite(d)
        if not fin.any():
            return goal_dir
        dn = np.roll(d, -1)
        fin_n = np.roll(fin, -1)
        with np.errstate(invalid="ignore"):
            jump = (fin != fin_n) | (fin & fin_n & (np.abs(d - dn) > 2.0 * R))
        disc = np.flatnonzero(jump)  # a gap between sector i and i + 1
        if disc.size == 0:
            return None
        rises_ccw = dn[disc] > d[disc]  # deeper counter-clockwise of the gap: near point at i
        near = np.where(rises_ccw, disc, (disc + 1) % n)
        side = np.where(rises_ccw, 1.0, -1.0)
        # The region each gap rises into, up to the next gap in that direction.
        nxt = np.roll(disc, -1)
        prv = np.roll(disc, 1)
        reg_lo = np.where(rises_ccw, disc + 1, prv + 1) % n  # region sectors lo .. hi (ccw)
        reg_hi = np.where(rises_ccw, nxt, disc) % n
        span = (reg_hi - reg_lo) % n
        if disc.size == 1:  # one gap: the region is the rest of the circle
            span = np.full(1, n - 1)
        far_end = np.where(rises_ccw, (reg_hi + 1) % n, (reg_lo - 1) % n)
        gdir = wrap(self._angles[disc] + 0.5 * TWO_PI / n - goal_dir)
        score = np.abs(gdir) + KEEP_RIGHT * (gdir > 0)
        if last is not None:  # stay with the gap taken last time unless another is clearly nearer the goal
            score = score + _STICKY * np.abs(wrap(self._angles[disc] - last))
        order = np.argsort(score, kind="stable")
        fd = np.where(fin, d, 0.0)
        pxy = np.column_stack((fd * self._cos, fd * self._sin))
        need = self.min_gap
        for i in order:
            j = int(near[i])
            if not fin[j]:
                continue
            P = pxy[j]
            in_reg = ((k - reg_lo[i]) % n) <= span[i]
            across = pts[in_reg]
            fe = int(far_end[i])
            if fin[fe] and span[i] < n // 2:
                across = np.vstack((across, pxy[fe][None, :]))
            if len(across):
                width = float(np.hypot(across[:, 0] - P[0], across[:, 1] - P[1]).min())
            else:
                width = math.inf
            if width < need:
                continue
            clearance = min(0.5 * width, R + 0.5 * self.avoid)
            off = math.asin(min(1.0, clearance / max(float(d[j]), 1e-6)))
            return wrap(float(self._angles[j]) + float(side[i]) * off)
        return None
