"""ND: Nearness Diagram navigation (Player's ``nd`` driver, thesis 3.4.1).

Minguez & Montano 2004, "Nearness Diagram (ND) Navigation: Collision Avoidance in Troublesome
Scenarios" (IEEE Trans. Robotics and Automation 20(1)). A divide-and-conquer reactive method: the
situation the robot is in picks the motion law. Each cycle:

1. **Nearness diagram.** The obstacle points within ``obstacle_avoid_dist`` are binned into 360
   one-degree sectors around the robot's centre (nearest point per sector; empty sectors are free).
   ``E[k]`` is the distance from the centre to the boundary of the rectangular base
   (``robot_geometry``) in the direction of sector ``k``, so ``d[k] - E[k]`` is the gap between the
   robot's body and the obstacle.
2. **Regions and valleys.** A *discontinuity* lies between neighbouring sectors whose depths differ
   by more than the robot's diameter (or where one is free). The sectors between two
   discontinuities form a region; a region is a *valley* when the depth rises into it across at
   least one of its discontinuities (a *rising* discontinuity).
3. **Region selection.** If a disc of the robot's radius plus ``safety_dist`` can travel straight
   to the goal, the goal direction is the target. Otherwise the valleys are tried nearest the goal
   first (of two about equally near, the one clockwise of the goal: keep right): a valley is taken
   when it is *navigable* -- its rising discontinuity nearest the goal leaves a gap (from the near
   obstacle point across to the closest obstacle point beyond it) at least the robot's diameter
   plus twice ``safety_dist`` plus 0.1 m wide. The target is the centre of that gap when it is
   narrow, else the direction that passes the gap's near point with the robot's radius plus
   ``avoid_dist`` to spare. No navigable valley: no free direction.
4. **Situations.** High safety (no obstacle inside the security zone of ``avoid_dist`` around the
   body): head for the target (the goal region, wide region and narrow region situations differ
   only in the target of step 3). Low safety: every obstacle within the zone pushes the heading
   away from itself -- at least ``90 deg * (1 - gap / avoid_dist)`` from its direction, and far
   enough that the straight path passes it with the robot's radius plus ``safety_dist`` to spare.
   With obstacles on one side only (situation LS1) the heading is turned away from them; with
   obstacles on both sides (LS2) it is kept in the cone between them, split down the middle when
   both push harder than the cone allows. An obstacle dead ahead counts as on the left (keep
   right).
5. **Motion.** Speed ``max_speed[0]`` scaled by how deep the nearest obstacle ahead is inside the
   zone and by the angle still to turn (none beyond 90 degrees); turn rate ``max_speed[1]`` scaled
   by that angle over 45 degrees; non-zero commands are at least ``min_speed``.

Stuck detection uses Player's options: no free direction (turning on the spot) for
``rotate_stuck_time``, or -- judged once per ``translate_stuck_time`` -- neither
``translate_stuck_dist`` of net progress (closer to the goal or away from where the window began)
nor ``translate_stuck_angle`` of net turn, is status ``blocked``; the escape then turns the robot
for 2 s at 30 deg/s towards the more open side, backing up at 0.1 m/s where the space behind has
been in view (Player's driver only waits).

Parameters are Player's, in its units (m, m/s, deg, deg/s). ``robot_geometry`` ``[length, width]``
(an addition, Player reads it from the base) defaults to the base's geometry given to the
constructor, else 0.44 x 0.38 m (a Pioneer 2DX). Defaults differ from Player's where marked "tuned"
(the closed-loop sweep of ``benchmarks/bench_local.py --trials`` showed a better value) or
"project" (chosen for the project's Pioneers at 10 Hz, not swept).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rsal.geometry import TWO_PI, wrap

from .local import KEEP_RIGHT, LocalPlanner, Param, corridor_clear

__all__ = ["ND"]

_SECTORS = 360
_TURN_SCALE = math.radians(45.0)  # turn rate saturates at this angle to the target
_ESCAPE = (0.1, math.radians(30.0), 2.0)  # m/s, rad/s, s
_GAP_SPARE = 0.1  # m of room a navigable gap leaves beyond the robot's disc and safety distance


class ND(LocalPlanner):
    """Nearness Diagram navigation with Player's ``nd`` driver's parameters."""

    name = "nd"
    PARAMS = {
        "max_speed": Param(
            (0.4, 60.0),
            (0.0, 1.0),
            (5.0, 720.0),
            "m/s, deg/s",
            "top forward speed and turn rate (project; Player [0.3 45])",
            size=2,
        ),
        "min_speed": Param(
            (0.05, 10.0), (0.0, 0.0), (1.0, 180.0), "m/s, deg/s", "least non-zero forward speed and turn rate", size=2
        ),
        "obstacle_avoid_dist": Param(2.0, 0.5, 50.0, "m", "obstacles farther than this are ignored (tuned)"),
        "safety_dist": Param(0.1, 0.0, 2.0, "m", "clearance always kept to obstacles (project; Player 0)"),
        "goal_tol": Param((0.5, 10.0), (0.01, 0.1), (10.0, 180.0), "m, deg", "goal position and yaw tolerance", size=2),
        "avoid_dist": Param(0.4, 0.05, 5.0, "m", "width of the security zone around the body"),
        "rotate_stuck_time": Param(
            5.0, 0.1, 600.0, "s", "turning without moving this long is stuck (project; Player 10)"
        ),
        "translate_stuck_time": Param(10.0, 0.1, 600.0, "s", "time in which the robot must make progress"),
        "translate_stuck_dist": Param(0.15, 0.0, 5.0, "m", "progress: moving this far ..."),
        "translate_stuck_angle": Param(10.0, 0.0, 180.0, "deg", "... or turning this much"),
        "robot_geometry": Param(None, (0.05, 0.05), (5.0, 5.0), "m, m", "base length and width", size=2),
    }

    def _configure(self, p: dict[str, Any]) -> None:
        geom = p["robot_geometry"] or self.geometry or (0.44, 0.38)
        self.length, self.width = float(geom[0]), float(geom[1])
        self.robot_radius = 0.5 * math.hypot(self.length, self.width)
        self.v_max, self.w_max = p["max_speed"][0], math.radians(p["max_speed"][1])
        self.v_min, self.w_min = min(p["min_speed"][0], self.v_max), min(math.radians(p["min_speed"][1]), self.w_max)
        self.turn_min = self.w_min
        self.pos_tol, self.ang_tol = p["goal_tol"][0], math.radians(p["goal_tol"][1])
        self.accel = None
        self.brake = 0.5
        self.escape_speed, self.escape_turnrate, self.escape_time = _ESCAPE
        self.blocked_after = p["rotate_stuck_time"]
        self.rotate_stuck_time = max(p["rotate_stuck_time"], p["translate_stuck_time"])
        self.stuck_time = p["translate_stuck_time"]
        self.stuck_dist = p["translate_stuck_dist"]
        self.stuck_angle = math.radians(p["translate_stuck_angle"])
        self._safety = p["safety_dist"]
        self._range = p["obstacle_avoid_dist"]
        self._ds = p["avoid_dist"]
        n = _SECTORS
        self._angles = wrap(np.arange(n) * (TWO_PI / n))
        c, s = np.abs(np.cos(self._angles)), np.abs(np.sin(self._angles))
        with np.errstate(divide="ignore"):
            self._E = np.minimum(0.5 * self.length / c, 0.5 * self.width / s)  # centre to body edge

    def safety(self, speed: float) -> float:
        return self._safety

    def _reset_algorithm(self) -> None:
        self.situation = ""  # last situation: "GR", "WR", "NR" (target kind) + "HS"/"LS1"/"LS2"

    # ------------------------------------------------------------------ the algorithm
    def _plan(self, goal, dist, pts, speed, pose, dt):
        n = _SECTORS
        r = np.hypot(pts[:, 0], pts[:, 1]) if len(pts) else np.empty(0)
        keep = r < self._range
        p, r = pts[keep], r[keep]
        ang = np.arctan2(p[:, 1], p[:, 0])
        k = np.rint(ang * (n / TWO_PI)).astype(np.int64) % n
        d = np.full(n, np.inf)
        np.minimum.at(d, k, r)
        goal_dir = math.atan2(goal[1], goal[0])
        clear = self.robot_radius + self._safety
        if corridor_clear(p, goal_dir, dist, clear):
            target, kind = goal_dir, "GR"
        else:
            found = self._target(d, k, p, goal_dir)
            if found is None:
                self.situation = "blocked"
                return 0.0, math.copysign(self.w_min, goal_dir), False
            target, kind = found
        # Security zone: gaps between body and obstacles.
        gap = d - self._E
        zone = gap < self._ds
        theta = target
        v_scale = 1.0
        if zone.any():
            theta, sides = self._deflect(target, d, gap, zone)
            kind += "LS2" if sides == 2 else "LS1"
            ahead = zone & (np.abs(self._angles) < 0.5 * math.pi)
            if ahead.any():
                v_scale = float(np.clip(gap[ahead].min() / self._ds, 0.0, 1.0))
        else:
            kind += "HS"
        self.situation = kind
        self.heading_wanted = theta
        v = self.v_max * v_scale * max(0.0, 1.0 - abs(theta) / (0.5 * math.pi))
        if 0.0 < v < self.v_min:
            v = self.v_min
        w = self.w_max * float(np.clip(theta / _TURN_SCALE, -1.0, 1.0))
        if abs(theta) > math.radians(1.0) and abs(w) < self.w_min:
            w = math.copysign(self.w_min, theta)
        return v, w, True

    def _target(self, d: np.ndarray, k: np.ndarray, p: np.ndarray, goal_dir: float) -> tuple[float, str] | None:
        """Target direction through the navigable valley nearest the goal, and its kind."""
        n = _SECTORS
        fin = np.isfinite(d)
        if not fin.any():
            return goal_dir, "GR"
        dn = np.roll(d, -1)
        fin_n = np.roll(fin, -1)
        with np.errstate(invalid="ignore"):
            jump = (fin != fin_n) | (fin & fin_n & (np.abs(d - dn) > 2.0 * self.robot_radius))
        disc = np.flatnonzero(jump)  # a discontinuity between sector i and i + 1
        if disc.size == 0:
            return None  # one closed region all round: nowhere to go
        deeper_next = dn > d  # inf > finite is True; the region after i is deeper
        start = disc + 1  # region j: sectors start[j] .. end[j] (unwrapped)
        end = np.roll(disc, -1) + np.where(np.arange(disc.size) == disc.size - 1, n, 0)
        rise_r = deeper_next[disc]  # rising into the region across its right (clockwise) end
        rise_l = ~deeper_next[np.roll(disc, -1)]  # ... across its left end
        valley = rise_r | rise_l
        if not valley.any():
            return None
        kg = int(round(goal_dir * n / TWO_PI)) % n
        off_s = (kg - start) % n
        inside = off_s <= end - start
        to_r = np.minimum(off_s, n - off_s)  # sectors from the goal to each region's right end
        off_e = (kg - end) % n
        to_l = np.minimum(off_e, n - off_e)  # ... and to its left end
        # Valleys nearest the goal first (a goal inside the valley counts as 0).
        score = np.minimum(np.where(rise_r, to_r, n), np.where(rise_l, to_l, n))
        score = np.where(inside, 0, score)
        # Keep right: of two valleys about as near the goal, prefer the one clockwise of it.
        left_of_goal = ((start - kg) % n) < (n // 2)
        score = score + np.where(left_of_goal & ~inside, int(round(KEEP_RIGHT * n / TWO_PI)), 0)
        score = np.where(valley, score, n + 1)
        fd = np.where(fin, d, 0.0)
        xy = np.column_stack((fd * np.cos(self._angles), fd * np.sin(self._angles)))  # sector points
        for j in np.argsort(score, kind="stable"):
            if not valley[j]:
                break
            s_j, e_j = int(start[j]), int(end[j])
            # (distance to goal, near sector, side of the opening, sector across the region)
            ends = []
            if rise_r[j]:
                ends.append((to_r[j], (s_j - 1) % n, 1.0, (e_j + 1) % n))
            if rise_l[j]:
                ends.append((to_l[j], (e_j + 1) % n, -1.0, (s_j - 1) % n))
            ends.sort(key=lambda t: t[0])
            in_region = ((k - s_j) % n) <= (e_j - s_j)
            for _, near, side, other in ends:
                if not fin[near]:
                    continue
                P = xy[near]
                across = p[in_region]
                if fin[other] and e_j - s_j < n // 2:  # the far end is across the gap, not behind
                    across = np.vstack((across, xy[other][None, :]))
                if len(across):
                    dq = np.hypot(across[:, 0] - P[0], across[:, 1] - P[1])
                    iq = int(np.argmin(dq))
                    w_gap, Q = float(dq[iq]), across[iq]
                else:
                    w_gap, Q = math.inf, None
                if w_gap < 2.0 * (self.robot_radius + self._safety) + _GAP_SPARE:
                    continue  # the robot does not fit through this gap
                if Q is not None and w_gap < 2.0 * (self.robot_radius + self._ds):
                    mid = 0.5 * (P + Q)  # narrow: through the middle of the gap
                    return math.atan2(mid[1], mid[0]), "NR"
                off = math.asin(min(1.0, (self.robot_radius + self._ds) / max(float(d[near]), 1e-6)))
                return wrap(float(self._angles[near]) + side * off), "WR"
        return None

    def _deflect(self, target: float, d: np.ndarray, gap: np.ndarray, zone: np.ndarray) -> tuple[float, int]:
        """Turn the heading away from the obstacles in the zone on each side of the target: at
        least ``90 deg * (1 - gap / avoid_dist)`` from each, and far enough that the straight path
        passes it with the robot's radius plus ``safety_dist`` to spare."""
        rel = wrap(self._angles - target + KEEP_RIGHT)  # keep right: dead ahead counts as left
        prox = np.clip(gap / self._ds, 0.0, 1.0)
        clear = np.arcsin(np.minimum(1.0, (self.robot_radius + self._safety) / np.maximum(d, 1e-6)))
        margin = np.maximum(0.5 * math.pi * (1.0 - prox), clear)  # required angle heading-obstacle
        left = zone & (rel > 0.0)
        right = zone & (rel <= 0.0)
        lo, hi = -math.pi, math.pi
        if left.any():
            hi = float((rel[left] - margin[left]).min())
        if right.any():
            lo = float((rel[right] + margin[right]).max())
        sides = int(left.any()) + int(right.any())
        if lo <= hi:
            theta = min(max(KEEP_RIGHT, lo), hi)
        else:  # pushed harder from both sides than the cone between allows: split the difference
            theta = 0.5 * (lo + hi)
        return wrap(target + theta - KEEP_RIGHT), sides
