"""The master of Find and Collect (thesis 4.2.2, fig. 3.14): the blackboard and the allocation.

:class:`MasterAgent` keeps the blackboard of participants and blobs (:class:`rsal.data.Board`),
merges repeated reports of one blob and hands each blob to one collector: the nearest free one
(``allocation: direct``), or, in the thesis's "advanced" variant, the one that wins a FIPA
contract-net call among the collectors (``allocation: contract_net``, :mod:`agents.contractnet`,
cost = straight-line distance to the blob), or, with energy, as a ``fetch`` task of the fleet
dispatcher (``allocation: dispatch``, :mod:`agents.dispatch`: the collectors bid, the dispatcher
awards, re-bids and sends collectors to charge). When a blob is home it publishes
``Outcome("delivered", subject=<blob id>, ...)``.
"""

from __future__ import annotations

import asyncio
import logging
import math
from dataclasses import dataclass, field

from agents.contractnet import Initiator
from agents.dispatch.tasks import Refusal, TaskRequest, TaskStatus, decode_body
from agents.registry import agent_class
from agents.runtime import Agent
from agents.services import Hello, Message, Outcome, SendPosition, match
from rsal.clock import clock
from rsal.data import Board, BoardObject, Position
from rsal.msgs import MessageError, get_float, get_str

from .messages import ALLOCATIONS, BLOB, COLLECT, COLLECTED, BlobReport
from .messages import check_number as _number
from .messages import check_point as _point

__all__ = ["MasterAgent"]

log = logging.getLogger(__name__)


@dataclass
class _BlobTask:
    """What the master knows of one blob (the ``data`` of its board note)."""

    id: str
    color: int
    reported_by: str
    found: float  # monotonic time of the first report
    spot: Position  # where it was reported
    reports: int = 1
    assignee: str = ""
    since: float = 0.0
    attempts: int = 0
    retry_at: float = 0.0
    failures: list[str] = field(default_factory=list)
    drop: Position | None = None  # where a collector put it down
    reason: str = ""  # why the last fetch failed
    task: str = ""  # its dispatcher task (allocation: dispatch)
    heard: bool = False  # the dispatcher said anything of that task
    to: Position | None = None  # where it goes (allocation: dispatch: one of the depots)


@agent_class("MasterAgent")
class MasterAgent(Agent):
    """Keeps the blackboard of participants and blobs and hands blobs to collectors (thesis 4.2.2).

    Participants are learned from ``hello`` (collectors offer ``collect``, explorers ``explore``);
    collectors' positions from ``send_position``. A ``blob`` report within ``merge_dist`` m of a known
    blob (also one already home) is the same blob; one within ``carry_dist`` m of a collector is a
    blob being carried and is ignored. Each new blob goes to the nearest free collector
    (``allocation: direct``, a ``collect`` message) or to the winner of a contract-net call
    (``allocation: contract_net``) or is submitted to the dispatcher ``dispatcher`` (an agent id)
    as a ``fetch`` task to one of ``depots`` ([[x, y], ...], map frame; the blobs take them in
    turn; ``allocation: dispatch``), followed on ``task_state``. A failed or timed-out fetch
    (``task_timeout`` s) is offered again after ``retry_after`` seconds. A blob brought home is
    published as ``Outcome("delivered")``.
    """

    capabilities = ("master",)

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str = "",
        period: float = 0.5,
        allocation: str = "direct",
        merge_dist: float = 0.8,
        carry_dist: float = 1.2,
        retry_after: float = 10.0,
        task_timeout: float = 600.0,
        bid_deadline: float = 1.0,
        discover_every: float = 2.0,
        dispatcher: str = "dispatcher",
        depots: list | None = None,
    ):
        super().__init__(agent_id, period=period, robot=robot)
        if allocation not in ALLOCATIONS:
            raise ValueError(f"agent {agent_id}: allocation {allocation!r} must be one of {', '.join(ALLOCATIONS)}")
        self.allocation = allocation
        self.merge_dist = _number(agent_id, "merge_dist", merge_dist, 0.0, 10.0)
        self.carry_dist = _number(agent_id, "carry_dist", carry_dist, 0.0, 10.0)
        self.retry_after = _number(agent_id, "retry_after", retry_after, 0.0, 3600.0)
        self.task_timeout = _number(agent_id, "task_timeout", task_timeout, 0.0, 86400.0)
        self.bid_deadline = _number(agent_id, "bid_deadline", bid_deadline, 0.0, 60.0)
        self.discover_every = _number(agent_id, "discover_every", discover_every, 0.0, 600.0)
        self.dispatcher = str(dispatcher)
        self.depots = [_point(agent_id, f"depots[{i}]", d) for i, d in enumerate(depots or [])]
        if allocation == "dispatch" and not self.depots:
            raise ValueError(
                f"agent {agent_id}: allocation dispatch needs depots, where blobs go; e.g. depots: [[-3, 2]]"
            )
        self.tasks: dict[str, str] = {}  # dispatcher task id -> blob id
        self._submitted = 0
        self.board = Board()
        self.duplicates = 0  # reports merged into a known blob
        self.ignored = 0  # reports of blobs being carried
        self.positions: dict[str, Position] = {}  # agent id -> latest send_position
        self.cnp: Initiator | None = None
        self._n = 0
        self._next_discovery = 0.0
        self._discovering = False
        self._bidding_until = 0.0

    # ------------------------------------------------------------------ blackboard views
    def blobs(self, state: str = "*") -> list[BoardObject]:
        """The blob notes in ``state`` (``new``, ``assigned``, ``delivered`` or ``*`` for all three),
        oldest first. (Sightings of carried blobs are kept under ``blob/carried``.)"""
        notes = self.board.values(f"blob/{state}")
        return sorted((n for n in notes if n.topic != "blob/carried" or state == "carried"), key=lambda o: o.data.found)

    def collectors(self) -> list[str]:
        return sorted(str(k[1]) for k, o in self.board.items("participant/collector"))

    def _set_state(self, note: BoardObject, state: str) -> None:
        note.topic = f"blob/{state}"
        self.board.put(("blob", note.data.id), note)

    # ------------------------------------------------------------------ lifecycle
    async def created(self) -> None:
        self.subscribe(BLOB, self.on_blob)
        self.subscribe(SendPosition.SERVICE, self.on_position)
        self.subscribe(COLLECTED, self.on_collected, filter=match(to=self.id))
        if self.allocation == "contract_net":
            self.cnp = Initiator(self)
        elif self.allocation == "dispatch":
            self.subscribe(TaskStatus.SERVICE, self.on_task_state, filter=match(requester=self.id))

    async def step(self) -> None:
        loop = asyncio.get_running_loop()
        now = clock().now()
        if now >= self._next_discovery and not self._discovering:
            self._next_discovery = now + self.discover_every
            self._discovering = True
            self._require_host().spawn(self._discover(), f"{self.id}: discovery")
        mono = clock().now()
        for note in self.blobs("assigned"):
            if mono - note.data.since > self.task_timeout:
                log.warning("%s: %s: no word from %s; offering it again", self.id, note.data.id, note.data.assignee)
                if note.data.task:
                    self.publish(TaskRequest.SERVICE, TaskRequest("cancel", task_id=note.data.task))
                self._failed(note, "timed out")
        if self.allocation == "direct":
            self._assign_direct(mono)
        elif self.allocation == "dispatch":
            self._assign_dispatch(mono)
        elif now >= self._bidding_until:
            self._assign_cnp(mono, loop)

    async def _discover(self) -> None:
        try:
            hellos = await self._require_host().who_is_there(timeout=min(1.0, self.discover_every))
        finally:
            self._discovering = False
        for h in hellos:
            self.on_hello(h)

    def on_hello(self, h: Hello) -> None:
        """Note a participant (its note lives a few discovery rounds)."""
        kind = "collector" if "collect" in h.capabilities else "explorer" if "explore" in h.capabilities else ""
        if kind:
            ttl = max(10.0, 3 * self.discover_every)
            self.board.put(("participant", h.id), BoardObject(f"participant/{kind}", data=h, timeout=ttl))

    # ------------------------------------------------------------------ inbound
    def on_position(self, msg: Message) -> None:
        b = msg.body
        if b.frame == "map":
            self.positions[msg.sender] = Position(b.x, b.y, b.yaw)

    def on_blob(self, msg: Message) -> None:
        try:
            rep = BlobReport.from_dict(msg.body)
        except MessageError as e:
            log.warning("%s: dropped a bad blob report from %s: %s", self.id, msg.sender, e)
            return
        self.report(rep, msg.sender)

    def report(self, rep: BlobReport, sender: str) -> str | None:
        """Take one blob report; returns the new blob's id, or None for a known or carried blob."""
        where = Position(rep.x, rep.y)
        for note in self.board.values("blob/*"):  # also one already home (there and where it was)
            if min(note.position.distance_to(where), note.data.spot.distance_to(where)) <= self.merge_dist:
                note.data.reports += 1
                self.duplicates += 1
                return None
        for cid in self.collectors():
            p = self.positions.get(cid)
            if p is not None and p.distance_to(where) <= self.carry_dist:
                # a blob in a gripper; remembered, so that the sighting's repeats are not taken as new
                self.ignored += 1
                data = _BlobTask(f"carried-{cid}", rep.color, sender, clock().now(), where)
                self.board.put(
                    ("carried", self.ignored), BoardObject("blob/carried", position=where, data=data, timeout=0)
                )
                return None
        blob_id = f"blob{self._n}"
        self._n += 1
        data = _BlobTask(blob_id, rep.color, sender, clock().now(), where)
        self.board.put(("blob", blob_id), BoardObject("blob/new", position=where, data=data, timeout=0))
        log.info("%s: %s at (%.2f, %.2f) reported by %s", self.id, blob_id, rep.x, rep.y, sender)
        return blob_id

    def on_collected(self, msg: Message) -> None:
        try:
            blob = get_str(msg.body, "blob")
            ok = bool(msg.body.get("ok", False))
            x, y = get_float(msg.body, "x"), get_float(msg.body, "y")
            reason = get_str(msg.body, "reason", "")
        except MessageError as e:
            log.warning("%s: dropped a bad collected message from %s: %s", self.id, msg.sender, e)
            return
        note = self.board.get(("blob", blob))
        if note is None:
            return
        if self.allocation == "contract_net" and ok and note.topic == "blob/delivered":  # after inform-done
            note.position = Position(x, y)
            return
        if note.topic != "blob/assigned":
            return
        if self.allocation == "contract_net":  # the contract says done or failure; this gives the spot
            note.data.assignee = msg.sender
            if ok:
                note.data.drop = Position(x, y)
            else:
                note.data.reason = reason
            return
        if note.data.assignee != msg.sender:
            return
        if ok:
            self._delivered(note, msg.sender, Position(x, y))
        else:
            self._failed(note, reason)

    # ------------------------------------------------------------------ allocation
    def _free_collectors(self) -> list[str]:
        busy = {n.data.assignee for n in self.blobs("assigned")}
        return [c for c in self.collectors() if c not in busy]

    def _assign_direct(self, now: float) -> None:
        free = self._free_collectors()
        for note in self.blobs("new"):
            if not free:
                return
            if note.data.retry_at > now:
                continue
            best = min(free, key=lambda c: (self._distance(c, note.position), c))
            free.remove(best)
            self._assign(note, best, now)
            self.publish(COLLECT, {"to": best, "blob": note.data.id, "x": note.position.x, "y": note.position.y})

    def _assign_cnp(self, now: float, loop: asyncio.AbstractEventLoop) -> None:
        if not self.collectors():
            return
        for note in self.blobs("new"):
            if note.data.retry_at > now:
                continue
            self._assign(note, "", now)
            self._bidding_until = clock().now() + self.bid_deadline + 0.5
            self._require_host().spawn(self._contract(note), f"{self.id}: contract for {note.data.id}")
            return  # one call in its bidding phase at a time

    def _assign_dispatch(self, now: float) -> None:
        """Every new blob as a ``fetch`` task to the dispatcher (one task per attempt); a task the
        dispatcher has not acknowledged within ``bid_deadline`` + 2 s is sent again (it may have
        started after the request: the dispatcher refuses a second copy of a task it knows)."""
        for note in self.blobs("assigned"):
            d = note.data
            if d.task and not d.heard and now - d.since > self.bid_deadline + 2.0:
                d.since = now
                self._submit(note)
        for note in self.blobs("new"):
            d = note.data
            if d.retry_at > now:
                continue
            if d.to is None:
                d.to = self.depots[self._submitted % len(self.depots)]
                self._submitted += 1
            self._assign(note, "", now)
            d.task, d.heard = f"{self.id}-{d.id}-{d.attempts}", False
            self.tasks[d.task] = d.id
            self._submit(note)
            log.info(
                "%s: %s at (%.2f, %.2f) -> the dispatcher as %s", self.id, d.id, *note.position.as_tuple()[:2], d.task
            )

    def _submit(self, note: BoardObject) -> None:
        d = note.data
        args = {"object": d.id, "at": [note.position.x, note.position.y], "to": [d.to.x, d.to.y]}
        self.publish(TaskRequest.SERVICE, TaskRequest("submit", task={"id": d.task, "kind": "fetch", "args": args}))

    def on_task_state(self, msg: Message) -> None:
        """The dispatcher's word on a fetch: on a robot (its assignee), done (delivered to its
        depot) or failed / cancelled / refused (offered again after ``retry_after``)."""
        if msg.sender != self.dispatcher:
            return
        try:
            st = decode_body(TaskStatus.SERVICE, msg.body)
        except Exception as e:
            log.warning("%s: dropped a bad task_state message from %s: %s", self.id, msg.sender, e)
            return
        note = self.board.get(("blob", self.tasks.get(st.task_id, "")))
        if note is None or note.topic != "blob/assigned" or note.data.task != st.task_id:
            return
        note.data.heard = True
        if st.state == "refused" and st.reason == Refusal.DUPLICATE_ID:  # a copy sent again: it has it
            return
        if st.robot:
            note.data.assignee = st.robot
        if st.state == "done":
            self._delivered(note, st.robot or "?", note.data.to or note.position)
        elif st.state in ("failed", "cancelled", "refused"):
            self._failed(note, st.text or st.reason or st.state)

    async def _contract(self, note: BoardObject) -> None:
        d = note.data
        task = {"blob": d.id, "x": note.position.x, "y": note.position.y, "master": self.id}
        # every collector is asked; a busy one refuses
        res = await self.cnp.call(task, deadline=self.bid_deadline, done_deadline=self.task_timeout)
        if res.winner:
            d.assignee = res.winner
        if res.outcome == "done":
            self._delivered(note, res.winner or "?", d.drop or note.position)
        elif res.outcome == "no_bids":
            d.assignee = ""
            d.retry_at = clock().now() + min(self.retry_after, 3.0)
            self._set_state(note, "new")
        else:
            self._failed(note, res.reason or d.reason or res.outcome)

    def _assign(self, note: BoardObject, collector: str, now: float) -> None:
        d = note.data
        d.assignee, d.since = collector, now
        d.attempts += 1
        self._set_state(note, "assigned")
        if collector:
            log.info("%s: %s at (%.2f, %.2f) -> %s", self.id, d.id, note.position.x, note.position.y, collector)

    def _distance(self, collector: str, where: Position) -> float:
        p = self.positions.get(collector)
        return p.distance_to(where) if p is not None else math.inf

    def _delivered(self, note: BoardObject, by: str, drop: Position) -> None:
        d = note.data
        found_at = note.position
        note.position = drop
        d.assignee = by
        self._set_state(note, "delivered")
        took = clock().now() - d.found
        text = f"{d.id} at ({found_at.x:.1f}, {found_at.y:.1f}) delivered home by {by} after {took:.0f} s"
        log.info("%s: %s", self.id, text)
        self.publish(Outcome.SERVICE, Outcome("delivered", d.id, text))

    def _failed(self, note: BoardObject, reason: str) -> None:
        d = note.data
        d.failures.append(reason)
        log.info(
            "%s: %s not collected by %s (%s); offered again in %g s",
            self.id,
            d.id,
            d.assignee,
            reason,
            self.retry_after,
        )
        d.assignee = ""
        d.retry_at = clock().now() + self.retry_after
        self._set_state(note, "new")

    def status(self) -> str:
        return (
            f"{len(self.collectors())} collector(s)  blobs: {len(self.blobs('new'))} new, "
            f"{len(self.blobs('assigned'))} assigned, {len(self.blobs('delivered'))} delivered  "
            f"{self.duplicates} duplicate report(s)"
        )
