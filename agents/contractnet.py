"""The FIPA contract-net interaction protocol (FIPA SC00029H) as a service for task allocation.

Thesis 4.2.1 and 4.2.2 ("Advanced" variants): hunters allocate prey nearest first and collectors bid
for blobs. One agent, the *initiator*, announces a task in a ``cfp`` (call for proposals) with a
reply-by deadline; *participants* answer ``propose`` (a bid: a cost, lower is better, plus optional
info) or ``refuse``. When the deadline passes the initiator sends ``accept-proposal`` to the lowest
bid and ``reject-proposal`` to every other one, and the winner answers ``inform-done`` or
``failure`` once it has performed the task.

All messages travel on one service of :mod:`agents.services` (``svc/contract_net/<sender>`` by
default) and share the call's conversation id. Every body is validated here: a message with a
missing or mistyped field is dropped (``dropped`` counts them), a message of an unknown or finished
conversation is ignored, and a proposal that arrives after the deadline is answered with
``reject-proposal`` and never chosen.

Receivers check what they can (``docs/security.md``, "Open fabric"): a participant accepts an award
(``accept-proposal``) only from the agent whose ``cfp`` it proposed to in that conversation, so an
award without a prior proposal, or from anyone else, is ignored; a participant given ``initiators``
answers only the calls of those agents (a ``cfp`` from any other sender is ignored), so a forged
call cannot commit it to a task. Each kind of ignored message is logged once per sender
(``ignored`` counts them all). The task itself is the application's to check in ``bid`` (refuse
what it does not know, e.g. a prey nobody has seen).

Body fields (besides the envelope ``sender``, ``conversation``, ``time``):

``performative``  one of :data:`PERFORMATIVES`
``to``            the receiving agent's id (``""`` for a ``cfp``, which goes to every participant)
``task``          the task description, a map (``cfp``)
``reply_by``      seconds since the epoch by which proposals are due (``cfp``)
``participants``  agent ids asked to bid, empty for everyone (``cfp``)
``cost``          the bid, a finite number, lower wins (``propose``)
``info``          a map of extra data (optional: ``propose``, ``inform-done``, ``failure``)
``reason``        why, a string (optional: ``refuse``, ``failure``)
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import math
import time
import uuid
from collections import OrderedDict
from collections.abc import Awaitable, Callable, Collection
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from rsal.clock import clock, wait_for
from rsal.msgs import MessageError, get_float, get_str

from .services import Message, check_name

if TYPE_CHECKING:
    from .runtime import Agent

__all__ = [
    "CONTRACT_NET",
    "CFP",
    "PROPOSE",
    "REFUSE",
    "ACCEPT",
    "REJECT",
    "DONE",
    "FAILURE",
    "PERFORMATIVES",
    "CnpMessage",
    "Result",
    "Initiator",
    "Participant",
]

log = logging.getLogger(__name__)

CONTRACT_NET = "contract_net"
CFP = "cfp"
PROPOSE = "propose"
REFUSE = "refuse"
ACCEPT = "accept-proposal"
REJECT = "reject-proposal"
DONE = "inform-done"
FAILURE = "failure"
PERFORMATIVES = (CFP, PROPOSE, REFUSE, ACCEPT, REJECT, DONE, FAILURE)

_MEMORY = 256  # finished conversations remembered (to reject late proposals)


def _get_map(m: dict, name: str, required: bool = False) -> dict:
    v = m.get(name)
    if v is None:
        if required:
            raise MessageError(f"missing field {name!r}")
        return {}
    if not isinstance(v, dict) or not all(isinstance(k, str) for k in v):
        raise MessageError(f"field {name!r} must be a map with string keys")
    return v


@dataclass(frozen=True)
class CnpMessage:
    """One validated contract-net message: the envelope of ``msg`` and the body fields."""

    performative: str
    sender: str
    conversation: str
    to: str = ""
    task: dict = field(default_factory=dict)
    reply_by: float = 0.0
    participants: tuple[str, ...] = ()
    cost: float = 0.0
    info: dict = field(default_factory=dict)
    reason: str = ""

    @classmethod
    def from_message(cls, msg: Message) -> CnpMessage:
        """Validate a service message; raises :class:`MessageError`."""
        m = msg.body
        if not isinstance(m, dict):
            raise MessageError("a contract-net body must be a map")
        perf = get_str(m, "performative", choices=PERFORMATIVES)
        to = get_str(m, "to", "")
        kw: dict[str, Any] = {}
        if perf == CFP:
            kw["task"] = _get_map(m, "task", required=True)
            kw["reply_by"] = get_float(m, "reply_by", lo=0.0)
            ps = m.get("participants", [])
            if not isinstance(ps, list) or not all(isinstance(p, str) for p in ps):
                raise MessageError("field 'participants' must be a list of strings")
            kw["participants"] = tuple(ps)
        else:
            if not to:
                raise MessageError(f"a {perf} message needs a receiver in 'to'")
            if perf == PROPOSE:
                kw["cost"] = get_float(m, "cost")
        if perf in (PROPOSE, DONE, FAILURE):
            kw["info"] = _get_map(m, "info")
        if perf in (REFUSE, FAILURE):
            kw["reason"] = get_str(m, "reason", "")
        return cls(perf, msg.sender, msg.conversation, to, **kw)


@dataclass
class Result:
    """The outcome of one :meth:`Initiator.call`.

    ``outcome`` is ``"done"`` (the winner informed done), ``"failure"`` (the winner reported a
    failure), ``"timeout"`` (the winner did not answer in time) or ``"no_bids"`` (nobody proposed in
    time). ``bids`` maps every in-time bidder to its cost; ``refused`` and ``late`` list the agents
    that refused or proposed after the deadline (``late`` may still grow after the call returned, as
    late proposals are rejected); ``info`` and ``reason`` come from the winner's answer.
    """

    conversation: str
    task: dict
    outcome: str = "no_bids"
    winner: str | None = None
    cost: float | None = None
    bids: dict[str, float] = field(default_factory=dict)
    refused: list[str] = field(default_factory=list)
    late: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.outcome == "done"


class _Call:
    def __init__(self, result: Result, participants: frozenset[str] | None, loop: asyncio.AbstractEventLoop):
        self.result = result
        self.participants = participants
        self.collecting = True
        self.answered = loop.create_future()  # every named participant answered
        self.finished = loop.create_future()  # the winner's inform-done / failure
        self.bid_info: dict[str, dict] = {}


class Initiator:
    """The initiator role for ``agent``: ``await Initiator(agent).call(task, deadline=0.5)``.

    Create it in ``created()`` (or later): it subscribes to the answers addressed to ``agent`` on
    ``service``; the subscription ends with the agent. Several calls may run at once; each has its
    own conversation.
    """

    def __init__(self, agent: Agent, *, service: str = CONTRACT_NET):
        self.agent = agent
        self.service = check_name("service", service)
        self.dropped = 0  # malformed messages ignored
        self._calls: dict[str, _Call] = {}
        self._closed: OrderedDict[str, Result] = OrderedDict()
        agent.subscribe(service, self._on_message, filter=self._mine)

    def _mine(self, msg: Message) -> bool:
        return isinstance(msg.body, dict) and msg.body.get("to") == self.agent.id

    def _send(self, performative: str, conversation: str, **body: Any) -> None:
        self.agent.publish(self.service, {"performative": performative, **body}, conversation=conversation)

    async def call(
        self,
        task: dict,
        *,
        deadline: float,
        participants: Collection[str] | None = None,
        done_deadline: float = 10.0,
    ) -> Result:
        """Announce ``task``, collect proposals for ``deadline`` seconds (less when every agent named
        in ``participants`` has answered), accept the lowest cost (ties: the smaller agent id), reject
        the others, and wait up to ``done_deadline`` seconds for the winner's answer. Both count
        seconds of the process's clock (:func:`rsal.clock.clock`: simulated seconds when the agents
        follow the simulation's clock), so a call means the same at any speed-up."""
        if not deadline > 0 or not done_deadline > 0:
            raise ValueError("deadline and done_deadline must be positive numbers of seconds")
        if not isinstance(task, dict):
            raise TypeError(f"a task is a dict, not {type(task).__name__}")
        loop = asyncio.get_running_loop()
        conv = uuid.uuid4().hex[:16]
        named = frozenset(participants) if participants is not None else None
        call = _Call(Result(conv, dict(task)), named, loop)
        self._calls[conv] = call
        try:
            self._send(
                CFP,
                conv,
                to="",
                task=dict(task),
                reply_by=time.time() + clock().wall(deadline),  # on the wire: wall seconds since the epoch
                participants=sorted(named or ()),
            )
            if named is not None and not named:
                call.answered.set_result(None)
            try:
                await wait_for(asyncio.shield(call.answered), deadline)
            except TimeoutError:
                pass
            call.collecting = False
            res = call.result
            if not res.bids:
                res.outcome = "no_bids"
                return res
            winner = min(res.bids, key=lambda s: (res.bids[s], s))
            res.winner, res.cost = winner, res.bids[winner]
            self._send(ACCEPT, conv, to=winner, task=dict(task))
            for other in sorted(res.bids):
                if other != winner:
                    self._send(REJECT, conv, to=other)
            try:
                await wait_for(asyncio.shield(call.finished), done_deadline)
            except TimeoutError:
                res.outcome = "timeout"
            return res
        finally:
            self._calls.pop(conv, None)
            self._closed[conv] = call.result
            while len(self._closed) > _MEMORY:
                self._closed.popitem(last=False)

    def _on_message(self, msg: Message) -> None:
        try:
            m = CnpMessage.from_message(msg)
        except MessageError as e:
            self.dropped += 1
            log.debug("%s: dropped a malformed contract-net message from %s: %s", self.agent.id, msg.sender, e)
            return
        call = self._calls.get(m.conversation)
        if m.performative == PROPOSE:
            if call is None or not call.collecting:
                res = call.result if call is not None else self._closed.get(m.conversation)
                if res is not None:  # late: rejected and recorded, also after call() returned
                    if m.sender not in res.late and m.sender not in res.bids:
                        res.late.append(m.sender)
                    self._send(REJECT, m.conversation, to=m.sender, reason="late")
                return
            if call.participants is not None and m.sender not in call.participants:
                return
            res = call.result
            if m.sender not in res.bids and m.sender not in res.refused:
                res.bids[m.sender] = m.cost
                call.bid_info[m.sender] = m.info
                self._check_answered(call)
        elif m.performative == REFUSE:
            if call is None or not call.collecting:
                return
            if call.participants is not None and m.sender not in call.participants:
                return
            res = call.result
            if m.sender not in res.bids and m.sender not in res.refused:
                res.refused.append(m.sender)
                self._check_answered(call)
        elif m.performative in (DONE, FAILURE):
            if call is None or call.collecting or m.sender != call.result.winner or call.finished.done():
                return
            call.result.outcome = "done" if m.performative == DONE else "failure"
            call.result.info = m.info
            call.result.reason = m.reason
            call.finished.set_result(None)

    @staticmethod
    def _check_answered(call: _Call) -> None:
        if call.participants is None or call.answered.done():
            return
        if call.participants <= set(call.result.bids) | set(call.result.refused):
            call.answered.set_result(None)


Bid = Callable[[dict], Awaitable[Any] | Any]
Perform = Callable[[dict], Awaitable[bool] | bool]


class Participant:
    """The participant role for ``agent``: answers every ``cfp`` on ``service`` (other than its own).

    ``bid(task)`` returns a cost (lower is better), ``(cost, info)`` or ``None`` to refuse;
    ``perform(task)`` returns ``True`` when done, ``False`` (or raises) on failure. Both may be plain
    or ``async`` and default to the agent's own ``bid`` and ``perform`` methods. An accepted
    proposal is honoured only within ``accept_grace`` seconds after the call's reply-by time, and
    only from the agent the proposal went to. ``initiators`` -- agent ids, or a predicate on the
    sender's id -- names whose calls are answered (default: everyone's); other calls are ignored.
    ``outcomes`` maps recent conversations to what became of them: ``refused``, ``proposed``,
    ``rejected``, ``done`` or ``failure``.
    """

    def __init__(
        self,
        agent: Agent,
        *,
        bid: Bid | None = None,
        perform: Perform | None = None,
        service: str = CONTRACT_NET,
        accept_grace: float = 30.0,
        initiators: Collection[str] | Callable[[str], bool] | None = None,
    ):
        self.agent = agent
        if initiators is None or callable(initiators):
            self._initiator_ok: Callable[[str], bool] | None = initiators
        else:
            allowed = frozenset(initiators)
            self._initiator_ok = allowed.__contains__
        self.ignored = 0  # calls from non-initiators and awards without a proposal of ours
        self._reported: set[tuple[str, str]] = set()  # (what, sender) logged once
        self.service = check_name("service", service)
        self._bid = bid or agent.bid  # type: ignore[attr-defined]
        self._perform = perform or agent.perform  # type: ignore[attr-defined]
        self.accept_grace = accept_grace
        self.dropped = 0
        self.outcomes: OrderedDict[str, str] = OrderedDict()
        self._pending: dict[str, tuple[str, dict, float]] = {}  # conversation -> (initiator, task, expiry)
        agent.subscribe(service, self._on_message, filter=self._mine)

    def _mine(self, msg: Message) -> bool:
        if not isinstance(msg.body, dict) or msg.sender == self.agent.id:
            return False
        perf = msg.body.get("performative")
        return perf == CFP or (perf in (ACCEPT, REJECT) and msg.body.get("to") == self.agent.id)

    def _send(self, performative: str, conversation: str, to: str, **body: Any) -> None:
        self.agent.publish(self.service, {"performative": performative, "to": to, **body}, conversation=conversation)

    def _note(self, conversation: str, what: str) -> None:
        self.outcomes[conversation] = what
        self.outcomes.move_to_end(conversation)
        while len(self.outcomes) > _MEMORY:
            self.outcomes.popitem(last=False)

    async def _on_message(self, msg: Message) -> None:
        try:
            m = CnpMessage.from_message(msg)
        except MessageError as e:
            self.dropped += 1
            log.debug("%s: dropped a malformed contract-net message from %s: %s", self.agent.id, msg.sender, e)
            return
        now = time.time()
        for conv in [c for c, (_, _, exp) in self._pending.items() if exp < now]:
            del self._pending[conv]
        if m.performative == CFP:
            await self._on_cfp(m)
        elif m.performative == REJECT:
            p = self._pending.get(m.conversation)
            if p is not None and p[0] == m.sender:
                del self._pending[m.conversation]
                self._note(m.conversation, "rejected")
        elif m.performative == ACCEPT:
            p = self._pending.get(m.conversation)
            if p is None or p[0] != m.sender:
                why = "no proposal of mine" if p is None else f"my proposal went to {p[0]}"
                self._ignore("award", m, f"an award ({why})")
                return
            del self._pending[m.conversation]
            await self._on_accept(m, p[1])

    def _ignore(self, what: str, m: CnpMessage, text: str) -> None:
        self.ignored += 1
        if (what, m.sender) not in self._reported:
            self._reported.add((what, m.sender))
            log.warning(
                "%s: ignored %s from %s in conversation %s on svc/%s (further ones from %s are not logged)",
                self.agent.id, text, m.sender, m.conversation, self.service, m.sender,
            )  # fmt: skip

    async def _on_cfp(self, m: CnpMessage) -> None:
        if m.participants and self.agent.id not in m.participants:
            return
        if self._initiator_ok is not None and not self._initiator_ok(m.sender):
            self._ignore("cfp", m, "a call for proposals from a sender that is no initiator of mine")
            return
        if m.conversation in self._pending or m.conversation in self.outcomes:
            return  # a repeated cfp
        self._note(m.conversation, "bidding")
        try:
            out = self._bid(m.task)
            if inspect.isawaitable(out):
                out = await out
        except Exception as e:
            log.exception("%s: bid failed", self.agent.id)
            out, reason = None, f"{type(e).__name__}: {e}"
        else:
            reason = ""
        info: dict = {}
        if isinstance(out, tuple) and len(out) == 2:
            out, info = out
        if not isinstance(info, dict):
            info = {}
        if out is None or isinstance(out, bool) or not isinstance(out, (int, float)) or not math.isfinite(out):
            if out is not None:
                reason = f"not a cost: {out!r}"
            self._note(m.conversation, "refused")
            self._send(REFUSE, m.conversation, m.sender, reason=reason)
            return
        self._pending[m.conversation] = (m.sender, m.task, m.reply_by + self.accept_grace)
        self._note(m.conversation, "proposed")
        self._send(PROPOSE, m.conversation, m.sender, cost=float(out), info=info)

    async def _on_accept(self, m: CnpMessage, task: dict) -> None:
        self._note(m.conversation, "performing")
        reason = ""
        try:
            ok = self._perform(task)
            if inspect.isawaitable(ok):
                ok = await ok
            ok = bool(ok)
        except Exception as e:
            log.exception("%s: perform failed", self.agent.id)
            ok, reason = False, f"{type(e).__name__}: {e}"
        self._note(m.conversation, "done" if ok else "failure")
        if ok:
            self._send(DONE, m.conversation, m.sender)
        else:
            self._send(FAILURE, m.conversation, m.sender, reason=reason)
