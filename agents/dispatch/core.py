"""The fleet dispatcher's logic: bidding windows, awards, re-bids, re-assignment and charging.

What Open-RMF's task dispatcher does (``rmf_task``, ``rmf_fleet_adapter``; its documented defaults
and its users' issues about failed tasks not re-bid and charging robots given work), as a state
machine with no network and no event loop: :class:`Dispatcher` is fed the requests and the robots'
messages (:mod:`agents.dispatch.tasks`), sends through a ``send`` callback and reads time from a
``now`` callback, so unit tests drive it on a fake clock and the agent
(:mod:`agents.dispatch.agent`) wires it to the fabric.

- **Bidding**: a submitted task is called for bids from every live robot that may take work (not
  below its charge threshold, not charging, not excluded); the call stays open ``window`` seconds
  (2 s, Open-RMF's default) or until every called robot answered. The lowest ``cost`` wins (ties:
  the smaller agent id); cost is the robot's own estimate: when the task would finish plus how much
  it delays the robot's other tasks (:mod:`agents.dispatch.bidder`). No bid: the task is called
  again every ``retry`` seconds, ``max_rounds`` times, then fails with ``no_bids``.
- **Direct assignment**: a task that names ``robot`` is awarded to it without bidding.
- **Failures**: a robot that reports ``failed`` or ``forfeit``, or whose liveliness token goes
  (``robot_lost``), loses its tasks; each is called again without that robot (a failed task at most
  ``max_rounds`` times in all). Only the robot a task is awarded to can move it on, and a task is
  done once: a late ``done`` from a robot that lost the task is ignored.
- **Re-assignment**: every ``reassign_period`` seconds the tasks awarded but not started are
  called again; the holder bids too, and the task moves only when another robot beats the holder
  by more than ``reassign_margin`` seconds (the holder is sent ``revoke``).
- **Charging** (:class:`ChargePolicy`): a robot whose battery falls below ``threshold`` is given a
  ``charge`` task at the front of its queue, its not-started tasks are re-bid to others, and it is
  not called for bids until the charge is done (it reports done at ``target``). Chargers are
  reserved one robot each; with fewer chargers than robots the others wait for one, nearest free
  charger first. A robot whose queue empties gets its finishing request: ``park`` (back to where
  it first reported), ``charge`` (when below ``target``) or ``nothing``. A robot with no battery
  model is dispatched without energy constraints; the dispatcher says so once.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from .tasks import (
    DispatchMsg,
    FleetMsg,
    Refusal,
    Task,
    TaskRefused,
    TaskState,
    TaskStatus,
    parse_task,
    task_outline,
    task_places,
)

__all__ = ["Charger", "ChargePolicy", "Dispatcher", "RobotRecord", "TaskRecord", "FINISHING"]

log = logging.getLogger(__name__)

FINISHING = ("park", "charge", "nothing")


@dataclass(frozen=True)
class Charger:
    """A charging station: ``name`` and its pose (m, m, rad, map frame)."""

    name: str
    x: float
    y: float
    yaw: float = 0.0


@dataclass(frozen=True)
class ChargePolicy:
    """``threshold``: charge below which a robot goes to charge (0..1; Open-RMF's example: 0.1 or
    0.2); ``target``: the charge it charges to; ``finishing``: what a robot does when its queue
    empties (:data:`FINISHING`); ``enabled`` false: no charging at all (the baseline)."""

    threshold: float = 0.2
    target: float = 0.9
    finishing: str = "nothing"
    enabled: bool = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.threshold < self.target <= 1.0:
            raise ValueError(
                f"charge threshold {self.threshold!r} and target {self.target!r} need 0 <= threshold < target <= 1"
            )
        if self.finishing not in FINISHING:
            raise ValueError(f"finishing request {self.finishing!r} must be one of {', '.join(FINISHING)}")


@dataclass
class TaskRecord:
    task: Task
    requester: str
    state: TaskState = TaskState.BIDDING
    robot: str = ""
    reason: str = ""
    submitted: float = 0.0
    round: int = 0
    rounds: int = 0  # calls made in all
    called: frozenset[str] = frozenset()
    closes: float = math.inf  # the open call's window closes (inf: no call open)
    next_call: float = 0.0  # when a task waiting for bids is called again
    bids: dict[str, tuple[float, int]] = field(default_factory=dict)  # agent -> (cost, index)
    refused: set[str] = field(default_factory=set)
    excluded: set[str] = field(default_factory=set)
    awarded_at: float = math.nan
    window_closed_at: float = math.nan
    holder_cost: float = math.inf  # the holder's cost when re-assigning
    internal: bool = False  # a charge or park task the dispatcher made itself


@dataclass
class RobotRecord:
    agent: str
    robot: str = ""
    alive: bool = True
    x: float = math.nan
    y: float = math.nan
    home: tuple[float, float] | None = None
    battery: float | None = None  # None: no battery model
    charging: bool = False
    queue: list[str] = field(default_factory=list)  # task ids awarded, in the robot's order
    charger: str = ""  # the charger reserved for it
    charge_task: str = ""  # its open charge task


class Dispatcher:
    """The dispatcher's state. Feed it :meth:`submit`, :meth:`cancel`, :meth:`on_fleet` and
    :meth:`robot_lost`; call :meth:`tick` often (every 0.1 s is plenty). ``send(body)`` publishes a
    :class:`DispatchMsg` or :class:`TaskStatus`; ``now()`` is the clock (s); ``wall(now)`` converts a
    clock time to wall seconds since the epoch for ``reply_by``. ``check(task)`` may refuse a task
    against the map (raise :class:`TaskRefused`)."""

    def __init__(
        self,
        *,
        now: Callable[[], float],
        send: Callable[[DispatchMsg | TaskStatus], None],
        wall: Callable[[float], float] | None = None,
        window: float = 2.0,
        retry: float = 5.0,
        max_rounds: int = 5,
        reassign_period: float = 0.0,
        reassign_margin: float = 5.0,
        policy: ChargePolicy | None = None,
        chargers: list[Charger] | None = None,
        check: Callable[[Task], None] | None = None,
        name: str = "dispatcher",
    ):
        for what, v in (("window", window), ("retry", retry)):
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"{name}: {what} {v!r} must be a positive number of seconds")
        self.now, self.send = now, send
        self.wall = wall or (lambda t: t)
        self.window, self.retry, self.max_rounds = float(window), float(retry), int(max_rounds)
        self.reassign_period, self.reassign_margin = float(reassign_period), float(reassign_margin)
        self.policy = policy or ChargePolicy()
        self.chargers = {c.name: c for c in (chargers or [])}
        self.check = check
        self.name = name
        self.tasks: dict[str, TaskRecord] = {}
        self._open: set[str] = set()  # tasks with a call open or waiting for the next call
        self.robots: dict[str, RobotRecord] = {}
        self.latencies: list[float] = []  # award time - window close, per award after a call
        self._ids = itertools.count(1)
        self._next_reassign = now() + self.reassign_period if self.reassign_period > 0 else math.inf
        self._said: set[tuple[str, str]] = set()

    # ------------------------------------------------------------------ requests
    def submit(self, task: dict | Task, requester: str = "", *, internal: bool = False) -> TaskRecord:
        """Validate and take a task; raises :class:`TaskRefused` (and publishes ``refused``)."""
        try:
            if isinstance(task, Task):
                t = task
            else:
                t = parse_task(task, "" if isinstance(task, dict) and task.get("id") else self._new_id())
            if t.id in self.tasks:
                raise TaskRefused(
                    Refusal.DUPLICATE_ID, f"task {t.id}: a task with this id exists; leave 'id' out for a fresh one"
                )
            if t.robot and t.robot not in self.robots:
                known = ", ".join(sorted(self.robots)) or "none yet"
                raise TaskRefused(Refusal.UNKNOWN_ROBOT, f"task {t.id}: no robot agent {t.robot!r} (known: {known})")
            if t.kind == "charge" and t.args.get("charger") and t.args["charger"] not in self.chargers:
                known = ", ".join(sorted(self.chargers)) or "none"
                raise TaskRefused(
                    Refusal.UNKNOWN_CHARGER, f"task {t.id}: no charger {t.args['charger']!r} (chargers: {known})"
                )
            if self.check is not None and t.kind != "charge":
                self.check(t)
        except TaskRefused as e:
            tid = task.id if isinstance(task, Task) else str(task.get("id", "")) if isinstance(task, dict) else ""
            kind = task.kind if isinstance(task, Task) else str(task.get("kind", "")) if isinstance(task, dict) else ""
            log.warning("%s: refused %s: %s", self.name, tid or "a task", e)
            self.send(TaskStatus(tid or "?", kind, TaskState.REFUSED.value, "", e.reason.value, str(e), requester))
            raise
        rec = TaskRecord(t, requester, submitted=self.now(), internal=internal)
        self.tasks[t.id] = rec
        if t.robot:
            self._award(rec, t.robot, -1)
        else:
            self._call(rec)
        return rec

    def cancel(self, task_id: str, requester: str = "") -> TaskRecord:
        rec = self.tasks.get(task_id)
        if rec is None:
            raise TaskRefused(Refusal.NOT_FOUND, f"no task {task_id!r}; 'rsal task list' shows the tasks")
        if rec.state.final:
            return rec
        if rec.robot:
            self._take_back(rec, "cancelled")
        self._finish(rec, TaskState.CANCELLED, "", f"cancelled by {requester or 'request'}")
        return rec

    def _new_id(self) -> str:
        while True:
            tid = f"t{next(self._ids)}"
            if tid not in self.tasks:
                return tid

    # ------------------------------------------------------------------ robots' messages
    def on_fleet(self, sender: str, m: FleetMsg) -> None:
        """A robot agent's message (``sender`` is the envelope's, checked against the key)."""
        if m.op == "status":
            self._on_status(sender, m)
            return
        r = self.robots.get(sender)
        rec = self.tasks.get(m.task_id)
        if r is None or rec is None or rec.state.final:
            return
        if m.op in ("bid", "refuse"):
            if m.round != rec.round or sender not in rec.called or rec.closes == math.inf:
                return  # a late or unasked answer
            if m.op == "bid":
                rec.bids[sender] = (m.cost, m.index)
            else:
                rec.refused.add(sender)
            if rec.called <= set(rec.bids) | rec.refused:
                self._close(rec)
        elif m.op == "progress":
            if rec.robot != sender:
                return  # only the holder moves a task on
            if m.state == "active":
                self._set(rec, TaskState.ACTIVE, sender, "", f"{sender} started")
            elif m.state == "done":
                self._drop_from(r, rec.task.id)
                self._finish(rec, TaskState.DONE, "", f"done by {sender}")
                self._after_task(r, rec)
            else:  # failed or forfeit: called again without it
                self._drop_from(r, rec.task.id)
                rec.excluded.add(sender)
                if rec.task.kind == "charge":
                    self._release_charger(r)
                why = m.reason or m.state
                log.info("%s: %s %s task %s (%s); re-bidding", self.name, sender, m.state, rec.task.id, why)
                self._rebid(rec, f"{sender} {m.state}: {why}")

    def _on_status(self, sender: str, m: FleetMsg) -> None:
        r = self.robots.get(sender)
        if r is None:
            r = self.robots[sender] = RobotRecord(sender)
            log.info("%s: robot agent %s (%s) joined", self.name, sender, m.robot)
        r.alive = True
        r.robot = m.robot
        r.x, r.y = m.x, m.y
        if r.home is None:
            r.home = (m.x, m.y)
        r.charging = m.charging
        if m.battery < 0:
            r.battery = None
            if ("nobattery", sender) not in self._said:
                self._said.add(("nobattery", sender))
                log.warning("%s: %s has no battery model: dispatched without energy constraints", self.name, sender)
        else:
            r.battery = m.battery

    def robot_lost(self, agent: str) -> None:
        """``agent``'s liveliness token went: every task it held is called again without it."""
        r = self.robots.get(agent)
        if r is None or not r.alive:
            return
        r.alive = False
        log.warning("%s: robot agent %s is gone; re-bidding its %d task(s)", self.name, agent, len(r.queue))
        self._release_charger(r)
        for tid in list(r.queue):
            rec = self.tasks[tid]
            r.queue.remove(tid)
            rec.excluded.add(agent)
            if rec.internal:
                self._finish(rec, TaskState.CANCELLED, Refusal.ROBOT_FAILED.value, f"{agent} is gone")
            else:
                self._rebid(rec, f"{agent} is gone")
        for rec in self.tasks.values():  # open calls stop waiting for it
            if rec.closes < math.inf and agent in rec.called:
                rec.called = rec.called - {agent}
                if rec.called <= set(rec.bids) | rec.refused:
                    self._close(rec)

    # ------------------------------------------------------------------ time
    def tick(self) -> None:
        now = self.now()
        for tid in sorted(self._open):
            rec = self.tasks[tid]
            if rec.closes <= now:
                self._close(rec)
            elif rec.state is TaskState.BIDDING and rec.closes == math.inf and rec.next_call <= now:
                self._call(rec)
            if rec.state.final or (rec.closes == math.inf and rec.state is not TaskState.BIDDING):
                self._open.discard(tid)
        if now >= self._next_reassign:
            self._next_reassign = now + self.reassign_period
            self._reassign()
        if self.policy.enabled:
            self._charging()

    def available(self, r: RobotRecord) -> bool:
        """May ``r`` be called for work?"""
        if not r.alive or r.charge_task:
            return False
        return not (self.policy.enabled and r.battery is not None and r.battery < self.policy.threshold)

    # ------------------------------------------------------------------ bidding
    def _call(self, rec: TaskRecord, holder: str = "") -> None:
        rec.round += 1
        rec.rounds += 1
        rec.bids.clear()
        rec.refused.clear()
        called = {a for a, r in self.robots.items() if self.available(r) and a not in rec.excluded}
        if holder:
            called.add(holder)
        rec.called = frozenset(called)
        if not called:
            self._no_bids(rec)
            return
        now = self.now()
        rec.closes = now + self.window
        self._open.add(rec.task.id)
        exclude = sorted(a for a in self.robots if a not in called)
        self.send(
            DispatchMsg(
                "call", rec.task.id, "", rec.task.to_dict(), rec.round, self.wall(rec.closes), -1, tuple(exclude)
            )
        )
        if rec.state is TaskState.BIDDING:
            self._status(rec, f"called {len(called)} robot(s), round {rec.round}")

    def _close(self, rec: TaskRecord) -> None:
        now = self.now()
        rec.closes = math.inf
        rec.window_closed_at = now
        bids = {
            a: b
            for a, b in rec.bids.items()
            if self.robots[a].alive and (a == rec.robot or self.available(self.robots[a]))
        }
        if rec.state is TaskState.ASSIGNED:  # a re-assignment round
            holder = rec.robot
            if not bids or holder not in bids:
                return
            best = min(bids, key=lambda a: (bids[a][0], a))
            if best != holder and bids[best][0] + self.reassign_margin < bids[holder][0]:
                self._take_back(rec, f"re-assigned to {best}")
                self._award(rec, best, bids[best][1])
            return
        if not bids:
            self._no_bids(rec)
            return
        best = min(bids, key=lambda a: (bids[a][0], a))
        self._award(rec, best, bids[best][1])
        self.latencies.append(self.now() - rec.window_closed_at)

    def _no_bids(self, rec: TaskRecord) -> None:
        rec.closes = math.inf
        if rec.rounds >= self.max_rounds:
            self._finish(rec, TaskState.FAILED, Refusal.NO_BIDS.value, f"no robot bid in {rec.rounds} call(s)")
        else:
            rec.next_call = self.now() + self.retry
            self._open.add(rec.task.id)
            self._status(rec, f"no bids in round {rec.round}; calling again in {self.retry:g} s")

    def _award(self, rec: TaskRecord, agent: str, index: int) -> None:
        r = self.robots[agent]
        rec.robot = agent
        rec.awarded_at = self.now()
        if index < 0 or index > len(r.queue):
            index = len(r.queue)
        r.queue.insert(index, rec.task.id)
        self.send(DispatchMsg("award", rec.task.id, agent, rec.task.to_dict(), rec.round, 0.0, index))
        self._set(rec, TaskState.ASSIGNED, agent, "", f"awarded to {agent}")

    def _take_back(self, rec: TaskRecord, why: str) -> None:
        r = self.robots.get(rec.robot)
        if r is not None:
            self._drop_from(r, rec.task.id)
            if r.alive:
                self.send(DispatchMsg("revoke", rec.task.id, rec.robot))
        rec.robot = ""

    def _rebid(self, rec: TaskRecord, why: str) -> None:
        rec.robot = ""
        if rec.rounds >= self.max_rounds:
            self._finish(
                rec, TaskState.FAILED, Refusal.ROBOT_FAILED.value, f"{why}; gave up after {rec.rounds} call(s)"
            )
            return
        self._set(rec, TaskState.BIDDING, "", "", why)
        self._call(rec)

    def _reassign(self) -> None:
        for rec in self.tasks.values():
            if rec.state is TaskState.ASSIGNED and not rec.internal and not rec.task.robot and rec.closes == math.inf:
                holder = self.robots.get(rec.robot)
                if holder is None or not holder.alive or (holder.queue and holder.queue[0] == rec.task.id):
                    continue  # the next task of its robot: about to start
                self._call(rec, holder=rec.robot)

    # ------------------------------------------------------------------ charging
    def _charging(self) -> None:
        p = self.policy
        for r in sorted(self.robots.values(), key=lambda r: (r.battery if r.battery is not None else 2.0, r.agent)):
            if not r.alive or r.battery is None or r.charge_task or r.battery >= p.threshold:
                continue
            self._send_to_charge(r, f"battery {r.battery:.0%} below {p.threshold:.0%}")

    def _send_to_charge(self, r: RobotRecord, why: str) -> bool:
        free = [c for c in self.chargers.values() if not any(o.charger == c.name for o in self.robots.values())]
        if not free:
            if ("nocharger", r.agent) not in self._said:
                self._said.add(("nocharger", r.agent))
                log.info(
                    "%s: %s needs a charger (%s); all %d are taken, it waits",
                    self.name,
                    r.agent,
                    why,
                    len(self.chargers),
                )
            return False
        self._said.discard(("nocharger", r.agent))
        c = min(free, key=lambda c: (math.hypot(c.x - r.x, c.y - r.y) if math.isfinite(r.x) else 0.0, c.name))
        r.charger = c.name
        # its work not yet started goes to others
        for tid in [t for t in r.queue[1:] if self.tasks[t].state is TaskState.ASSIGNED and not self.tasks[t].internal]:
            rec = self.tasks[tid]
            self._take_back(rec, "charging")
            self._rebid(rec, f"{r.agent} goes to charge")
        args = {"charger": c.name, "target": self.policy.target, "x": c.x, "y": c.y, "yaw": c.yaw}
        active = r.queue[:1] if r.queue and self.tasks[r.queue[0]].state is TaskState.ACTIVE else []
        t = Task(self._new_id(), "charge", args, r.agent)
        rec = TaskRecord(t, self.name, submitted=self.now(), internal=True)
        self.tasks[t.id] = rec
        r.charge_task = t.id
        log.info("%s: %s -> charger %s (%s)", self.name, r.agent, c.name, why)
        self._award(rec, r.agent, len(active))
        return True

    def _release_charger(self, r: RobotRecord) -> None:
        r.charger = ""
        r.charge_task = ""

    def _after_task(self, r: RobotRecord, rec: TaskRecord) -> None:
        if rec.task.kind == "charge" and r.charge_task == rec.task.id:
            self._release_charger(r)
        if r.queue or not r.alive or not self.policy.enabled or rec.internal:
            return  # the finishing request follows work, not its own park or charge
        f = self.policy.finishing
        if f == "charge" and r.battery is not None and r.battery < self.policy.target:
            self._send_to_charge(r, "finishing request")
        elif f == "park" and r.home is not None:
            t = Task(self._new_id(), "go_to", {"x": r.home[0], "y": r.home[1], "yaw": 0.0}, r.agent)
            park = TaskRecord(t, self.name, submitted=self.now(), internal=True)
            self.tasks[t.id] = park
            self._award(park, r.agent, 0)

    # ------------------------------------------------------------------ bookkeeping
    @staticmethod
    def _drop_from(r: RobotRecord, tid: str) -> None:
        if tid in r.queue:
            r.queue.remove(tid)

    def _set(self, rec: TaskRecord, state: TaskState, robot: str, reason: str, text: str) -> None:
        rec.state, rec.robot, rec.reason = state, robot, reason
        if state is TaskState.BIDDING:
            self._open.add(rec.task.id)
        elif state.final:
            self._open.discard(rec.task.id)
        self._status(rec, text)

    def _finish(self, rec: TaskRecord, state: TaskState, reason: str, text: str) -> None:
        rec.closes = math.inf
        robot = rec.robot
        self._set(rec, state, robot, reason, text)

    @staticmethod
    def _state_of(rec: TaskRecord, text: str) -> TaskStatus:
        t = rec.task
        places = tuple(task_outline(t))
        return TaskStatus(t.id, t.kind, rec.state.value, rec.robot, rec.reason, text, rec.requester, places)

    def _status(self, rec: TaskRecord, text: str) -> None:
        self.send(self._state_of(rec, text))

    def statuses(self) -> list[TaskStatus]:
        """Every task's current state (for ``list``)."""
        return [self._state_of(r, "") for r in self.tasks.values()]

    def places(self, task_id: str) -> list[tuple[float, float]]:
        return task_places(self.tasks[task_id].task)
