"""Tests of the FIPA contract-net protocol (FIPA SC00029H; thesis 4.2.1/4.2.2) over real Zenoh sessions.

The initiator runs on the listening session, the participants on the connecting one. Before each
scenario a warm-up call (which every participant refuses) proves that the subscriptions reached
both peers; waits use ``wait_until`` or the protocol's own short deadlines.
"""

from __future__ import annotations

import asyncio
import concurrent.futures

import pytest

from agents.contractnet import CnpMessage, Initiator, Participant
from agents.runtime import Agent
from agents.services import Message, encode_message
from rsal.clock import SimClock, set_clock
from rsal.msgs import MessageError
from tests.agents import test_runtime
from tests.conftest import wait_until

DEADLINE = 0.3
net = test_runtime.net  # the fixture: a listening and a connecting session on loopback


class Boss(Agent):
    async def created(self):
        self.cnp = Initiator(self)


class Worker(Agent):
    """Bids ``|task.x - x|``; refuses warm-up tasks; ``succeed`` decides the outcome of ``perform``."""

    def __init__(self, agent_id: str, x: float, *, succeed: bool = True, delay: float = 0.0, refuse: bool = False):
        super().__init__(agent_id, period=1.0)
        self.x, self.succeed, self.delay, self.refuse = x, succeed, delay, refuse
        self.performed: list[dict] = []

    async def created(self):
        self.cnp = Participant(self)

    async def bid(self, task: dict):
        if task.get("warmup") or self.refuse:
            return None
        if self.delay:
            await asyncio.sleep(self.delay)
        return abs(task["x"] - self.x), {"at": self.x}

    def perform(self, task: dict) -> bool:
        self.performed.append(task)
        return self.succeed


def setup(net, workers: list[Worker]):
    h1 = net["host"](net["listen"])
    h2 = net["host"](net["connect"])
    lt = net["loop"]
    boss = lt.run(h1.start(Boss("boss")))
    for w in workers:
        lt.run(h2.start(w))
    ids = [w.id for w in workers]

    def warm():
        r = lt.run(boss.cnp.call({"warmup": True}, deadline=1.0, participants=ids))
        return sorted(r.refused) == sorted(ids) and r.outcome == "no_bids"

    wait_until(warm, 15, "every participant to refuse the warm-up call")
    return boss, lt


def test_lowest_cost_wins_others_rejected(net):
    ws = [Worker("w1", 5.0), Worker("w2", 1.0), Worker("w3", 9.0)]
    boss, lt = setup(net, ws)
    res = lt.run(boss.cnp.call({"prey": "p1", "x": 2.0}, deadline=DEADLINE))
    assert res.outcome == "done" and res.ok
    assert res.winner == "w2" and res.cost == 1.0
    assert res.bids == {"w1": 3.0, "w2": 1.0, "w3": 7.0}
    assert res.refused == [] and res.late == []
    assert ws[1].performed == [{"prey": "p1", "x": 2.0}]
    assert ws[0].performed == ws[2].performed == []
    wait_until(
        lambda: [w.cnp.outcomes.get(res.conversation) for w in ws] == ["rejected", "done", "rejected"],
        5,
        "the losers rejected",
    )


def test_all_refuse_no_bids(net):
    ws = [Worker(f"w{i}", float(i), refuse=True) for i in range(3)]
    boss, lt = setup(net, ws)
    res = lt.run(boss.cnp.call({"x": 1.0}, deadline=DEADLINE, participants=[w.id for w in ws]))
    assert res.outcome == "no_bids" and res.winner is None and res.cost is None
    assert sorted(res.refused) == ["w0", "w1", "w2"] and res.bids == {}
    assert all(w.performed == [] for w in ws)


def test_winner_failure(net):
    ws = [Worker("w1", 0.0, succeed=False), Worker("w2", 4.0)]
    boss, lt = setup(net, ws)
    res = lt.run(boss.cnp.call({"blob": "b7", "x": 0.5}, deadline=DEADLINE))
    assert res.outcome == "failure" and not res.ok
    assert res.winner == "w1" and res.cost == 0.5
    assert ws[0].performed == [{"blob": "b7", "x": 0.5}] and ws[1].performed == []


def test_late_proposal_rejected_not_chosen(net):
    slow = Worker("slow", 2.0)
    ws = [Worker("w1", 5.0), slow]
    boss, lt = setup(net, ws)
    slow.delay = DEADLINE + 0.3  # bids the lowest cost, but after the deadline
    res = lt.run(boss.cnp.call({"x": 2.0}, deadline=DEADLINE))
    assert res.outcome == "done" and res.winner == "w1" and res.bids == {"w1": 3.0}
    wait_until(lambda: slow.cnp.outcomes.get(res.conversation) == "rejected", 5, "the late bidder rejected")
    assert res.late == ["slow"] and slow.performed == []


def test_deadlines_count_seconds_of_the_process_clock(net):
    """On the simulation's clock a call collects proposals for simulated seconds: while the
    simulation is paused the call goes on however much wall time passes, and it ends once
    simulated time passes the deadline."""
    ws = [Worker("w1", 5.0), Worker("w2", 1.0)]
    boss, lt = setup(net, ws)
    sim = SimClock()
    sim.feed(100.0, paused=True)
    old = set_clock(sim)
    try:
        fut = asyncio.run_coroutine_threadsafe(boss.cnp.call({"x": 2.0}, deadline=DEADLINE), lt.loop)
        calls = boss.cnp._calls
        wait_until(lambda: any(len(c.result.bids) == 2 for c in list(calls.values())), 10, "both bids in")
        with pytest.raises(concurrent.futures.TimeoutError):  # three deadlines of wall time: still open
            fut.result(3 * DEADLINE)
        sim.feed(100.0 + 2 * DEADLINE)  # simulated time passes the deadline
        res = fut.result(10)
    finally:
        set_clock(old)
    assert res.outcome == "done" and res.winner == "w2" and res.bids == {"w1": 3.0, "w2": 1.0}


def test_concurrent_calls_do_not_mix(net):
    ws = [Worker("w1", 0.0), Worker("w2", 10.0), Worker("w3", 20.0)]
    boss, lt = setup(net, ws)

    async def both():
        return await asyncio.gather(
            boss.cnp.call({"prey": "a", "x": 9.0}, deadline=DEADLINE),
            boss.cnp.call({"prey": "b", "x": 19.5}, deadline=DEADLINE),
        )

    a, b = lt.run(both())
    assert a.conversation != b.conversation
    assert (a.winner, a.cost, a.outcome) == ("w2", 1.0, "done")
    assert (b.winner, b.cost, b.outcome) == ("w3", 0.5, "done")
    assert a.bids == {"w1": 9.0, "w2": 1.0, "w3": 11.0}
    assert b.bids == {"w1": 19.5, "w2": 9.5, "w3": 0.5}
    assert ws[1].performed == [{"prey": "a", "x": 9.0}] and ws[2].performed == [{"prey": "b", "x": 19.5}]
    assert ws[0].performed == []


def test_malformed_messages_ignored(net):
    ws = [Worker("w1", 1.0)]
    boss, lt = setup(net, ws)
    raw = net["connect"]
    bad = [
        {"performative": "propose", "to": "boss", "cost": "cheap"},
        {"performative": "propose", "to": "boss"},
        {"performative": "shout", "to": "boss"},
        {"performative": "cfp", "task": "not a map", "reply_by": 1.0},
        {"performative": "cfp", "task": {}, "reply_by": 1.0, "participants": [3]},
    ]
    for b in bad:
        raw.put("svc/contract_net/x", encode_message("x", b, "c1", 1.0))
    wait_until(lambda: boss.cnp.dropped >= 3 and ws[0].cnp.dropped >= 2, 5, "the malformed messages dropped")
    res = lt.run(boss.cnp.call({"x": 1.5}, deadline=DEADLINE))
    assert (res.winner, res.cost, res.outcome) == ("w1", 0.5, "done")


def test_cnp_message_validation():
    def msg(body):
        return Message("contract_net", "a", "c", 1.0, body)

    cfp = CnpMessage.from_message(msg({"performative": "cfp", "task": {"x": 1}, "reply_by": 5.0}))
    assert cfp.task == {"x": 1} and cfp.reply_by == 5.0 and cfp.participants == ()
    p = CnpMessage.from_message(msg({"performative": "propose", "to": "b", "cost": 2, "info": {"k": 1}}))
    assert (p.cost, p.to, p.info) == (2.0, "b", {"k": 1})
    for bad in (
        {"performative": "propose", "cost": 1.0},  # no receiver
        {"performative": "propose", "to": "b", "cost": float("nan")},
        {"performative": "cfp", "task": {}},  # no reply_by
        {"performative": "failure", "to": "b", "info": [1]},
        {"performative": 3},
    ):
        with pytest.raises(MessageError):
            CnpMessage.from_message(msg(bad))
