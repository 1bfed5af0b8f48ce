"""Navigating agents and the hunters of Hunt and Prey (thesis 3.6.1 fig. 3.9, 4.2.1).

:class:`NavAgent` controls a :class:`rsal.robot.NavRobot` — a robot with ``amcl`` localization and a
``wavefront`` planner, as ``rsal sim WORLD --nav vfh`` serves them (thesis 3.4.1, appendix A.3). It
publishes the robot's localized pose on ``send_position`` (map frame) and drives to every goal that
another agent sends it on ``new_goal`` (the thesis's NewGoalService); a newer goal supersedes the
older one. A goal that ends is reported on ``outcome``: ``arrived`` with ``ok`` true when reached,
false when the planner refused it (unreachable), aborted it or it was not reached within
``goal_timeout`` seconds. Agents in the same process use ``await agent.goto(x, y, yaw)``.

:class:`FollowAgent` is the hunter of thesis 4.2.1: it listens to ``send_position`` and navigates to
where its prey is now -- the prey's broadcast positions tracked between messages by a Kalman filter
(:mod:`rsal.tracking`) -- planning again when the prey has moved more than
``replan_distance`` from the current goal (at most once per ``replan_interval``). When its localized
pose comes within ``capture_distance`` of the prey it publishes ``outcome`` ``caught`` (subject: the
prey's robot) and stops; the prey (:class:`agents.classes.EscapeAgent`) then spins in place.

In the advanced form (``allocation="contract_net"``) the hunters share out the prey themselves with
the contract net of :mod:`agents.contractnet`: the hunter with the lowest id is the auctioneer. Every
``replan_interval`` seconds it looks at the prey that are not caught (agents whose ``hello`` offers
the capability ``prey``, located by their ``send_position``), gives each an equal share of the
hunters (``ceil(hunters / prey)``), takes the nearest prey short of hunters for itself when it is free,
and announces the other places one ``cfp`` at a time (task: the prey and where it is). A free hunter
bids its straight-line distance to the prey, a busy one refuses, so the nearest free hunter wins
("nearest first"). The winner chases until the prey is caught, by anyone, and then answers
``inform-done``; nobody chases a caught prey.
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
from rsal.tracking import Tracks

from .classes import RobotAgent
from .contractnet import Initiator, Participant
from .services import Hello, Message, NewGoal, Outcome, SendPosition, match

__all__ = ["FollowAgent", "GoalResult", "NavAgent"]

log = logging.getLogger(__name__)

HUNT_SERVICE = "hunt_cnp"  # the contract-net service the hunters allocate prey on


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


def _number(agent_id: str, name: str, value, lo: float, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (lo < value <= hi):
        rng = f"({lo:g}, {hi:g}]" if math.isfinite(hi) else f"> {lo:g}"
        raise ValueError(f"agent {agent_id}: {name} {value!r} must be a number {rng}")
    return float(value)


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
        self.goal_timeout = _number(agent_id, "goal_timeout", goal_timeout, 0.0)
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
            self.publish(Outcome.SERVICE, Outcome("arrived", self.robot, text, ok=res.ok))

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


class FollowAgent(NavAgent):
    """A hunter (thesis 4.2.1): chases its ``prey`` (a robot id) by navigating to the prey's latest
    broadcast position until within ``capture_distance`` metres, then publishes ``caught``. With
    ``allocation="contract_net"`` and no ``prey`` the hunters allocate the prey among themselves."""

    capabilities = ("send_position", "new_goal", "hunter")

    def __init__(
        self,
        agent_id: str,
        *,
        prey: str = "",
        allocation: str = "fixed",
        capture_distance: float = 1.0,
        replan_distance: float = 0.75,
        replan_interval: float = 1.0,
        **kw,
    ):
        super().__init__(agent_id, **kw)
        if allocation not in ("fixed", "contract_net"):
            raise ValueError(f"agent {agent_id}: allocation {allocation!r} must be 'fixed' or 'contract_net'")
        if not isinstance(prey, str):
            raise ValueError(f"agent {agent_id}: prey {prey!r} must be a robot id")
        if allocation == "fixed" and not prey:
            raise ValueError(f"agent {agent_id}: a prey robot id is required (or allocation: contract_net)")
        self.allocation = allocation
        self.prey = prey  # the prey chased now ("" for none)
        self.capture_distance = _number(agent_id, "capture_distance", capture_distance, 0.0, 20.0)
        self.replan_distance = _number(agent_id, "replan_distance", replan_distance, 0.0, 20.0)
        self.replan_interval = _number(agent_id, "replan_interval", replan_interval, 0.0, 60.0)
        self.positions: dict[str, SendPosition] = {}  # robot id -> latest broadcast position
        self.tracks = Tracks()  # robot id -> Kalman track of its broadcasts (where it is between them)
        self.caught: dict[str, str] = {}  # prey robot -> the outcome text
        self.catches = 0  # prey this hunter caught
        self.prey_robots: set[str] = {prey} if prey else set()
        self.hunters: list[str] = []  # hunter agent ids seen on hello (contract net)
        self._chase_goal: Position | None = None
        self._last_plan = -math.inf
        self._backoff = 0  # chase goals refused in a row
        self._hunt_start = 0.0
        self._cnp: Participant | None = None
        self._initiator: Initiator | None = None
        self._assigned: dict[str, set[str]] = {}  # auctioneer: prey -> hunters chasing it
        self._auctioning: set[str] = set()  # auctioneer: prey with a cfp under way
        self._allocation_task: asyncio.Task | None = None

    async def created(self) -> None:
        await super().created()
        self._hunt_start = clock().now()
        self.subscribe(SendPosition.SERVICE, self._on_position)
        self.subscribe(Outcome.SERVICE, self._on_caught, filter=match(event="caught"))
        if self.allocation == "contract_net":
            self._cnp = Participant(self, bid=self._bid, perform=self._perform, service=HUNT_SERVICE)
            self._initiator = Initiator(self, service=HUNT_SERVICE)
            self._allocation_task = self.host.spawn(self._allocation_loop(), f"{self.id}: allocation")

    async def killed(self) -> None:
        if self._allocation_task is not None:
            self._allocation_task.cancel()
        await super().killed()

    # ------------------------------------------------------------------ messages
    def _on_position(self, msg: Message) -> None:
        p: SendPosition = msg.body
        if p.frame == "map":
            self.positions[p.robot] = p
            self.tracks.update(p.robot, p.x, p.y, p.yaw, clock().now())

    def _on_caught(self, msg: Message) -> None:
        o: Outcome = msg.body
        if o.subject in self.caught:
            return
        self.caught[o.subject] = o.text
        if o.subject == self.prey and msg.sender != self.id:
            log.info("%s: my prey %s was caught by %s; stopping the chase", self.id, o.subject, msg.sender)
            self._end_chase()

    def _end_chase(self) -> None:
        self.prey = ""
        self._chase_goal = None
        self.host.spawn(self.stop_robot(), f"{self.id}: stop")

    # ------------------------------------------------------------------ contract net
    def _bid(self, task: dict):
        prey = task.get("prey")
        if self.prey or not isinstance(prey, str) or prey in self.caught:
            return None  # busy, or nothing to chase
        me = self.nav.position if self.nav is not None else None
        if me is None:
            return None
        return math.hypot(float(task.get("x", 0.0)) - me.x, float(task.get("y", 0.0)) - me.y)

    async def _perform(self, task: dict) -> bool:
        """Take on the prey (done at once: the chase itself ends with the prey's ``caught``)."""
        prey = task["prey"]
        if self.prey or prey in self.caught:
            return False
        self._chase(prey)
        return True

    def _chase(self, prey: str) -> None:
        log.info("%s: chasing %s", self.id, prey)
        self.prey = prey
        self.prey_robots.add(prey)
        self._chase_goal = None
        self._last_plan = -math.inf

    async def _look_around(self) -> None:
        """Who hunts and what is prey (hello), for the allocation."""
        hellos: list[Hello] = await self.host.who_is_there(timeout=0.5)
        self.hunters = sorted(h.id for h in hellos if "hunter" in h.capabilities)
        self.prey_robots |= {h.robot for h in hellos if "prey" in h.capabilities and h.robot}

    async def _allocation_loop(self) -> None:
        """Look around every ``replan_interval`` (at least 1 s); the lowest-id hunter allocates."""
        while self.state == "running":
            await self._look_around()
            if self.hunters and self.hunters[0] == self.id:
                await self._allocate()
            await clock().asleep(max(1.0, self.replan_interval))

    async def _allocate(self) -> None:
        """The auctioneer's round: share the uncaught prey among the hunters, nearest first."""
        for p in [p for p in self._assigned if p in self.caught]:
            del self._assigned[p]
        prey = sorted(p for p in self.prey_robots if p not in self.caught and p in self.positions)
        if not prey or not self.hunters:
            return
        share = math.ceil(len(self.hunters) / len(prey))
        if not self.prey:  # the auctioneer hunts too: the nearest prey short of hunters
            me = self.nav.position
            open_ = [p for p in prey if len(self._assigned.get(p, ())) < share]
            if me is not None and open_:
                mine = min(open_, key=lambda p: (math.hypot(self.positions[p].x - me.x, self.positions[p].y - me.y), p))
                self._assigned.setdefault(mine, set()).add(self.id)
                self._chase(mine)
        for p in sorted(prey, key=lambda p: (len(self._assigned.get(p, ())), p)):
            if p not in self._auctioning and len(self._assigned.get(p, ())) < share:
                self._auctioning.add(p)
                self.host.spawn(self._auction(p), f"{self.id}: cfp {p}")

    async def _auction(self, prey: str) -> None:
        """One cfp for one place on ``prey`` among the hunters not yet given a prey."""
        try:
            busy = set().union(*self._assigned.values())
            others = [h for h in self.hunters if h != self.id and h not in busy]
            pos = self.positions.get(prey)
            if not others or pos is None:
                return
            res = await self._initiator.call(
                {"prey": prey, "x": pos.x, "y": pos.y}, deadline=1.0, participants=others, done_deadline=5.0
            )
            if res.ok and prey not in self.caught:
                log.info("%s: %s goes after %s (%.1f m away)", self.id, res.winner, prey, res.cost)
                self._assigned.setdefault(prey, set()).add(res.winner)
        finally:
            self._auctioning.discard(prey)

    # ------------------------------------------------------------------ the chase
    async def step(self) -> None:
        await super().step()
        now = clock().now()
        prey = self.prey
        if not prey or prey in self.caught or self.nav is None:
            return
        target = self.positions.get(prey)
        me = self.nav.position
        if target is None or me is None:
            return
        d = math.hypot(target.x - me.x, target.y - me.y)
        if d <= self.capture_distance:
            text = f"prey {prey} caught by {self.robot} after {now - self._hunt_start:.1f} s"
            log.info("%s: %s", self.id, text)
            self.caught[prey] = text
            self.catches += 1
            self.publish(Outcome.SERVICE, Outcome("caught", prey, text))
            self._end_chase()
            return
        # plan for where the prey is now (its track between broadcasts), not where it last said it was
        target = self.tracks.predict(prey, now) or target
        d = math.hypot(target.x - me.x, target.y - me.y)
        g = self._chase_goal  # the prey's position the current goal was made from
        moved = g is None or math.hypot(target.x - g.x, target.y - g.y) > self.replan_distance
        idle = self.goal_state != "driving"
        if (moved or idle) and now - self._last_plan >= self.replan_interval:
            self._last_plan = now
            # The prey's own spot may be refused (too close to a wall for the planner's clearance):
            # then aim 0.4 m nearer to the hunter per refusal in a row, up to 1.6 m.
            if self.goal_state == "unreachable":
                self._backoff = min(self._backoff + 1, 4)
            elif self.goal_state in ("driving", "done"):
                self._backoff = 0
            back = min(0.4 * self._backoff, max(0.0, d - 0.3))
            heading = math.atan2(target.y - me.y, target.x - me.x)
            goal = Position(target.x - back * math.cos(heading), target.y - back * math.sin(heading), heading)
            self._chase_goal = Position(target.x, target.y, heading)
            self._goal_task = self.start_goal(goal, report=False)

    def status(self) -> str:
        line = super().status()
        if self.prey:
            chase = f"chasing {self.prey}"
        elif self.allocation == "fixed":
            chase = f"hunt over ({self.caught.get(next(iter(self.prey_robots)), 'prey gone')})"
        else:
            chase = "free"
        return f"{line}  {chase}, caught {self.catches}"
