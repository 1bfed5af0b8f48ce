"""The neighbourhood swarm's per-hub accounting (agents.scenarios.swarm.ledger.NearLedger).

The hub accounts the (receiver, message) pairs of all its agents at once and splits them per agent
only when an agent's figures are read. Checked against the per-agent path it replaces, written
here message by message: each agent gets exactly the (sender, sequence number) keys of the
messages published in the cells it watched when they arrived (never its own), the same count and
the same latency histogram -- across several flushes, cells that change between them, agents that
ask rarely (their older batches parked), join late or leave.
"""

from __future__ import annotations

import random
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest

from agents.cells import cell_of, cells_near
from agents.scenarios.swarm import LatencyHistogram, SwarmAgent
from agents.scenarios.swarm.ledger import NearLedger, Received
from agents.scenarios.swarm.metrics import latency_bin
from agents.services import Message, SendPosition

SIZE = 2.0


class _Reference:
    """The per-agent path: every message handed to every agent its cells list, one at a time."""

    def __init__(self) -> None:
        self.got: dict[str, Received] = {}
        self.hist: dict[str, LatencyHistogram] = {}
        self.n: dict[str, int] = {}

    def account(self, by_cell: dict, msgs: list[tuple[str, int, float, float, float]]) -> None:
        for sender, seq, x, y, lat in msgs:
            for a in by_cell.get(cell_of(x, y, SIZE), []):
                if a.id == sender:
                    continue
                self.got.setdefault(a.id, Received()).add(sender, seq)
                h = self.hist.setdefault(a.id, LatencyHistogram())
                h.add_bin(latency_bin(max(lat, 0.0)), max(lat, 0.0))
                self.n[a.id] = self.n.get(a.id, 0) + 1


def _cells(agents: list[SwarmAgent], rng: random.Random) -> dict[str, list[SwarmAgent]]:
    """Each agent watches the cells within 3 m of a random point (one agent listed twice in a cell,
    as a hub may list an agent whose cells were added one robot at a time)."""
    by_cell: dict[str, list[SwarmAgent]] = {}
    for a in agents:
        for c in sorted(cells_near(rng.uniform(-8, 8), rng.uniform(-8, 8), 3.0, SIZE)):
            by_cell.setdefault(c, []).append(a)
    c = next(iter(by_cell))
    by_cell[c].append(by_cell[c][0])
    return by_cell


def test_per_hub_accounting_equals_the_per_agent_path():
    rng = random.Random(7)
    agents = [SwarmAgent(f"h{i}", robot=f"r{i}", neighbourhood=SIZE) for i in range(40)]
    late = SwarmAgent("late", robot="rl", neighbourhood=SIZE)
    hub = SimpleNamespace(cell_size=SIZE, by_cell={})
    hub.agents_in = lambda c: hub.by_cell.get(c, [])
    ledger = NearLedger(hub, keep=2)  # few batches kept: the rare askers' slices get parked
    for a in agents:
        a.join_ledger(ledger)
    stranger = SwarmAgent("x0", robot="rx", neighbourhood=SIZE)  # listed in cells, never joined
    ref = _Reference()
    senders = [a.id for a in agents] + ["far0", "far1", "late"]
    seqs = dict.fromkeys(senders, 0)
    now = time.time()
    for flush in range(8):
        if flush == 3:
            late.join_ledger(ledger)
            agents.append(late)
        hub.by_cell = _cells(agents + [stranger], rng)
        msgs = []
        for _ in range(300):
            s = rng.choice(senders)
            if rng.random() < 0.9:  # a few sequence numbers lost
                lat = rng.choice([-0.001, 0.0, 2e-5, rng.uniform(0.0005, 0.2)])
                x, y = rng.uniform(-12, 12), rng.uniform(-12, 12)
                sent = now - lat
                msgs.append((s, seqs[s], x, y, now - sent))  # the latency the receiver works out
                body = SendPosition(s, x, y, 0.0)
                ledger.on_message(hub, Message("send_position", s, f"p{seqs[s]}", sent, body), now)
            seqs[s] += 1
        ledger.on_message(hub, Message("send_position", "h0", "hello", now, SendPosition("h0", 0.0, 0.0, 0.0)), now)
        ref.account({c: [a for a in v if a is not stranger] for c, v in hub.by_cell.items()}, msgs)
        ledger.flush()
        if flush % 3 == 0:  # some agents read their figures between flushes, the others only at the end
            for a in agents[::5]:
                assert a.received == ref.n.get(a.id, 0)
    assert ledger.pairs == sum(ref.n.values()) > 5_000
    for a in agents:
        want = ref.got.get(a.id, Received())
        assert a.ranges == want.ranges(), a.id
        assert a.id not in a.ranges
        assert a.received == ref.n.get(a.id, 0)
        h, w = a.latency.to_dict(), ref.hist.get(a.id, LatencyHistogram()).to_dict()
        assert (h["bins"], h["counts"], h["max"]) == (w["bins"], w["counts"], w["max"]), a.id
        assert h["sum"] == pytest.approx(w["sum"], rel=1e-12, abs=1e-12)
    assert stranger.received == 0 and stranger.ranges == {}
    assert len(ledger._batches) <= 2


def test_an_agent_that_left_is_no_longer_accounted():
    hub = SimpleNamespace(cell_size=SIZE)
    a, b = SwarmAgent("l0", robot="q0", neighbourhood=SIZE), SwarmAgent("l1", robot="q1", neighbourhood=SIZE)
    hub.agents_in = lambda c: [a, b] if c == cell_of(0.5, 0.5, SIZE) else []
    ledger = NearLedger(hub)
    a.join_ledger(ledger)
    b.join_ledger(ledger)
    now = time.time()
    ledger.on_message(hub, Message("send_position", "s", "p0", now, SendPosition("s", 0.5, 0.5, 0.0)), now)
    ledger.flush()
    assert a.ranges == {"s": [0, 0]}  # taken before it leaves
    ledger.leave(a)
    ledger.on_message(hub, Message("send_position", "s", "p1", now, SendPosition("s", 0.5, 0.5, 0.0)), now)
    ledger.flush()
    assert a.ranges == {"s": [0, 0]} and a.received == 1
    assert b.ranges == {"s": [0, 1]} and b.received == 2
    assert ledger.take(a) is None


def test_flush_of_five_hundred_agents_costs_no_call_per_agent():
    """500 agents each watching ~12 cells of a 50 m square, 1000 messages (~60,000 pairs) per
    flush, as one host of the 1000-robot swarm: the flush makes no Python call per agent or pair
    (its CPU against the per-agent path: benchmarks/bench_ledger.py)."""
    rng = np.random.default_rng(3)
    agents = [SwarmAgent(f"k{i}", robot=f"k{i}", neighbourhood=5.0) for i in range(500)]
    by_cell: dict[str, list[SwarmAgent]] = {}
    for a, (x, y) in zip(agents, rng.uniform(0, 50, (500, 2)), strict=True):
        for c in cells_near(x, y, 5.5, 5.0):
            by_cell.setdefault(c, []).append(a)
    hub = SimpleNamespace(cell_size=5.0, agents_in=lambda c: by_cell.get(c, []))
    ledger = NearLedger(hub)
    for a in agents:
        a.join_ledger(ledger)
    now = time.time()
    calls = []
    for rep in range(5):
        for i, (x, y) in enumerate(rng.uniform(0, 50, (1000, 2))):
            s = f"k{i % 500}"
            ledger.on_message(
                hub, Message("send_position", s, f"p{2 * rep + i // 500}", now - 0.01, SendPosition(s, x, y, 0.0)), now
            )
        n = [0]

        def count(frame, event, arg, n=n):
            if event == "call":  # Python-level calls only (numpy's C functions are c_call)
                n[0] += 1

        sys.setprofile(count)
        try:
            ledger.flush()
        finally:
            sys.setprofile(None)
        calls.append(n[0])
    assert ledger.pairs > 150_000
    # one Python call per watched cell (its receivers) at most, none per agent or pair
    assert max(calls) < len(by_cell) + 100 < len(agents), (calls, len(by_cell))
    assert sum(a.received for a in agents) == ledger.pairs


def test_received_merges_batches_and_singles_into_sorted_unique_keys():
    from agents.scenarios.swarm.ledger import code

    rng = np.random.default_rng(3)
    r = Received()
    seen: set[tuple[str, int]] = set()
    for step in range(30):  # batches that repeat and interleave, merged at every other step
        for _ in range(3):
            senders = rng.choice([f"s{i}" for i in range(20)], 40)
            seqs = rng.integers(0, 200, 40)
            r.add_keys(np.array([(code(s) << 24) | int(q) for s, q in zip(senders, seqs, strict=True)]))
            seen.update(zip(senders.tolist(), seqs.tolist(), strict=True))
        r.add("s3", step)
        seen.add(("s3", step))
        if step % 2:
            k = r.keys()
            assert np.all(np.diff(k) > 0)  # sorted, no repeats
            assert len(r) == len(seen)
    want: dict[str, list[int]] = {}
    for s in sorted({s for s, _ in seen}):
        q = sorted(q for t, q in seen if t == s)
        runs = [q[0], q[0]]
        for x in q[1:]:
            if x == runs[-1] + 1:
                runs[-1] = x
            else:
                runs += [x, x]
        want[s] = runs
    assert r.ranges() == want
