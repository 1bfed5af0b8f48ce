"""The navigating robot agent (thesis 3.6.1 fig. 3.9 NavAgent, 3.4.1, appendix A.3).

:class:`NavAgent` controls a :class:`rsal.robot.NavRobot` — a robot with ``amcl`` localization and a
``wavefront`` planner, as ``rsal sim WORLD --nav vfh`` serves them. It publishes the robot's
localized pose on ``send_position`` (map frame) and drives to every goal that another agent sends it
on ``new_goal`` (the thesis's NewGoalService); a newer goal supersedes the older one. A goal that
ends is reported on ``outcome``: ``arrived`` with ``ok`` true when reached, false when the planner
refused it (unreachable), aborted it or it was not reached within ``goal_timeout`` seconds. Agents
in the same process use ``await agent.goto(x, y, yaw)``. Scenarios build on it: the hunters of Hunt
and Prey (:mod:`agents.scenarios.hunt`), the robots the Distribution scenario spreads out.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from dataclasses import dataclass

from rsal.clock import clock, wait_for
from rsal.data import Position
from rsal.msgs import ErrorCode, RpcError
from rsal.robot import NavRobot, RobotError

from .classes import RobotAgent
from .registry import agent_class
from .services import Message, NewGoal, Outcome, SendPosition, match

__all__ = ["GoalResult", "NavAgent", "number_arg"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GoalResult:
    """How a goal ended: ``status`` is ``done``, ``unreachable`` (refused by the planner),
    ``aborted`` (the planner gave it up on the way), ``timeout``, ``superseded`` (a newer goal
    replaced it) or ``failed`` (the planner could not be asked); ``message`` says why."""

    status: str
    message: str = ""
    goal: Position | None = None
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.status == "done"


def number_arg(agent_id: str, name: str, value, lo: float, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (lo < value <= hi):
        rng = f"({lo:g}, {hi:g}]" if math.isfinite(hi) else f"> {lo:g}"
        raise ValueError(f"agent {agent_id}: {name} {value!r} must be a number {rng}")
    return float(value)


@agent_class("NavAgent")
class NavAgent(RobotAgent):
    """Drives a NavRobot to goals on the map (thesis fig. 3.9 NavAgent): ``new_goal`` messages with
    ``to`` equal to its id, or :meth:`goto` from an agent of the same process."""

    capabilities = ("send_position", "new_goal")
    needs = ("planner", "localize")

    def __init__(
        self,
        agent_id: str,
        *,
        goal_timeout: float = 300.0,
        **kw,
    ):
        super().__init__(agent_id, **kw)
        self.goal_timeout = number_arg(agent_id, "goal_timeout", goal_timeout, 0.0)
        self.goal: Position | None = None  # the goal being driven to
        self.goal_state = "idle"  # idle, driving, or the status of the last GoalResult
        self.reached = 0  # goals reached
        self.failed = 0  # goals that ended otherwise (superseded ones not counted)
        self._goal_seq = 0
        self._goal_task: asyncio.Task | None = None
        self._send_lock: asyncio.Lock | None = None

    # ------------------------------------------------------------------ robot
    @property
    def nav(self) -> NavRobot | None:
        """The robot (None until found)."""
        return self.pioneer  # type: ignore[return-value]

    def make_robot(self, devices: list) -> NavRobot:
        robot = NavRobot(devices, name=self.robot, period=self.period, laser=self.laser)
        if robot.localized is None:  # amcl's position2d not announced (or not answering) yet
            raise RobotError(
                f"robot {self.robot!r}: no localized position2d (amcl, frame 'map') appeared within "
                f"{self.startup_timeout:g} s; serve the robot with its navigation stack ('rsal sim WORLD --nav vfh')"
            )
        if self.start_pose is not None:  # amcl starts around the given pose instead of its own init_pose
            try:
                robot.localize.set_position(self.start_pose)
            except RpcError as e:
                raise RobotError(f"robot {self.robot!r}: cannot set its start pose: {e}") from None
        return robot

    def pose_message(self) -> SendPosition | None:
        r = self.nav
        if r is None:
            return None
        pose = r.position
        if pose is None:
            return None
        localized = (r.localized is not None and r.localized.latest is not None) or (
            r.localize is not None and getattr(r.localize, "position", None) is not None
        )
        return SendPosition(self.robot, pose.x, pose.y, pose.yaw, "map" if localized else "odom")

    # ------------------------------------------------------------------ lifecycle
    async def created(self) -> None:
        self._send_lock = asyncio.Lock()
        await super().created()
        self.subscribe(NewGoal.SERVICE, self._on_new_goal, filter=match(to=self.id))

    async def killed(self) -> None:
        self._goal_seq += 1  # nothing pending is sent any more
        if self._goal_task is not None and not self._goal_task.done():
            self._goal_task.cancel()
        await super().killed()

    def _on_new_goal(self, msg: Message) -> None:
        g: NewGoal = msg.body
        log.info("%s: new goal (%.2f, %.2f) from %s", self.id, g.x, g.y, msg.sender)
        self._goal_task = self.start_goal(Position(g.x, g.y, g.yaw), report=True)

    # ------------------------------------------------------------------ goals
    def start_goal(self, goal: Position, *, report: bool = True) -> asyncio.Task:
        """Drive to ``goal`` (map frame) in a task of the host; it supersedes any earlier goal. The
        task's result is a :class:`GoalResult`; with ``report`` the end is published as ``arrived``."""
        self._goal_seq += 1
        self.goal = goal
        self.goal_state = "driving"
        return self._require_host().spawn(self._drive(goal, self._goal_seq, report), f"{self.id}: goal")

    async def goto(self, x: float, y: float, yaw: float = 0.0, *, report: bool = True) -> GoalResult:
        """Drive to ``(x, y, yaw)`` (map frame, m, m, rad) and return how the goal ended."""
        self._goal_task = self.start_goal(Position(x, y, yaw), report=report)
        return await asyncio.shield(self._goal_task)

    async def stop_robot(self) -> None:
        """Stop the robot (the planner's goal is kept but not driven) without blocking the loop."""
        self._goal_seq += 1
        self.goal_state = "stopped"
        r = self.nav
        if r is not None:
            try:
                await asyncio.to_thread(r.stop)
            except Exception as e:  # the planner may be unreachable; the base is stopped anyway
                log.warning("%s: stopping %s: %s", self.id, self.robot, e)

    async def _send(self, goal: Position, seq: int):
        """Send the goal to the planner; a planner still waiting for its map or first pose is
        asked again until ``startup_timeout``. Returns the goal's future, or None if superseded."""
        assert self._send_lock is not None
        async with self._send_lock:  # one set_goal at a time, so that they reach the planner in order
            ready_by = time.monotonic() + self.startup_timeout
            while True:
                if seq != self._goal_seq:
                    return None
                fut = await asyncio.to_thread(self.nav.goto, goal)
                err = fut.exception() if fut.done() else None
                not_ready = isinstance(err, RpcError) and err.code == ErrorCode.UNAVAILABLE
                if not (not_ready and time.monotonic() < ready_by):
                    return fut
                await asyncio.sleep(0.3)

    async def _drive(self, goal: Position, seq: int, report: bool) -> GoalResult:
        t0 = clock().now()
        try:
            fut = await self._send(goal, seq)
            if fut is None:
                res = GoalResult("superseded", "a newer goal replaced it", goal)
            else:
                try:
                    await wait_for(asyncio.wrap_future(fut), self.goal_timeout)
                    res = GoalResult("done", "reached", goal)
                except TimeoutError:
                    res = GoalResult("timeout", f"not reached within {self.goal_timeout:g} s", goal)
                    if seq == self._goal_seq:
                        await self.stop_robot()
                except RpcError as e:
                    if "superseded" in e.message:
                        res = GoalResult("superseded", e.message, goal)
                    elif e.code == ErrorCode.NOT_FOUND:
                        res = GoalResult("unreachable", e.message, goal)
                    elif e.code == ErrorCode.UNAVAILABLE:
                        res = GoalResult("aborted", e.message, goal)
                    else:
                        res = GoalResult("failed", str(e), goal)
        except Exception as e:  # the planner could not be asked (timeout, session closing)
            res = GoalResult("failed", f"{type(e).__name__}: {e}", goal)
        res = GoalResult(res.status, res.message, goal, clock().now() - t0)
        if res.status == "superseded":
            return res
        if seq == self._goal_seq:
            self.goal_state = res.status
        if res.ok:
            self.reached += 1
        else:
            self.failed += 1
        if report:
            self._report(res)
        return res

    def _report(self, res: GoalResult) -> None:
        g = res.goal
        where = f"({g.x:.2f}, {g.y:.2f})" if g is not None else "its goal"
        if res.ok:
            text = f"{self.robot} arrived at {where} after {res.seconds:.1f} s"
        else:
            what = {"unreachable": "is unreachable", "timeout": "was not reached", "aborted": "was aborted"}
            text = f"{self.robot}: goal {where} {what.get(res.status, 'failed')}: {res.message}"
            log.warning("%s: %s", self.id, text)
        if self.host is not None and self.state == "running":
            at = (g.x, g.y) if g is not None else None
            self.publish(Outcome.SERVICE, Outcome("arrived", self.robot, text, ok=res.ok, at=at))

    def status(self) -> str:
        """One progress line: pose, goal and its state, waypoint, goals reached, positions sent."""
        r = self.nav
        if r is None:
            return "no robot yet"
        p = r.position
        where = f"x={p.x:6.2f} y={p.y:6.2f} yaw={p.yaw:5.2f}" if p is not None else "no pose"
        g = self.goal
        goal = f"goal ({g.x:.2f}, {g.y:.2f}) {self.goal_state}" if g is not None else "no goal"
        wp = f"  waypoint {r.planner.waypoint_index}/{r.planner.waypoint_count}" if self.goal_state == "driving" else ""
        return f"{where}  {goal}{wp}  reached {self.reached}, failed {self.failed}  sent {self.sent} position(s)"
