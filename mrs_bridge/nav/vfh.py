"""VFH+: the Vector Field Histogram local planner (Player's ``vfh`` driver, thesis 3.4.1, A.3).

Borenstein & Koren 1991, "The Vector Field Histogram -- Fast Obstacle Avoidance for Mobile
Robots", with the refinements of Ulrich & Borenstein 1998, "VFH+: Reliable Obstacle Avoidance for
Fast Mobile Robots". Each cycle:

1. **Active window.** Obstacle points within the window (``window_diameter`` cells of
   ``cell_size`` metres, centred on the robot) mark their grid cells occupied. Every occupied cell
   has a magnitude ``m = c (a - d)^4`` that grows as its distance ``d`` shrinks (``a`` is the
   window radius; ``c = 1e4 m^-4``, the scale of Player's driver, so its unitless cutoffs mean the
   same here). A wall straight ahead sums to about 1.1e6 in its sector at 1 m, 2.2e6 at 0.6 m
   and 3.4e5 at 1.5 m; a single cell stays below 4e5 -- small obstacles are kept clear of by the
   enlargement and the motion guard. Lower cutoffs are more cautious. Cell geometry is tabulated
   once.
2. **Primary polar histogram** (VFH+ enlargement). A cell at direction ``beta`` adds its
   magnitude to every sector within ``beta +- asin(r_rs / d)``, ``r_rs`` being the robot radius
   plus the speed-dependent safety distance (``safety_dist_0ms`` .. ``safety_dist_1ms``): the
   histogram is that of a point robot among obstacles grown by ``r_rs``. All cells are added in
   one pass with difference arrays (``bincount`` + ``cumsum``).
3. **Binary histogram with hysteresis.** A sector is blocked above ``obs_cutoff``, free below
   ``free_space_cutoff`` and keeps its last state in between (both interpolated for the speed).
4. **Masked histogram.** Directions that the robot cannot turn into at its current speed without
   hitting a cell are blocked: the left and right turning circles have radius
   ``v / max_turnrate(v) * min_turn_radius_safety_factor``; a cell closer than that radius plus
   ``r_rs`` to a circle's centre blocks every direction beyond it on that side.
5. **Direction.** Openings are runs of free sectors. A narrow one (up to 80 degrees) offers its
   centre; a wide one its two sides 40 degrees in from the borders, and the goal direction if it
   lies between them. The candidate with the least ``weight_desired_dir * |to goal| +
   weight_current_dir * |to the last chosen direction|`` wins (the last direction is kept in the
   odometry frame; a candidate left of the goal pays :data:`~mrs_bridge.nav.local.KEEP_RIGHT`
   extra, so ties go right).
6. **Speed.** ``max_speed_narrow_opening`` or ``max_speed_wide_opening`` (never above
   ``max_speed``), reduced by the obstacle density straight ahead and by the angle still to turn;
   turn rate proportional to that angle, at least ``min_turnrate`` and at most ``max_turnrate``
   interpolated between ``max_turnrate_0ms`` and ``max_turnrate_1ms``.

No free sector at all for more than a second, or no progress in 10 s, is status ``blocked``; the
escape (``escape_speed``, ``escape_time``, ``escape_max_turnrate``; Player's default 0 disables
it) backs the robot up, where it has looked lately, while turning to the more open side.

Parameters are Player's, in its units (m, m/s, deg, deg/s); ``*_0ms``/``*_1ms`` pairs are linear
in the speed, and ``min_turn_radius_safety_factor`` is accepted too. Defaults are Player's except
where marked "tuned" (the closed-loop sweep of ``benchmarks/bench_local.py --trials`` -- random
2-5 m runs on the floor map past a box that is not on the map, two other robots crossing -- showed
a better value) or "project" (chosen for the project's Pioneers at 10 Hz, not swept). Notably the
cutoffs: the sweep favoured ``free_space_cutoff_0ms`` 1e6 with the ``obs_cutoff`` pair at twice
the free ones (hysteresis) over Player's 2e6 without, and showed 4e6 and above failing most runs
(the robot then only ever stops at the motion guard).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rsal.geometry import TWO_PI, wrap

from .local import KEEP_RIGHT, LocalPlanner, Param

__all__ = ["VFH"]

_MAG_SCALE = 1.0e4  # m^-4: cell magnitude scale (Player's cutoff values keep their meaning)
_WIDE_OPENING = math.radians(80.0)  # openings wider than this are "wide" (VFH+ s_max)
_TURN_GAIN = 1.2  # 1/s: turn rate per radian to the chosen direction
_STOP_TURN_ANGLE = math.radians(70.0)  # no forward speed while the chosen direction is this far off
_BLOCKED_AFTER = 1.0  # s with every sector blocked before status "blocked"
_STUCK = (10.0, 0.15, math.radians(20.0), 20.0)  # s, m, rad, s: no-progress detection


class VFH(LocalPlanner):
    """VFH+ local planner with Player's ``vfh`` driver's parameters."""

    name = "vfh"
    PARAMS = {
        "cell_size": Param(0.1, 0.01, 1.0, "m", "local occupancy grid cell size"),
        "window_diameter": Param(61, 5, 401, "cells", "active window side, in cells", integer=True),
        "sector_angle": Param(5, 1, 45, "deg", "histogram sector width (must divide 360)", integer=True),
        "safety_dist_0ms": Param(0.1, 0.0, 2.0, "m", "clearance kept to obstacles when stopped"),
        "safety_dist_1ms": Param(None, 0.0, 2.0, "m", "clearance kept at 1 m/s", same_as="safety_dist_0ms"),
        "max_speed": Param(0.4, 0.0, 5.0, "m/s", "top forward speed (thesis A.3; Player 0.2)"),
        "max_speed_narrow_opening": Param(
            None, 0.0, 5.0, "m/s", "top speed through narrow openings", same_as="max_speed"
        ),
        "max_speed_wide_opening": Param(None, 0.0, 5.0, "m/s", "top speed through wide openings", same_as="max_speed"),
        "max_acceleration": Param(0.3, 0.01, 10.0, "m/s^2", "speeding-up limit (project; Player 0.2)"),
        "min_turnrate": Param(10.0, 0.0, 360.0, "deg/s", "least turn rate when turning"),
        "max_turnrate_0ms": Param(60.0, 1.0, 720.0, "deg/s", "turn rate limit when stopped (project; Player 40)"),
        "max_turnrate_1ms": Param(None, 1.0, 720.0, "deg/s", "turn rate limit at 1 m/s", same_as="max_turnrate_0ms"),
        "min_turn_radius_safety_factor": Param(1.0, 0.0, 10.0, "", "scales the turning circles of the mask"),
        "free_space_cutoff_0ms": Param(1.0e6, 0.0, math.inf, "", "below: sector free, stopped (tuned; Player 2e6)"),
        "obs_cutoff_0ms": Param(
            None,
            0.0,
            math.inf,
            "",
            "above: sector blocked, stopped (tuned: 2 x free; Player: = free)",
            same_as="free_space_cutoff_0ms",
            factor=2.0,
        ),
        "free_space_cutoff_1ms": Param(
            None, 0.0, math.inf, "", "below: sector free at 1 m/s", same_as="free_space_cutoff_0ms"
        ),
        "obs_cutoff_1ms": Param(
            None,
            0.0,
            math.inf,
            "",
            "above: sector blocked at 1 m/s (tuned: 2 x free; Player: = free)",
            same_as="free_space_cutoff_1ms",
            factor=2.0,
        ),
        "weight_desired_dir": Param(5.0, 0.0, 1000.0, "", "cost weight of the angle to the goal"),
        "weight_current_dir": Param(1.0, 0.0, 1000.0, "", "cost weight of the angle to the last direction"),
        "distance_epsilon": Param(0.5, 0.01, 10.0, "m", "goal position tolerance"),
        "angle_epsilon": Param(10.0, 0.1, 180.0, "deg", "goal yaw tolerance"),
        "escape_speed": Param(0.1, 0.0, 2.0, "m/s", "backing-up speed when blocked (project; Player 0: off)"),
        "escape_time": Param(2.0, 0.0, 60.0, "s", "duration of one escape (project; Player 0: off)"),
        "escape_max_turnrate": Param(30.0, 0.0, 360.0, "deg/s", "turn rate while escaping (project; Player 0: off)"),
    }

    # ------------------------------------------------------------------ configuration
    def _configure(self, p: dict[str, Any]) -> None:
        if 360 % p["sector_angle"]:
            raise ValueError(
                f"vfh: parameter 'sector_angle' = {p['sector_angle']!r} is invalid; expected a divisor of 360 in "
                "[1, 45] deg (e.g. 5)"
            )
        for speed in ("0ms", "1ms"):
            lo, hi = p[f"free_space_cutoff_{speed}"], p[f"obs_cutoff_{speed}"]
            if hi < lo:
                raise ValueError(
                    f"vfh: parameter 'obs_cutoff_{speed}' = {hi!r} is invalid; expected at least "
                    f"free_space_cutoff_{speed} = {lo!r} (the blocked threshold is the upper one)"
                )
        self.robot_radius = self._radius(0.25)
        self.v_max = p["max_speed"]
        self.v_narrow = min(p["max_speed_narrow_opening"], self.v_max)
        self.v_wide = min(p["max_speed_wide_opening"], self.v_max)
        self.w0 = math.radians(p["max_turnrate_0ms"])
        self.w1 = math.radians(p["max_turnrate_1ms"])
        self.w_max = max(self.w0, self.w1)
        self.turn_min = math.radians(p["min_turnrate"])
        self.pos_tol = p["distance_epsilon"]
        self.ang_tol = math.radians(p["angle_epsilon"])
        self.accel = p["max_acceleration"]
        self.brake = p["max_acceleration"]
        self.escape_speed = p["escape_speed"]
        self.escape_turnrate = math.radians(p["escape_max_turnrate"])
        self.escape_time = p["escape_time"]
        self.blocked_after = _BLOCKED_AFTER
        self.stuck_time, self.stuck_dist, self.stuck_angle, self.rotate_stuck_time = _STUCK
        self._s0, self._s1 = p["safety_dist_0ms"], p["safety_dist_1ms"]
        self._free0, self._free1 = p["free_space_cutoff_0ms"], p["free_space_cutoff_1ms"]
        self._obs0, self._obs1 = p["obs_cutoff_0ms"], p["obs_cutoff_1ms"]
        self._w_des, self._w_cur = p["weight_desired_dir"], p["weight_current_dir"]
        self._turn_factor = p["min_turn_radius_safety_factor"]
        # Sectors and the tabulated window.
        self._alpha = math.radians(p["sector_angle"])
        self._n = 360 // p["sector_angle"]
        self._wide = max(1, int(round(_WIDE_OPENING / self._alpha)))
        self._cell = p["cell_size"]
        self._side = int(p["window_diameter"])
        self._half = self._side // 2
        c = (np.arange(self._side) - self._half) * self._cell  # cell centres, robot at a centre
        cx, cy = np.meshgrid(c, c, indexing="ij")
        radius = self._half * self._cell
        d = np.hypot(cx, cy).ravel()
        inside = (d <= radius) & (d > 0.0)
        self._cx, self._cy = cx.ravel(), cy.ravel()
        self._cd = np.where(d > 0.0, d, 1e-9)
        self._cbeta = np.arctan2(self._cy, self._cx)
        self._cmag = np.where(inside, _MAG_SCALE * (radius - d) ** 4, 0.0)
        self._radius_w = radius
        self._sector_dirs = wrap(np.arange(self._n) * self._alpha)

    def safety(self, speed: float) -> float:
        return max(0.0, self._s0 + (self._s1 - self._s0) * abs(speed))

    def max_turnrate(self, speed: float) -> float:
        """Turn-rate limit (rad/s) at ``speed`` m/s."""
        return max(self.w0 + (self.w1 - self.w0) * abs(speed), 1e-3)

    def _reset_algorithm(self) -> None:
        self._binary = np.zeros(self._n, dtype=bool)
        self._last_dir: float | None = None  # odometry-frame direction chosen last cycle
        self.histogram = np.zeros(self._n)  # last primary polar histogram (for inspection)

    # ------------------------------------------------------------------ the algorithm
    def _cells(self, pts: np.ndarray) -> np.ndarray:
        """Flat indices of the window cells that hold at least one point."""
        if len(pts) == 0:
            return np.empty(0, dtype=np.int64)
        ij = np.floor(pts / self._cell + 0.5).astype(np.int64) + self._half
        ok = (ij >= 0).all(axis=1) & (ij < self._side).all(axis=1)
        flat = ij[ok, 0] * self._side + ij[ok, 1]
        grid = np.zeros(self._side * self._side, dtype=bool)
        grid[flat] = True
        cells = np.flatnonzero(grid)
        return cells[self._cmag[cells] > 0.0]

    def polar_histogram(self, pts: np.ndarray, speed: float = 0.0) -> np.ndarray:
        """The primary polar histogram (sector ``k`` at ``k * sector_angle``, counter-clockwise)."""
        return self._histogram(self._cells(pts), speed)

    def _histogram(self, cells: np.ndarray, speed: float) -> np.ndarray:
        n = self._n
        if cells.size == 0:
            return np.zeros(n)
        r_rs = self.robot_radius + self.safety(speed)
        d = self._cd[cells]
        beta = self._cbeta[cells]
        gamma = np.maximum(np.arcsin(np.minimum(r_rs / d, 1.0)), 0.5 * self._alpha)
        lo = np.ceil((beta - gamma) / self._alpha - 1e-9).astype(np.int64) + 2 * n
        hi = np.floor((beta + gamma) / self._alpha + 1e-9).astype(np.int64) + 2 * n + 1
        m = self._cmag[cells]
        size = 4 * n + 1
        acc = np.bincount(lo, m, size) - np.bincount(hi, m, size)
        return np.cumsum(acc[:-1]).reshape(4, n).sum(axis=0)

    def _turn_mask(self, cells: np.ndarray, speed: float) -> np.ndarray:
        """Sectors that the robot cannot turn into without sweeping over an occupied cell."""
        blocked = np.zeros(self._n, dtype=bool)
        if cells.size == 0:
            return blocked
        r_rs = self.robot_radius + self.safety(speed)
        r_turn = abs(speed) / self.max_turnrate(speed) * self._turn_factor
        x, y, beta = self._cx[cells], self._cy[cells], self._cbeta[cells]
        reach = (r_turn + r_rs) ** 2
        right = (beta < 0.0) & (x * x + (y + r_turn) ** 2 < reach)
        left = (beta > 0.0) & (x * x + (y - r_turn) ** 2 < reach)
        dirs = self._sector_dirs
        if right.any():
            phi_r = float(beta[right].max())
            blocked |= dirs < phi_r
        if left.any():
            phi_l = float(beta[left].min())
            blocked |= dirs > phi_l
        return blocked

    def _plan(self, goal, dist, pts, speed, pose, dt):
        v_now = max(speed[0], 0.0)
        cells = self._cells(pts)
        hist = self._histogram(cells, v_now)
        self.histogram = hist
        lo_cut = self._free0 + (self._free1 - self._free0) * v_now
        hi_cut = self._obs0 + (self._obs1 - self._obs0) * v_now
        binary = np.where(hist > hi_cut, True, np.where(hist < lo_cut, False, self._binary))
        self._binary = binary
        blocked = binary | self._turn_mask(cells, v_now)
        goal_dir = math.atan2(goal[1], goal[0])
        yaw = pose[2]
        last = goal_dir if self._last_dir is None else wrap(self._last_dir - yaw)
        choice = self._choose(blocked, goal_dir, last)
        if choice is None:
            # Nowhere to go: turn slowly towards the least dense side.
            k = int(np.argmin(hist))
            turn = self._sector_dirs[k]
            return 0.0, math.copysign(self.turn_min, turn if turn != 0 else 1.0), False
        theta, narrow = choice
        self.heading_wanted = theta
        self._last_dir = wrap(theta + yaw)
        v_cap = self.v_narrow if narrow else self.v_wide
        v = v_cap * max(0.0, 1.0 - hist[0] / max(hi_cut, 1.0))  # slower the denser it is straight ahead
        v *= max(0.0, 1.0 - abs(theta) / _STOP_TURN_ANGLE)
        w_lim = self.max_turnrate(v_now)
        w = float(np.clip(_TURN_GAIN * theta, -w_lim, w_lim))
        if abs(theta) > 0.5 * self._alpha and abs(w) < self.turn_min:
            w = math.copysign(min(self.turn_min, w_lim), theta)
        return v, w, True

    def _choose(self, blocked: np.ndarray, goal_dir: float, last: float) -> tuple[float, bool] | None:
        """The direction to steer (robot frame, rad) and whether its opening is narrow."""
        a = self._alpha
        if blocked.all():
            return None
        if not blocked.any():
            return goal_dir, False
        k0 = int(np.argmax(blocked))  # start the circular scan at a blocked sector
        free = np.roll(~blocked, -k0).astype(np.int8)
        edges = np.diff(np.concatenate(([0], free, [0])))
        starts = np.flatnonzero(edges == 1)
        ends = np.flatnonzero(edges == -1) - 1
        width = ends - starts + 1
        right = (starts + k0) * a  # direction of the first free sector going counter-clockwise
        left = right + (width - 1) * a
        narrow = width <= self._wide
        half = 0.5 * self._wide * a
        cand = [np.where(narrow, 0.5 * (right + left), right + half)]
        kind = [narrow]
        wide = ~narrow
        if wide.any():
            cand.append((left - half)[wide])
            kind.append(narrow[wide])
            # The goal direction, if it lies inside a wide opening between its two side candidates.
            rel = (goal_dir - (right + half)) % TWO_PI
            inside = wide & (rel <= (left - right - 2 * half) + 1e-9)
            if inside.any():
                cand.append(np.array([goal_dir]))
                kind.append(np.array([False]))
        c = wrap(np.concatenate(cand))
        narrow_c = np.concatenate(kind)
        to_goal = wrap(c - goal_dir)
        cost = self._w_des * (np.abs(to_goal) + KEEP_RIGHT * (to_goal > 0)) + self._w_cur * np.abs(wrap(c - last))
        i = int(np.argmin(cost))
        return float(c[i]), bool(narrow_c[i])
