"""The dispatcher and its robots on the fabric: :class:`DispatcherAgent` and :class:`FleetAgent`.

:class:`DispatcherAgent` runs :class:`agents.dispatch.core.Dispatcher` on the agent host's loop:
requests arrive on ``task_request`` (from agents, the control center or ``rsal task``), the robots'
bids, progress and status on ``fleet``; it calls, awards and revokes on ``dispatch`` and publishes
every change of a task on ``task_state``. A robot agent whose liveliness token (``agents/<id>``)
goes is lost: its tasks are re-bid. Only the message's sender, checked against its key by
:mod:`agents.services`, can bid for itself or move its own task on.

:class:`FleetWorker` is the robot side for any agent class (bids, queue, status, work; a task the
dispatcher takes back while under way is cancelled and ``abandon``-ed, a killed agent abandons its
task). :class:`FleetAgent` is a :class:`agents.navigation.NavAgent` that works for the dispatcher: it
reports its pose, battery (its ``power:0``; -1 without a battery model) and queue on ``fleet``
every ``status_every`` seconds, bids for every call with :func:`agents.dispatch.bidder.plan_bid`
(travel along its planner's paths at ``speed``, :class:`agents.dispatch.bidder.PathTravel`; straight
lines when it has no planner that plans without driving, said once), and performs its queue in
order through its planner: ``go_to`` drives there, ``patrol`` drives the route's points (closing
the loop) ``laps`` times, ``fetch`` drives to the object and on to its destination (this robot has
no gripper: it visits both),
``charge`` drives onto the charger and waits until the battery reaches the target, ``custom``
drives to ``at`` and waits ``duration`` seconds. A goal the planner refuses or aborts fails the task
(the dispatcher re-bids it).

The module stays whole at a little over 500 lines: the dispatcher's agent and the robot side are
the two ends of one conversation (``dispatch`` and ``fleet``), read together.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Sequence

import zenoh

from rsal.clock import clock

from ..navigation import NavAgent, number_arg
from ..registry import agent_class
from ..runtime import Agent
from ..services import Message
from .bidder import PathTravel, plan_bid
from .core import ChargePolicy, Charger, Dispatcher
from .mapcheck import MapCheck
from .tasks import DispatchMsg, FleetMsg, Task, TaskRefused, TaskRequest, TaskStatus, decode_body, parse_task
from .tasks import task_places as places

__all__ = ["DispatcherAgent", "FleetAgent", "FleetWorker", "parse_chargers"]

log = logging.getLogger(__name__)


def _typed(service: str, owner: str, warned: set):
    """A callback wrapper that decodes ``service``'s dict body; malformed: logged once per sender."""

    def wrap(fn):
        def cb(msg: Message):
            try:
                body = decode_body(service, msg.body)
            except Exception as e:
                if (service, msg.sender) not in warned:
                    warned.add((service, msg.sender))
                    log.warning("%s: dropped a malformed %s message from %s: %s", owner, service, msg.sender, e)
                return None
            return fn(msg, body)

        return cb

    return wrap


def parse_chargers(items: Sequence, where: str) -> list[Charger]:
    """Chargers from ``[{name, pose: [x, y, yaw degrees]}, ...]``; ValueError with one line."""
    out = []
    for i, c in enumerate(items or []):
        try:
            pose = c["pose"]
            out.append(Charger(str(c["name"]), float(pose[0]), float(pose[1]), math.radians(float(pose[2]))))
        except (KeyError, TypeError, ValueError, IndexError):
            raise ValueError(f"{where}: chargers[{i}] must be {{name: c0, pose: [x, y, degrees]}}, got {c!r}") from None
    return out


@agent_class("DispatcherAgent")
class DispatcherAgent(Agent):
    """The fleet dispatcher (``docs/dispatch.md``). ``window``: bidding window (s); ``retry``,
    ``max_rounds``: calls of a task nobody bid for; ``reassign_period`` (s, 0: off) and
    ``reassign_margin`` (s); ``charging`` (false: the baseline without charging), ``threshold``,
    ``target``, ``finishing``: the charging policy; ``chargers``: ``[{name, pose: [x, y, deg]}]``
    (empty: read from the simulation's ``describe`` when ``simulation`` names its node)."""

    capabilities = ("task_request", "task_state", "dispatch")

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str = "",
        period: float = 0.1,
        window: float = 2.0,
        retry: float = 5.0,
        max_rounds: int = 5,
        reassign_period: float = 0.0,
        reassign_margin: float = 5.0,
        charging: bool = True,
        threshold: float = 0.2,
        target: float = 0.9,
        finishing: str = "nothing",
        chargers: Sequence = (),
        simulation: str = "",
        map: str = "",  # noqa: A002 - the scenario argument's name
        robot_radius: float = 0.25,
        startup_timeout: float = 60.0,
    ):
        super().__init__(agent_id, period=period, robot=robot)
        self.policy = ChargePolicy(float(threshold), float(target), finishing, bool(charging))
        self.chargers = parse_chargers(chargers, f"agent {agent_id}")
        self.simulation = simulation
        self.map_addr = map
        self.robot_radius = number_arg(agent_id, "robot_radius", robot_radius, 0.0)
        self.startup_timeout = number_arg(agent_id, "startup_timeout", startup_timeout, 0.0)
        self.check: MapCheck | None = None
        self.params = dict(
            window=number_arg(agent_id, "window", window, 0.0),
            retry=number_arg(agent_id, "retry", retry, 0.0),
            max_rounds=int(max_rounds),
            reassign_period=float(reassign_period),
            reassign_margin=float(reassign_margin),
        )
        self.core: Dispatcher | None = None
        self._warned: set = set()
        self._live = None

    async def created(self) -> None:
        if not self.chargers and self.simulation:
            self.chargers = await asyncio.to_thread(self._sim_chargers)
        if self.map_addr:
            self.check = MapCheck(await asyncio.to_thread(self._load_map), robot_radius=self.robot_radius)
            self.check.check_chargers(self.chargers, f"agent {self.id}")  # ValueError: one line, agent not started
        clk = clock()
        self.core = Dispatcher(
            now=clk.now,
            send=self._send,
            wall=lambda t: time.time() + clk.wall(t - clk.now()),
            policy=self.policy,
            chargers=self.chargers,
            check=self.check,
            name=self.id,
            **self.params,
        )
        w = _typed
        self.subscribe(TaskRequest.SERVICE, w(TaskRequest.SERVICE, self.id, self._warned)(self._on_request))
        self.subscribe(FleetMsg.SERVICE, w(FleetMsg.SERVICE, self.id, self._warned)(self._on_fleet))
        host = self._require_host()
        self._live = host.session.liveliness().declare_subscriber(
            "agents/*", lambda s: host.services.call_soon(self._on_token, str(s.key_expr), s.kind)
        )
        log.info("%s: %d charger(s), charging %s", self.id, len(self.chargers), "on" if self.policy.enabled else "off")

    def _sim_chargers(self) -> list[Charger]:
        from rsal.client import Fabric

        fab = Fabric(self._require_host().session, own_session=False)
        try:
            addr = f"{self.simulation}:simulation:0"
            geo = fab.device(addr).describe(timeout=10.0).geometry
            return [Charger(c["name"], *c["pose"][:3]) for c in geo.get("chargers", [])]
        except Exception as e:
            log.warning("%s: no chargers from %s: %s", self.id, self.simulation, e)
            return []
        finally:
            fab.close()

    def _load_map(self):  # a worker thread
        from ..maps import fetch_map

        hint = "is 'rsal sim' running with its floorplan, or leave 'map' out"
        return fetch_map(self._require_host().session, self.map_addr, self.startup_timeout, self.id, hint)

    def _send(self, body) -> None:
        if self.host is not None and self.state == "running":
            self.publish(body.SERVICE, body)

    def _on_request(self, msg: Message, r: TaskRequest) -> None:
        assert self.core is not None
        if r.op == "list":
            for st in self.core.statuses():
                self.publish(TaskStatus.SERVICE, st, conversation=msg.conversation)
            return
        try:
            if r.op == "submit":
                self.core.submit(r.task, msg.sender)
            else:
                self.core.cancel(r.task_id, msg.sender)
        except TaskRefused as e:
            if r.op == "cancel":
                self.publish(
                    TaskStatus.SERVICE, TaskStatus(r.task_id, "", "refused", "", e.reason.value, str(e), msg.sender)
                )

    def _on_fleet(self, msg: Message, m: FleetMsg) -> None:
        assert self.core is not None
        if m.op == "status" and self.check is not None and msg.sender not in self.core.robots:
            self.check.add_start(m.x, m.y)  # its part of the floor is reachable
        self.core.on_fleet(msg.sender, m)

    def _on_token(self, key: str, kind: zenoh.SampleKind) -> None:
        if kind == zenoh.SampleKind.DELETE and self.core is not None:
            self.core.robot_lost(key.rsplit("/", 1)[-1])

    async def step(self) -> None:
        if self.core is not None:
            self.core.tick()

    async def killed(self) -> None:
        if self._live is not None:
            try:
                self._live.undeclare()
            except Exception:
                pass


class FleetWorker:
    """The robot side of the dispatcher, for any :class:`~agents.runtime.Agent` subclass: bids,
    its queue, status reports and performing tasks in order. The agent class provides
    :meth:`where` (its map position or None), :meth:`battery` (0..1 or None without a battery
    model), :meth:`charging` and :meth:`perform` (do one task, return ``""`` or why not); it calls
    :meth:`start_worker` from ``created()`` and :meth:`report_status` from its steps."""

    speed_default = 0.4  # m/s, the agent class's ``speed`` when its scenario gives none
    charge_timeout_default = 36000.0  # s, likewise for ``charge_timeout``

    def __init__(
        self,
        agent_id: str,
        *,
        speed: float | None = None,
        threshold: float = 0.2,
        target: float = 0.9,
        status_every: float = 1.0,
        charge_timeout: float | None = None,
        **kw,
    ):
        """The worker's arguments (class docstring of the agent class; ``speed`` and
        ``charge_timeout`` default to the class's ``speed_default``/``charge_timeout_default``);
        the rest go on to the robot agent's constructor, next in the MRO."""
        super().__init__(agent_id, **kw)  # type: ignore[call-arg]
        self.init_worker(
            speed=self.speed_default if speed is None else speed,
            threshold=threshold,
            target=target,
            status_every=status_every,
            charge_timeout=self.charge_timeout_default if charge_timeout is None else charge_timeout,
            agent_id=agent_id,
        )

    def init_worker(
        self,
        *,
        speed: float,
        threshold: float,
        target: float,
        status_every: float,
        agent_id: str,
        charge_timeout: float = 36000.0,
    ) -> None:
        """Set up the worker's state; for classes that call their base constructors themselves."""
        self.speed = number_arg(agent_id, "speed", speed, 0.0)
        self.charge_timeout = number_arg(agent_id, "charge_timeout", charge_timeout, 0.0)
        self.threshold, self.target = float(threshold), float(target)
        self.status_every = number_arg(agent_id, "status_every", status_every, 0.0)
        self.queue: list[Task] = []  # awarded, not started
        self.active: Task | None = None
        self.dispatcher = ""  # the agent whose calls it answers (the first that awards it anything)
        self.done: list[str] = []  # tasks it performed, in order
        self.heading_to: tuple[float, float] | None = None  # the point its active task drives to next
        self._wake: asyncio.Event | None = None
        self._doing: asyncio.Future | None = None
        self._warned: set = set()
        self._next_status = -math.inf

    power = None  # the robot's power:0 proxy, from find_power()
    has_battery = False

    # to provide
    def where(self) -> tuple[float, float] | None:
        raise NotImplementedError

    def battery(self) -> float | None:
        """0..1 from the robot's ``power:0`` (see :meth:`find_power`); None without a battery model."""
        if not self.has_battery or self.power is None:
            return None
        return self.power.fraction

    def charging(self) -> bool:
        return bool(self.power.charging) if self.power is not None and self.has_battery else False

    def find_power(self) -> None:
        """Find the robot's ``power:0`` on the agent's ``fabric`` (a worker thread): its battery
        model, or none (``describe`` says ``battery: false``, or no such device)."""
        if getattr(self, "fabric", None) is None:
            return
        try:
            p = self.fabric.device(f"{self.robot}:power:0")  # type: ignore[attr-defined]
            geo = p.describe(timeout=5.0).geometry
            self.has_battery = bool(geo.get("battery", True))
            if self.has_battery:
                p.wait_for_data(5.0)  # its first status carries the charge, not "no battery model"
            self.power = p
        except Exception as e:
            self.has_battery = False
            log.warning("%s: no power device for %s (%s): no battery model", self.id, self.robot, e)  # type: ignore[attr-defined]

    def travel(self):
        """``travel(a, b)`` seconds between two points for bids (None for unreachable), or None:
        straight lines at ``speed``. It may block (a planner asked over the fabric): bids then run
        on a worker thread."""
        return None

    async def perform(self, task: Task) -> str:
        raise NotImplementedError

    async def abandon(self, task: Task) -> None:
        """The dispatcher took back ``task`` while it was under way (cancelled): stop doing it."""

    def places_left(self) -> list[tuple[float, float]]:
        """The places the active task still visits, for bids (default: its last place)."""
        return places(self.active)[-1:] if self.active is not None else []

    async def wait_charged(self, task: Task, timeout: float) -> str:
        """On the charger: wait until :meth:`battery` reaches the ``charge`` task's target (at once
        without a battery model); ``""`` or why not."""
        target = float(task.args.get("target", self.target))
        deadline = clock().now() + timeout
        while (b := self.battery()) is not None and b < target:
            if clock().now() >= deadline:
                return f"not charged to {target:.0%} within {timeout:g} s"
            await clock().asleep(1.0)
        return ""

    # ------------------------------------------------------------------ messages
    def start_worker(self) -> None:
        self._wake = asyncio.Event()
        self.subscribe(  # type: ignore[attr-defined]
            DispatchMsg.SERVICE,
            _typed(DispatchMsg.SERVICE, self.id, self._warned)(self._on_dispatch),  # type: ignore[attr-defined]
            filter=lambda m: isinstance(m.body, dict) and m.body.get("to") in ("", self.id),  # type: ignore[attr-defined]
        )
        self._worker = self._require_host().spawn(self._work(), f"{self.id}: tasks")  # type: ignore[attr-defined]

    def stop_worker(self) -> None:
        """Stop working (from ``killed()``): the active task is abandoned, not finished."""
        w = getattr(self, "_worker", None)
        if w is not None and not w.done():
            w.cancel()

    def _on_dispatch(self, msg: Message, m: DispatchMsg) -> None:
        if self.dispatcher and msg.sender != self.dispatcher:
            return
        if m.op == "call":
            if self.id not in m.exclude:  # type: ignore[attr-defined]
                self._bid(m)
        elif m.op == "award":
            try:
                task = parse_task(m.task)
            except TaskRefused as e:
                self._fleet(FleetMsg("progress", task_id=m.task_id, state="failed", reason=str(e)))
                return
            self.dispatcher = self.dispatcher or msg.sender
            if any(t.id == task.id for t in self.queue) or (self.active and self.active.id == task.id):
                return
            if task.kind == "charge":  # a charge goes before any other work waiting
                self.queue.insert(0, task)
            else:
                i = m.index - (1 if self.active is not None else 0)
                self.queue.insert(max(0, min(i, len(self.queue))) if m.index >= 0 else len(self.queue), task)
            assert self._wake is not None
            self._wake.set()
        elif m.op == "revoke":
            self.queue = [t for t in self.queue if t.id != m.task_id]
            if self.active is not None and self.active.id == m.task_id and self._doing is not None:
                self._doing.cancel()  # cancelled while under way: stop it, report nothing

    def _fleet(self, body: FleetMsg) -> None:
        if self.host is not None and self.state == "running":  # type: ignore[attr-defined]
            self.publish(FleetMsg.SERVICE, body)  # type: ignore[attr-defined]

    def _bid(self, m: DispatchMsg) -> None:
        try:
            task = parse_task(m.task)
        except TaskRefused as e:
            self._fleet(FleetMsg("refuse", task_id=m.task_id, round=m.round, reason=str(e)))
            return
        pose = self.where()
        if pose is None:
            self._fleet(FleetMsg("refuse", task_id=m.task_id, round=m.round, reason="no pose yet"))
            return
        travel = self.travel()
        ahead = self.places_left()  # read on the loop: the active task's way still ahead
        args = (pose, [t for t in self.queue if t.id != task.id], task, ahead, self.battery(), travel)
        if travel is None:
            self._send_bid(m, self._cost(*args), self.active is not None)
        else:  # a planner is asked: off the loop, answered when done
            self._require_host().spawn(self._bid_off_loop(m, args), f"{self.id}: bid {m.task_id}")  # type: ignore[attr-defined]

    async def _bid_off_loop(self, m: DispatchMsg, args: tuple) -> None:
        busy = self.active is not None
        self._send_bid(m, await asyncio.to_thread(self._cost, *args), busy)

    def _cost(self, pose, queue, task, ahead, battery, travel):
        """The bid (:func:`plan_bid`) for ``task`` from ``pose`` after the places ``ahead`` (the
        active task's) and ``queue``."""
        busy = 0.0
        for p in ahead:
            t = travel(pose, p) if travel is not None else None
            busy, pose = busy + (t if t is not None else math.dist(pose, p) / self.speed), p
        return plan_bid(
            pose, queue, task, speed=self.speed, travel=travel, battery=battery, threshold=self.threshold,
            target=self.target, busy_until=busy,
        )  # fmt: skip

    def _send_bid(self, m: DispatchMsg, b, busy: bool) -> None:
        if b is None:
            self._fleet(FleetMsg("refuse", task_id=m.task_id, round=m.round, reason="unreachable"))
            return
        index = b.index + (1 if busy else 0)
        self._fleet(FleetMsg("bid", task_id=m.task_id, round=m.round, cost=b.cost, finish=b.finish, index=index))

    def report_status(self) -> None:
        """Send a ``fleet`` status when ``status_every`` seconds passed since the last one."""
        now = clock().now()
        p = self.where()
        if now < self._next_status or p is None:
            return
        self._next_status = now + self.status_every
        b = self.battery()
        ids = tuple(([self.active.id] if self.active else []) + [t.id for t in self.queue])
        self._fleet(
            FleetMsg(
                "status", robot=self.robot, x=p[0], y=p[1], battery=-1.0 if b is None else min(1.0, max(0.0, b)),  # type: ignore[attr-defined]
                charging=self.charging(), queue=ids, active=self.active.id if self.active else "",
                target=tuple(self.heading_to) if self.active is not None and self.heading_to is not None else (),
            )
        )  # fmt: skip

    # ------------------------------------------------------------------ work
    async def _work(self) -> None:
        assert self._wake is not None
        while self.state == "running":  # type: ignore[attr-defined]
            if not self.queue:
                self._wake.clear()
                await self._wake.wait()
                continue
            task = self.active = self.queue.pop(0)
            self._fleet(FleetMsg("progress", task_id=task.id, state="active"))
            self._doing = asyncio.ensure_future(self.perform(task))
            try:
                reason = await self._doing
            except asyncio.CancelledError:
                if not self._doing.cancelled() or self.state != "running":  # type: ignore[attr-defined]
                    raise  # the worker itself is stopped
                self.active = self.heading_to = None
                await self.abandon(task)
                continue
            except Exception as e:
                log.exception("%s: task %s failed", self.id, task.id)  # type: ignore[attr-defined]
                reason = f"{type(e).__name__}: {e}"
            self.active = None
            self.heading_to = None
            if reason:
                self._fleet(FleetMsg("progress", task_id=task.id, state="failed", reason=reason))
            else:
                self.done.append(task.id)
                self._fleet(FleetMsg("progress", task_id=task.id, state="done"))

    def forfeit(self, task_id: str, reason: str = "forfeit") -> bool:
        """Give back a task not started; the dispatcher re-bids it."""
        for t in self.queue:
            if t.id == task_id:
                self.queue.remove(t)
                self._fleet(FleetMsg("progress", task_id=task_id, state="forfeit", reason=reason))
                return True
        return False


@agent_class("FleetAgent")
class FleetAgent(FleetWorker, NavAgent):
    """A navigating robot agent that bids for and performs dispatcher tasks (module docstring).
    ``speed``: m/s for its bids; ``threshold``/``target``: the dispatcher's charging policy, for
    its bids and for when a charge is done; ``status_every``: s between ``fleet`` status reports;
    ``charge_timeout``: s it waits on a charger."""

    capabilities = ("send_position", "new_goal", "fleet")

    def __init__(self, agent_id: str, **kw):
        super().__init__(agent_id, **kw)  # FleetWorker's arguments, then NavAgent's
        self._path: PathTravel | None = None
        self._said_straight = False

    async def created(self) -> None:
        await NavAgent.created(self)
        await asyncio.to_thread(self.find_power)
        self.start_worker()

    def where(self) -> tuple[float, float] | None:
        p = self.nav.position if self.nav is not None else None
        return (p.x, p.y) if p is not None else None

    def travel(self):
        """Path length over ``speed`` from its planner's ``rpc/plan`` (:class:`PathTravel`)."""
        planner = self.nav.planner if self.nav is not None else None
        if planner is None:
            if not self._said_straight:
                self._said_straight = True
                log.warning("%s: no planner for %s: bids use straight lines", self.id, self.robot)
            return None
        if self._path is None:
            self._path = PathTravel(lambda a, b: planner.plan(b, start=a, timeout=2.0)["length"], self.speed, self.id)
        return None if self._path.straight else self._path

    async def step(self) -> None:
        await NavAgent.step(self)
        self.report_status()

    async def killed(self) -> None:
        self.stop_worker()
        await NavAgent.killed(self)

    async def abandon(self, task: Task) -> None:
        await self.stop_robot()

    async def perform(self, task: Task) -> str:
        """Do ``task``; returns ``""`` when done, else why not."""
        a = task.args
        for x, y in places(task):
            yaw = float(a.get("yaw", 0.0)) if task.kind in ("go_to", "charge") else 0.0
            self.heading_to = (x, y)
            res = await self.goto(x, y, yaw, report=False)
            if not res.ok:
                return f"goal ({x:.2f}, {y:.2f}) {res.status}: {res.message}"
        if task.kind == "custom":
            await clock().asleep(float(a.get("duration", 0.0)))
        elif task.kind == "charge":
            return await self.wait_charged(task, self.charge_timeout)
        return ""
