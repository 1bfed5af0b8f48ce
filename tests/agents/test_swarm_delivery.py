"""Delivery within a neighbourhood radius on ground truth (agents.scenarios.swarm.delivery).

Unit tests of the metric itself: the ranges a receiver reports, the pairs owed (true distance at
send time, interpolated between ground-truth samples, within each receiver's listening window),
missing pairs named, gaps the monitor itself saw, and the monitor's verdict built on them.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from agents.scenarios.swarm import LatencyHistogram, NeighbourhoodDelivery, SwarmAgent, SwarmMonitor, expand_ranges
from agents.services import Message, SendPosition


def test_expand_ranges():
    assert expand_ranges([0, 2, 5, 5, 7, 9]).tolist() == [0, 1, 2, 5, 7, 8, 9]
    assert expand_ranges([]).tolist() == []


def _msg(sender: str, seq: int) -> Message:
    return Message("send_position", sender, f"p{seq}", time.time(), SendPosition(sender, 0.0, 0.0, 0.0))


def test_receiver_keeps_sequence_ranges_in_order_and_joins_them():
    a = SwarmAgent("s0", robot="r0", neighbourhood=3.0)
    assert a.cell_size == 3.0 and a.margin == pytest.approx(0.5 * (0.5 + 0.5))
    for seq in (0, 1, 2, 5, 6, 9, 4, 8, 3, 7, 12, 1):  # late, reordered and repeated messages
        a.receive(_msg("s1", seq))
    a.receive(_msg("s2", 4))
    assert a.ranges == {"s1": [0, 9, 12, 12], "s2": [4, 4]}
    s = a.stats()
    assert s["ranges"] == {"s1": [0, 9, 12, 12], "s2": [4, 4]} and "since" in s and s["t"] > 0
    assert "ranges" not in SwarmAgent("s9", robot="r9").stats()  # all-to-all: no ranges


def test_published_stats_carry_only_what_is_new_and_the_judge_adds_the_parts_up():
    a = SwarmAgent("s0", robot="r0", neighbourhood=3.0)
    mon = SwarmMonitor("m", robots=["r0"], neighbourhood=3.0)
    sent = []
    for batch in ((0, 1, 2, 5), (3, 4, 9), (), (6, 7, 8, 2)):  # a late message, an empty part, a repeat
        for seq in batch:
            a.receive(_msg("s1", seq))
        body = a.stats(part=True)
        assert "ranges" not in body and body["part"] == len(sent)
        sent.append(body)
    assert [b["new_ranges"] for b in sent] == [{"s1": [0, 2, 5, 5]}, {"s1": [3, 4, 9, 9]}, {}, {"s1": [2, 2, 6, 8]}]
    for body in sent:
        mon._on_stats(Message("swarm_stats", "s0", "x", time.time(), body))
    whole = mon.reports()["s0"]["ranges"]["s1"]
    assert set(expand_ranges(whole).tolist()) == set(range(10)) and a.ranges == {"s1": [0, 9]}
    assert mon.parts_lost == 0
    a.receive(_msg("s1", 10))
    a.stats(part=True)  # part 4 never reaches the judge
    a.receive(_msg("s1", 11))
    mon._on_stats(Message("swarm_stats", "s0", "x", time.time(), a.stats(part=True)))
    assert mon.parts_lost == 1
    assert "1 swarm_stats part(s) never came" in mon.judge(10.0, final=False).text


def test_neighbourhood_arguments_are_checked():
    with pytest.raises(ValueError, match="neighbourhood"):
        SwarmAgent("s0", robot="r0", neighbourhood=-1)
    with pytest.raises(ValueError, match="shared"):
        SwarmAgent("s0", robot="r0", neighbourhood=2.0, shared=False)
    with pytest.raises(ValueError, match="margin"):
        SwarmAgent("s0", robot="r0", neighbourhood=2.0, margin=-0.1)
    with pytest.raises(ValueError, match="neighbourhood"):
        SwarmMonitor("m", robots=2, neighbourhood=-3)
    with pytest.raises(ValueError, match="bundle: true bundles cell broadcasts; give a neighbourhood"):
        SwarmAgent("s0", robot="r0", bundle=True)
    with pytest.raises(ValueError, match="bundle 'yes' must be true or false"):
        SwarmAgent("s0", robot="r0", neighbourhood=2.0, bundle="yes")


def _three(settle: float = 0.0) -> NeighbourhoodDelivery:
    """r0 at the origin; r1 drives from 1 m to 5 m along x between t=100 and t=101; r2 at 10 m."""
    d = NeighbourhoodDelivery(["r0", "r1", "r2"], radius=2.0, settle=settle)
    d.truth(100.0, np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0]]))
    d.truth(101.0, np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]]))
    return d


def _report(robot: str, ranges: dict, since: float = 0.0, t: float = 1e12) -> dict:
    return {"robot": robot, "since": since, "t": t, "ranges": ranges}


def test_pairs_owed_are_those_within_the_radius_at_send_time():
    d = _three()
    d.sent("a0", "r0", 0, 100.1)  # r1 at 1.4 m: owed to r1; r2 at 10 m: not
    d.sent("a0", "r0", 1, 100.5)  # r1 at 3.0 m: owed to nobody
    d.sent("a1", "r1", 0, 100.2)  # r0 at 1.8 m: owed to r0
    d.sent("a1", "r1", 1, 100.3)  # r0 at 2.2 m: not
    d.sent("a0", "r0", 3, 99.0)  # before the first sample: not judged; the monitor never saw seq 2
    full = {
        "a0": _report("r0", {"a1": [0, 0]}),
        "a1": _report("r1", {"a0": [0, 0]}),
        "a2": _report("r2", {}),
    }
    r = d.result(full)
    assert (r.expected, r.received, r.sends, r.monitor_missed) == (2, 2, 4, 1)
    assert r.pct == 100.0 and r.missing == []
    # r1 did not get a0's broadcast 0: one pair missing, named with its true distance at the sample before
    r = d.result({**full, "a1": _report("r1", {"a0": [1, 3]})})
    assert (r.expected, r.received) == (2, 1) and r.missing == [("a1", "a0", 0, 1.0)]
    # an agent that has not reported owes nothing (the monitor counts the reporting agents apart)
    r = d.result({"a0": full["a0"]})
    assert (r.expected, r.received) == (1, 1)


def test_listening_window_and_settle():
    d = _three(settle=0.5)
    d.sent("a1", "r1", 0, 100.2)  # r0 within 2 m of both
    d.sent("a1", "r1", 1, 100.05)
    r = d.result({"a0": _report("r0", {}, since=99.4), "a1": _report("r1", {})})
    assert (r.expected, r.received) == (2, 0)
    r = d.result({"a0": _report("r0", {}, since=99.6), "a1": _report("r1", {})})
    assert r.expected == 1  # only the broadcast at 100.2 (>= 99.6 + 0.5)
    r = d.result({"a0": _report("r0", {}, t=100.6), "a1": _report("r1", {})})
    assert r.expected == 1 and r.missing[0][2] == 1  # the report at 100.6 speaks up to 100.1 only


def test_many_robots_vectorised_against_brute_force():
    rng = np.random.default_rng(3)
    n, radius = 60, 3.0
    names = [f"r{i}" for i in range(n)]
    d = NeighbourhoodDelivery(names, radius, settle=0.0)
    X = [rng.uniform(0, 15, (n, 2))]
    for _ in range(4):
        X.append(X[-1] + rng.uniform(-0.5, 0.5, (n, 2)))
    for k, x in enumerate(X):
        d.truth(float(k), x)
    sends = [(i, q, float(rng.uniform(0, 4))) for i in range(n) for q in range(5)]
    for i, q, t in sends:
        d.sent(f"a{i}", f"r{i}", q, t)
    owed = set()
    for i, q, t in sends:
        k = min(int(t), 3)
        P = X[k] + (t - k) * (X[k + 1] - X[k])
        for j in range(n):
            if j != i and np.hypot(*(P[j] - P[i])) <= radius:
                owed.add((j, i, q))
    # every receiver reports all of every sender's broadcasts but drops one owed pair
    drop = sorted(owed)[7]
    reports = {}
    for j in range(n):
        ranges = {f"a{i}": [0, 4] for i in range(n) if i != j}
        if j == drop[0]:
            q = drop[2]
            ranges[f"a{drop[1]}"] = [x for x in ([0, q - 1] if q else []) + ([q + 1, 4] if q < 4 else [])]
        reports[f"a{j}"] = _report(f"r{j}", ranges)
    r = d.result(reports)
    assert r.expected == len(owed) > 50
    assert r.received == len(owed) - 1
    assert r.missing[0][:3] == (f"a{drop[0]}", f"a{drop[1]}", drop[2])


def test_monitor_verdict_within_the_radius():
    m = SwarmMonitor("mon", robots=3, duration=10, neighbourhood=2.0, settle=0.0)
    d = m.delivery
    d.truth(100.0, np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0]]))
    d.truth(101.0, np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0]]))
    d.sent("s0", "r0", 0, 100.5)
    d.sent("s1", "r1", 0, 100.5)
    h = LatencyHistogram()
    h.add(0.004)
    m.stats = {
        "s0": {**_report("r0", {"s1": [0, 0]}), "latency": h.to_dict()},
        "s1": {**_report("r1", {"s0": [0, 0]}), "latency": h.to_dict()},
        "s2": {**_report("r2", {}), "latency": h.to_dict()},
    }
    v = m.judge(10.0)
    assert v.ok and "delivery within 2 m 100.0 % (2/2)" in v.text, v.text
    m.stats["s1"]["ranges"] = {}
    v = m.judge(10.0)
    assert not v.ok and "delivery within 2 m 50.0 % (1/2)" in v.text and "('s1', 's0', 0, 1.0)" in v.text
    assert "broadcasts seen" in m.judge(5.0, final=False).text


def test_ledger_hands_each_agent_the_messages_of_its_cells_in_one_batch():
    from types import SimpleNamespace

    from agents.cells import cell_of
    from agents.scenarios.swarm.ledger import NearLedger, latency_bins
    from agents.scenarios.swarm.metrics import latency_bin

    lat = np.array([0.0, 1e-6, 2e-5, 0.004, 0.05, 3.0, 1e3])
    assert latency_bins(lat).tolist() == [latency_bin(x) for x in lat]
    a0 = SwarmAgent("n0", robot="q0", neighbourhood=2.0)
    a1 = SwarmAgent("n1", robot="q1", neighbourhood=2.0)
    c_left, c_right = cell_of(0.5, 0.5, 2.0), cell_of(2.5, 0.5, 2.0)
    by_cell = {c_left: [a0, a1], c_right: [a1]}
    hub = SimpleNamespace(cell_size=2.0, agents_in=lambda c: by_cell.get(c, []))
    ledger = NearLedger(hub)
    a0.join_ledger(ledger)
    a1.join_ledger(ledger)
    now = time.time()

    def put(sender: str, seq: int, x: float) -> None:
        m = Message("send_position", sender, f"p{seq}", now - 0.004, SendPosition(sender, x, 0.5, 0.0))
        ledger.on_message(hub, m, now)

    for seq in range(3):
        put("n0", seq, 0.5)  # in the left cell: n1 hears it; n0 not its own
        put("n9", seq, 2.5)  # in the right cell: n1 only
    put("n8", 0, 9.0)  # in no agent's cells
    assert a1.received == 0  # nothing before the flush
    ledger.flush()
    assert a0.ranges == {} and a0.received == 0
    assert a1.ranges == {"n0": [0, 2], "n9": [0, 2]} and a1.received == 6
    assert a1.latency.n == 6 and a1.latency.quantile(0.5) == pytest.approx(0.004, rel=0.26)
    assert "received 6 from 2 sender(s) within 2 m" in a1.status(), a1.status()
    put("n9", 4, 2.5)  # seq 3 lost
    ledger.flush()
    assert a1.ranges["n9"] == [0, 2, 4, 4]
