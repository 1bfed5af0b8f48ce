"""The wavefront planner's executive: a plan's waypoints handed one at a time to a local planner.

:class:`Executive` does what Player's ``wavefront`` driver does with a plan (Player manual,
"wavefront"; thesis 3.4.1): it gives the local planner the next waypoint as its target, advances
within ``distance_epsilon``, finishes at the goal within ``distance_epsilon`` and ``angle_epsilon``,
and replans when the localized pose strays more than ``replan_dist_thresh`` from the rest of the
path (at most every ``replan_min_time`` seconds). The plans come from
:class:`~mrs_bridge.nav.wavefront.Wavefront`; ``mrs_bridge.nav.wavefront.Executive`` still resolves.
"""

from __future__ import annotations

import math

import numpy as np

from rsal.geometry import wrap

from .wavefront import Plan, PlanError, Wavefront, _point

__all__ = ["Executive"]


def _distance_to_polyline(p: np.ndarray, pts: np.ndarray) -> float:
    if len(pts) == 1:
        return float(np.hypot(*(p - pts[0])))
    a, b = pts[:-1], pts[1:]
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
    q = a + t[:, None] * ab
    return float(np.min(np.hypot(q[:, 0] - p[0], q[:, 1] - p[1])))


class Executive:
    """Hands a plan's waypoints one at a time to a local planner, as Player's ``wavefront`` driver.

    ``status`` is ``"idle"`` (no goal, or stopped), ``"driving"``, ``"done"`` or ``"aborted"``
    (a replan failed; :attr:`error` says why). Waypoint 0 is the start, so driving begins at
    waypoint 1. Each intermediate target's yaw points along the path to the next waypoint; the
    last target carries the goal's yaw. Times are the caller's monotonic seconds. Replanning is
    off when ``replan_dist_thresh`` or ``replan_min_time`` is negative (Player's ``-1``).
    ``distance_epsilon`` is in metres, ``angle_epsilon`` in radians (Player's configuration file
    gives degrees).
    """

    def __init__(
        self,
        planner: Wavefront,
        *,
        distance_epsilon: float = 0.5,
        angle_epsilon: float = math.radians(10),
        replan_dist_thresh: float = 2.0,
        replan_min_time: float = 2.0,
    ):
        for name, v in (("distance_epsilon", distance_epsilon), ("angle_epsilon", angle_epsilon)):
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a non-negative finite number, not {v!r}")
        self.planner = planner
        self.distance_epsilon = float(distance_epsilon)
        self.angle_epsilon = float(angle_epsilon)
        self.replan_dist_thresh = float(replan_dist_thresh)
        self.replan_min_time = float(replan_min_time)
        self.plan: Plan | None = None
        self.goal: tuple[float, float, float] | None = None
        self.status = "idle"
        self.waypoint_index = 0
        #: why the last replan failed, when ``status == "aborted"``
        self.error: PlanError | None = None
        #: plans made for the current goal after the first
        self.replans = 0
        self._t_plan = -math.inf

    # ------------------------------------------------------------------ commands
    def set_goal(self, pose, goal, now: float) -> Plan:
        """Plan from ``pose`` to ``goal`` ``(x, y[, yaw])`` and start driving; raises :class:`PlanError`."""
        gx, gy = _point(goal, "goal")
        gyaw = float(goal[2]) if len(goal) > 2 else 0.0
        plan = self.planner.plan(pose, (gx, gy))
        self.goal = (gx, gy, gyaw)
        self.replans = 0
        self._adopt(plan, now)
        return plan

    def stop(self) -> None:
        """Stop handing out targets; the goal is kept for :meth:`resume`."""
        if self.status == "driving":
            self.status = "idle"

    def resume(self, pose, now: float) -> str:
        """Replan from ``pose`` to the kept goal and drive again; returns the new status."""
        if self.goal is None or self.status == "done":
            return self.status
        return self.replan(pose, now)

    def replan(self, pose, now: float) -> str:
        """Plan again from ``pose`` to the goal now (after a map change, say); returns the new status."""
        if self.goal is None:
            return self.status
        try:
            plan = self.planner.plan(pose, self.goal[:2])
        except PlanError as e:
            self.error = e
            self.plan = None
            self.status = "aborted"
            self._t_plan = now
            return self.status
        self.replans += 1
        self._adopt(plan, now)
        return self.status

    # ------------------------------------------------------------------ per cycle
    def update(self, pose, now: float) -> tuple[np.ndarray | None, str]:
        """The local target ``(x, y, yaw)`` for the localized ``pose`` ``(x, y, yaw)``, and the status."""
        if self.status != "driving" or self.plan is None:
            return None, self.status
        x, y = float(pose[0]), float(pose[1])
        yaw = float(pose[2]) if len(pose) > 2 else 0.0
        p = np.array([x, y])
        if self._should_replan(p, now):
            if self.replan(pose, now) != "driving":
                return None, self.status
        wp = self.plan.waypoints
        last = len(wp) - 1
        while self.waypoint_index < last and math.dist((x, y), wp[self.waypoint_index]) <= self.distance_epsilon:
            self.waypoint_index += 1
        if (
            self.waypoint_index == last
            and math.dist((x, y), wp[last]) <= self.distance_epsilon
            and abs(wrap(yaw - self.goal[2])) <= self.angle_epsilon
        ):
            self.status = "done"
            return None, self.status
        return self.target(), self.status

    def target(self) -> np.ndarray | None:
        """The current waypoint as ``(x, y, yaw)``, or None without a plan."""
        if self.plan is None:
            return None
        wp = self.plan.waypoints
        i = self.waypoint_index
        if i >= len(wp) - 1:
            yaw = self.goal[2]
        else:
            yaw = math.atan2(wp[i + 1, 1] - wp[i, 1], wp[i + 1, 0] - wp[i, 0])
        return np.array([wp[i, 0], wp[i, 1], yaw])

    # ------------------------------------------------------------------ helpers
    def _adopt(self, plan: Plan, now: float) -> None:
        self.plan = plan
        self.waypoint_index = 1
        self.status = "driving"
        self.error = None
        self._t_plan = now

    def _should_replan(self, p: np.ndarray, now: float) -> bool:
        if self.replan_dist_thresh < 0 or self.replan_min_time < 0:
            return False
        if now - self._t_plan < self.replan_min_time:
            return False
        remaining = self.plan.waypoints[max(self.waypoint_index - 1, 0) :]
        return _distance_to_polyline(p, remaining) > self.replan_dist_thresh
