"""The Swarm scenario (thesis 4.2.3): a crowd of wall-following robots broadcasting positions.

Unit tests: the latency histogram, the receivers' gap accounting, the monitor's overlap and spread
check and verdict, constructor errors, the crowd world. Integration: ``rsal sim`` with a crowd in
its own process, the SwarmAgents and the SwarmMonitor on one AgentHost in this process (one Zenoh
session), over loopback; the simulator runs at a speed-up and the agents follow its clock
(``sim_time``), so periods and the duration are simulated seconds. The run ends on the monitor's
verdict after the simulated duration; then the agents stop broadcasting and every receiver's count
from every sender is checked against the sender's own count (every message received by every
subscriber), with loss and latency printed. The latency target (p99 < 50 ms) is measured by
``benchmarks/bench_swarm.py``; here the monitor's bound is loose so that a loaded machine does not
fail a functional test.
"""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
import pytest

from agents.runtime import AgentHost
from agents.scenarios.swarm import (
    LATENCY_EDGES,
    Disperse,
    LatencyHistogram,
    SwarmAgent,
    SwarmMonitor,
    away_from,
    crowd_world,
    latency_bin,
    latency_bins,
    write_crowd_world,
)
from agents.scenarios.swarm.messages import STATS_SERVICE
from agents.services import Message, Outcome, SendPosition
from rsal.behaviours import Sectors
from rsal.client import Fabric
from rsal.data import Position
from rsal.keys import DeviceAddr
from rsal.transport import TransportArgs
from simulator.loader import load_world
from tests.conftest import MAPS, SPEEDUP, free_port, rsal_cmd, wait_until

# The hundred-robot run at 2x: its monitor takes ground truth with 100 get_pose calls every 0.5
# simulated s and the test wants at least 60 samples in 60 s; at 2x a 2-core machine running the
# suite alone takes 94-114 (at 3x, or with heavy other work on the machine, too few).
SPEEDUP_CROWD = "2"


# ---------------------------------------------------------------------------- unit
def test_latency_histogram_quantiles_merge_and_round_trip():
    h = LatencyHistogram()
    for ms in [1.0] * 98 + [20.0, 40.0]:
        h.add(ms / 1000)
    assert h.n == 100
    assert 0.001 <= h.quantile(0.5) <= 0.00126  # upper edge of the bin holding 1 ms
    assert 0.020 <= h.quantile(0.99) <= 0.0252
    assert h.quantile(1.0) == pytest.approx(0.040)  # never above the maximum seen
    g = LatencyHistogram.from_dict(h.to_dict())
    g.merge(h)
    assert g.n == 200 and g.max_s == pytest.approx(0.040)
    h.add(0.0)  # a clock step backwards lands in the first bin
    assert h.to_dict()["bins"][0] == 0 and h.counts[0] == 1 and len(LATENCY_EDGES) == h.counts.size + 1
    with pytest.raises(ValueError):
        LatencyHistogram.from_dict({"bins": [1, 2], "counts": [1]})


def test_latency_bins_have_round_edges_so_a_50_ms_limit_is_decided_exactly():
    assert {0.001, 0.002, 0.005, 0.01, 0.02, 0.04, 0.05, 0.1} <= set(LATENCY_EDGES.tolist())
    under, at = LatencyHistogram(), LatencyHistogram()
    for _ in range(1000):
        under.add(0.0499)  # all under 50 ms: the bound is the edge 50 ms (or the largest seen)
        at.add(0.0501)
    under.add(0.5)
    at.add(0.5)  # the bin above 50 ms: its bound is the next edge, 63 ms
    assert under.quantile(0.99) == 0.05
    assert at.quantile(0.99) == pytest.approx(0.063)
    lat = np.array([-1.0, 0.0, 1e-5, 0.00125, 0.0499, 0.05, 99.0, 1e9])
    assert latency_bins(lat).tolist() == [latency_bin(v) for v in lat.tolist()]
    assert latency_bin(0.05) == latency_bin(0.0501) == latency_bin(0.0499) + 1


def _msg(sender: str, seq: int, x: float = 1.0, t: float | None = None) -> Message:
    return Message("send_position", sender, f"p{seq}", time.time() if t is None else t, SendPosition(sender, x, 0, 0))


def test_receiver_counts_gaps_per_sender_and_keeps_poses_on_its_board():
    a = SwarmAgent("s0", robot="r0")
    for seq in (0, 1, 2, 4, 5):  # 3 lost
        a.receive(_msg("r1", seq, x=float(seq)))
    for seq in (7, 8):  # joined late: counted from the first seen
        a.receive(_msg("r2", seq))
    a.receive(_msg("s0", 0))  # its own broadcast is not counted
    assert a.delivery() == (7, 8)
    assert a.positions()["r1"].x == 5.0 and set(a.positions()) == {"r1", "r2"}
    s = a.stats()
    assert s["received"] == 7 and s["expected"] == 8 and s["senders"] == 2
    assert LatencyHistogram.from_dict(s["latency"]).n == 7


def test_monitor_counts_overlaps_spread_and_judges():
    m = SwarmMonitor("mon", robots=3, duration=10)
    assert m.robots == ["r0", "r1", "r2"]
    m.check(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]]), 0.0)
    assert m.overlaps == 0 and m.closest == pytest.approx(1.0)
    m.check(np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 2.0]]), 1.0)  # 0.3 m < 2 * 0.19 - 0.02
    assert m.overlaps == 1 and m.closest == pytest.approx(0.3)
    h = LatencyHistogram()
    h.add(0.004)
    for sender in ("s0", "s1", "s2"):
        m.stats[sender] = {"received": 10, "expected": 10, "latency": h.to_dict()}
    v = m.judge(10.0)
    assert v.final and not v.ok and v.event == "verdict" and v.subject == "swarm"
    assert "1 overlap" in v.text and "delivery 100.0 %" in v.text
    m.overlaps = 0
    assert m.judge(10.0).ok
    m.stats["s2"] = {"received": 9, "expected": 10, "latency": h.to_dict()}
    assert "delivery 96.67 % < 100 %" in m.judge(10.0).text


def test_monitor_counts_latency_from_each_agents_first_report_of_the_judged_run():
    m = SwarmMonitor("mon", robots=2, duration=10, max_p99_ms=50)
    start_up, running = LatencyHistogram(), LatencyHistogram()
    for _ in range(100):
        start_up.add(0.8)  # a crowd starting: late deliveries
    for _ in range(1000):
        running.add(0.004)
    later = LatencyHistogram()
    later.merge(start_up)
    later.merge(running)

    def report(sender: str, h: LatencyHistogram) -> None:
        m._on_stats(Message(STATS_SERVICE, sender, "", 0.0, {"received": 1, "expected": 1, "latency": h.to_dict()}))

    report("s0", start_up)  # before the run opened: the whole histogram counts
    report("s1", start_up)
    assert "p99 latency 800 ms" in m.judge(10.0).text and not m.judge(10.0).ok
    m.window_from = time.time()
    report("s0", start_up)  # the first report of the judged run: its base
    report("s1", start_up)
    report("s0", later)
    report("s1", later)
    got, want, hist, reporting = m.merged()
    assert hist.n == 2000 and reporting == 2
    v = m.judge(10.0)
    assert v.ok and "p99 latency 5 ms" in v.text, v.text  # the upper edge of 4 ms's bin


def test_monitor_judges_real_time_and_the_hosts_control_overruns_of_the_judged_run():
    m = SwarmMonitor("mon", robots=2, duration=10, min_rtf=0.95, max_overrun_pct=5)
    hists = {"s0": LatencyHistogram(), "s1": LatencyHistogram()}

    def report(sender: str, loop: str, cycles: int, overruns: int) -> None:
        hists[sender].add(0.004)  # a delivery between reports: the judged run has latencies
        body = {"received": 1, "expected": 1, "latency": hists[sender].to_dict()}
        body["loop"] = {"id": loop, "cycles": cycles, "overruns": overruns}
        m._on_stats(Message(STATS_SERVICE, sender, "", 0.0, body))

    report("s0", "hostA:1", 100, 90)  # start-up's overruns, before the judged run
    m.window_from = time.time()
    report("s0", "hostA:1", 200, 95)  # each loop's first report of the judged run: its base
    report("s1", "hostB:2", 50, 0)
    report("s0", "hostA:1", 500, 101)  # 300 cycles, 6 overruns
    report("s1", "hostB:2", 350, 3)  # 300 cycles, 3 overruns
    assert m.overrun_pct() == pytest.approx(100 * 9 / 600)
    v = m.judge(10.0, wall=10.2)
    assert v.ok and "0.98 x real time" in v.text and "overruns 1.5 %" in v.text, v.text
    v = m.judge(10.0, wall=12.5)
    assert not v.ok and "simulation at 0.80 x real time < 0.95" in v.text
    report("s1", "hostB:2", 450, 40)  # 37 more overruns in 100 cycles
    v = m.judge(10.0, wall=10.0)
    assert not v.ok and "control overruns 6.6 % >= 5 %" in v.text, v.text
    assert SwarmMonitor("m2", robots=1).judge(1.0).text.count("overruns") == 0  # no loop reported: not said
    with pytest.raises(ValueError, match="min_rtf"):
        SwarmMonitor("m3", robots=1, min_rtf=-1)


def test_monitor_opens_the_judged_run_when_the_last_agent_reports_and_skips_a_bad_first_report():
    m = SwarmMonitor("mon", robots=2, duration=10, startup_timeout=30)
    good = {"received": 1, "expected": 1, "latency": LatencyHistogram().to_dict()}

    def report(sender: str, body: dict) -> None:
        m._on_stats(Message(STATS_SERVICE, sender, "", 0.0, body))

    async def run() -> tuple[float | None, float | None]:
        m._all_reported = asyncio.Event()
        waiting = asyncio.create_task(m._await_reports())
        report("s0", good)
        await asyncio.sleep(0)
        before = m.window_from  # one of two reported: still waiting
        report("s1", good)
        await asyncio.wait_for(waiting, 5.0)  # not the 30 s start-up timeout
        return before, m.window_from

    before, opened = asyncio.run(run())
    assert before is None and opened is not None
    report("s0", {"received": 1, "expected": 1, "latency": {"bins": "x"}})  # unparseable: not its base
    assert "s0" not in m.base and m.stats["s0"] is good
    report("s0", good)
    assert "s0" in m.base and m.merged()[2].n == 0  # its base minus itself: nothing yet


def test_disperse_steers_away_from_neighbours_until_a_wall_is_in_sight():
    me = Position(0.0, 0.0, 0.0)
    h = away_from(me, [Position(1.0, 0.0), Position(0.0, 3.0), Position(50.0, 50.0)], radius=4.0)
    assert h == pytest.approx(math.atan2(-1 / 3, -1.0))  # each pushes with 1/d: mostly away from the nearer
    assert away_from(me, [Position(10.0, 0.0)], radius=4.0) is None
    b = Disperse()
    b.set_wallfollow(True)
    open_space = Sectors.empty()
    assert b.step(open_space, 0.0) == (b.p.cruise_speed, 0.0) and b.state == "disperse"  # straight on
    b.heading, b.yaw = math.pi / 2, 0.0
    v, w = b.step(open_space, 0.1)
    assert w == pytest.approx(b.p.turn_rate) and v < b.p.cruise_speed  # turning left, towards the heading
    wall = Sectors.empty()
    wall.dist[9] = 0.6  # a wall on the left, at the wall distance
    b.step(wall, 0.2)
    assert b.state == "wallfollow"


def test_away_headings_is_away_from_for_many_robots_at_once():
    from agents.scenarios.swarm import away_headings

    rng = np.random.default_rng(5)
    me = rng.uniform(0, 10, (40, 2))
    others = np.vstack([me[:30] + rng.normal(0, 0.05, (30, 2)), rng.uniform(0, 10, (20, 2)), [[np.nan, np.nan]]])
    own = np.r_[np.arange(30), np.full(10, -1)]  # robot i's own broadcast is row i (30 .. 39: none)
    radius = rng.uniform(1.0, 3.0, 40)
    h = away_headings(me, others, radius, own)
    for i in range(40):
        rest = [Position(*o) for k, o in enumerate(others[:-1]) if k != own[i]]
        want = away_from(Position(*me[i]), rest, radius[i])
        assert (np.isnan(h[i]) and want is None) or h[i] == pytest.approx(want), i
    assert np.isnan(h).sum() < 40  # some have neighbours


def test_constructor_errors_are_clear():
    with pytest.raises(TypeError):
        SwarmAgent("s0", robot="r0", speed=3)  # unknown argument
    with pytest.raises(ValueError, match="robot id is required"):
        SwarmAgent("s0", robot="")
    with pytest.raises(ValueError, match="side"):
        SwarmAgent("s0", robot="r0", side="up")
    with pytest.raises(ValueError, match="crowd: true needs vector: true"):
        SwarmAgent("s0", robot="r0", crowd=True, vector=False)
    with pytest.raises(ValueError, match="crowd 'yes' must be true or false"):
        SwarmAgent("s0", robot="r0", crowd="yes")
    with pytest.raises(ValueError, match="robots"):
        SwarmMonitor("m", robots=0)
    with pytest.raises(ValueError, match="duration"):
        SwarmMonitor("m", duration=0)


def test_crowd_world_is_the_checked_in_swarm_world_and_loads():
    assert (MAPS / "swarm.world").read_text() == crowd_world(100)
    assert (MAPS / "swarm_gps.world").read_text() == crowd_world(100, localization="gps")
    assert (MAPS / "swarm1000.world").read_text() == crowd_world(1000, localization="gps")
    gps = load_world(str(MAPS / "swarm_gps.world"))
    assert {m.localization for m in gps.models if m.name.startswith("r")} == {"gps"}
    spec = load_world(str(MAPS / "swarm.world"))
    names = [m.name for m in spec.models if m.name.startswith("r")]
    assert len(names) == 100
    with pytest.raises(ValueError, match="do not fit"):
        crowd_world(2000)
    with pytest.raises(ValueError, match="localization"):
        crowd_world(4, localization="amcl")


# ---------------------------------------------------------------------------- integration
async def _until(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(0.05)


async def _swarm_run(ep: str, n: int, duration: float, mixed: bool, follow, **kw) -> dict:
    async with AgentHost.connect(TransportArgs(connect=[ep])) as host:
        await asyncio.to_thread(follow, host.session)  # the agents' periods count simulated seconds
        truth = Fabric(host.session, own_session=False)
        sim_addr = DeviceAddr("sim", "simulation", 0)
        before = await asyncio.to_thread(truth.rpc, sim_addr, "get_poses", {}, timeout=30)
        verdicts: list[Outcome] = []
        t0 = time.monotonic()
        # mixed: every other agent has its own subscription and blackboard instead of the host's
        agents = [
            SwarmAgent(f"swarm{i}", robot=f"r{i}", startup_timeout=120, shared=not (mixed and i % 2), **kw)
            for i in range(n)
        ]
        await asyncio.gather(*(host.start(a) for a in agents))
        started = time.monotonic() - t0
        # Latency is judged by benchmarks/bench_swarm.py; here a loaded machine must not fail the run.
        mon = SwarmMonitor("monitor", robots=n, duration=duration, startup_timeout=60, max_p99_ms=1000)
        await host.start(mon)
        await _until(lambda: mon.verdict is not None, duration * 4 + 120, "the monitor's verdict")
        verdicts.append(mon.verdict)
        moved = [a.pioneer.distance for a in agents]
        after = await asyncio.to_thread(truth.rpc, sim_addr, "get_poses", {}, timeout=30)
        p0 = dict(zip(before["names"], before["poses"], strict=True))
        p1 = dict(zip(after["names"], after["poses"], strict=True))
        truly_moved = [math.dist(p0[a.robot][:2], p1[a.robot][:2]) for a in agents]  # ground truth
        # Stop the broadcasts, then every receiver must have got every message of every sender.
        for a in agents:
            a.stop_broadcast()
        await asyncio.sleep(0)
        sent = {a.id: a.sent for a in agents}

        def drained() -> bool:
            return all(a.senders.get(s, [0, -1, 0])[1] == sent[s] - 1 for a in agents for s in sent if s != a.id)

        try:
            await _until(drained, 30, "the last broadcasts to reach every receiver")
        except pytest.fail.Exception:
            pass  # the counts below show what is missing
        got = want = 0
        hist = LatencyHistogram()
        for a in agents:
            hist.merge(a.latency)
            for s, cnt in sent.items():
                if s == a.id:
                    continue
                first, _last, rec = a.senders.get(s, [0, -1, 0])
                got += rec
                want += cnt - first  # every message from the first one this receiver could see
        hub = agents[0]._hub
        return {
            "verdict": verdicts[0],
            "started_s": started,
            "got": got,
            "want": want,
            "p50_ms": 1000 * hist.quantile(0.5),
            "p99_ms": 1000 * hist.quantile(0.99),
            "max_ms": 1000 * hist.max_s,
            "moved": moved,
            "truly_moved": truly_moved,
            "control_load": hub.load() if hub else math.nan,
            "overruns": hub.overruns if hub else -1,
            "closest": mon.closest,
            "samples": mon.samples,
            "spread": (mon.spread[0][1], mon.spread[-1][1]),
            "boards": [len(a.positions()) for a in agents],
            "sent": sum(sent.values()),
        }


def _run_swarm_test(
    procs, sim_time, tmp_path, n: int, duration: float, speedup: str, mixed: bool = False, **kw
) -> dict:
    world = write_crowd_world(tmp_path / f"crowd{n}.world", n)
    ep = f"tcp/127.0.0.1:{free_port()}"
    sim = procs(rsal_cmd("sim", str(world), "--listen", ep, "--no-map", "--speedup", speedup))
    wait_until(lambda: "[sim]" in sim.output() or not sim.alive(), 60, "the simulator's start line")
    assert sim.alive(), sim.output()
    t0 = time.monotonic()
    r = asyncio.run(_swarm_run(ep, n, duration, mixed, sim_time, **kw))
    r["wall_s"] = time.monotonic() - t0
    loss = r["want"] - r["got"]
    pct = 100.0 * r["got"] / r["want"] if r["want"] else 0.0
    print(
        f"\nswarm n={n} sim_s={duration:g} wall_s={r['wall_s']:.1f} startup_s={r['started_s']:.1f} "
        f"sent={r['sent']} delivered={r['got']}/{r['want']} delivery={pct:.3f}% lost={loss} "
        f"latency p50={r['p50_ms']:.1f}ms p99={r['p99_ms']:.1f}ms max={r['max_ms']:.1f}ms "
        f"control_load={r['control_load']:.2f} overruns={r['overruns']} closest={r['closest']:.2f}m "
        f"samples={r['samples']}\n{r['verdict'].text}"
    )
    assert sim.alive(), sim.output()
    return r


def test_ten_robots_swarm(procs, sim_time, tmp_path):
    r = _run_swarm_test(procs, sim_time, tmp_path, 10, 15.0, SPEEDUP, mixed=True)
    v = r["verdict"]
    assert v.final and v.event == "verdict" and "10 robots" in v.text
    assert "no overlap" in v.text and r["closest"] >= 2 * 0.19 - 0.02
    assert r["got"] == r["want"] > 0, "every position message must reach every subscriber"
    assert sum(d > 1.0 for d in r["moved"]) >= 8, f"the robots must drive: {r['moved']}"
    assert r["spread"][1] > r["spread"][0] + 0.5, f"the crowd must spread out: {r['spread']}"
    assert v.ok, v.text


def test_ten_robots_swarm_through_the_crowd_device(procs, sim_time, tmp_path):
    """The host reads and commands its ten robots through the simulator's crowd device (one
    describe, one data message per step, one command message per cycle): the robots drive on
    ground truth and every broadcast reaches every subscriber."""
    r = _run_swarm_test(procs, sim_time, tmp_path, 10, 15.0, SPEEDUP, crowd=True)
    v = r["verdict"]
    assert v.final and v.event == "verdict" and "10 robots" in v.text
    assert "no overlap" in v.text
    assert r["got"] == r["want"] > 0, "every position message must reach every subscriber"
    assert sum(d > 1.0 for d in r["truly_moved"]) >= 8, f"the robots must drive (ground truth): {r['truly_moved']}"
    assert sum(d > 1.0 for d in r["moved"]) >= 8, f"and count their odometry: {r['moved']}"
    assert r["spread"][1] > r["spread"][0] + 0.5, f"the crowd must spread out: {r['spread']}"
    assert v.ok, v.text


@pytest.mark.timeout(600)
def test_hundred_robots_sixty_seconds(procs, sim_time, tmp_path):
    r = _run_swarm_test(procs, sim_time, tmp_path, 100, 60.0, SPEEDUP_CROWD)
    v = r["verdict"]
    assert "100 robots" in v.text and "no overlap" in v.text
    assert r["samples"] >= 60
    assert r["got"] == r["want"] > 0, "every position message must reach every subscriber"
    assert sum(d > 1.0 for d in r["moved"]) >= 80
    assert r["spread"][1] > r["spread"][0] + 0.5, f"the crowd must spread out: {r['spread']}"
    assert v.ok, v.text


# ---------------------------------------------------------------------------- neighbourhood
@pytest.mark.parametrize(
    "crowd, wildcard, bundle",
    [(False, 64, False), (True, 64, False), (True, 0, False), (True, 64, True)],
    ids=["proxies", "crowd", "crowd-cell-subscribers", "crowd-bundled"],
)
def test_neighbourhood_swarm_delivers_within_the_radius_on_ground_truth(
    procs, sim_time, tmp_path, crowd, wildcard, bundle
):
    """16 robots 2.5 m apart (gps: their position2d is the true pose), neighbourhood 3 m in cells
    of 1.5 m: the monitor's ground-truth verdict has 100 % delivery within the radius; no message
    reached a receiver farther than the reach of its cells; some broadcasts were out of every
    cell's reach (the scoping works) and robots crossed cell borders. Both with the robots' device
    proxies and through the simulator's crowd device (``crowd: true``, the ``thousand`` app's path);
    the host's ~100 cells through one wildcard subscriber (``wildcard_cells`` 64, the default) and
    through a subscriber per cell (0); and with the host's broadcasts bundled (``bundle: true``, the
    ``thousand`` app's: the judge takes them apart)."""
    from agents.cells import cell_of

    n, radius, cell, duration = 16, 3.0, 1.5, 20.0
    world = write_crowd_world(tmp_path / "crowd16.world", n, spacing=2.5, localization="gps")
    ep = f"tcp/127.0.0.1:{free_port()}"
    sim = procs(rsal_cmd("sim", str(world), "--listen", ep, "--no-map", "--speedup", SPEEDUP))
    wait_until(lambda: "[sim]" in sim.output() or not sim.alive(), 60, "the simulator's start line")
    assert sim.alive(), sim.output()

    async def run():
        async with AgentHost.connect(TransportArgs(connect=[ep])) as host:
            await asyncio.to_thread(sim_time, host.session)
            agents = [
                SwarmAgent(
                    f"swarm{i}",
                    robot=f"r{i}",
                    startup_timeout=120,
                    neighbourhood=radius,
                    cell_size=cell,
                    crowd=crowd,
                    wildcard_cells=wildcard,
                    bundle=bundle,
                )
                for i in range(n)
            ]
            # latency is the benchmark's to judge; a loaded machine (p99 up to 0.8 s seen) must not fail this
            mon = SwarmMonitor(
                "monitor", robots=n, duration=duration, startup_timeout=60, max_p99_ms=5000, neighbourhood=radius
            )
            await host.start(mon)  # listening before the first broadcast
            await asyncio.gather(*(host.start(a) for a in agents))
            await _until(lambda: mon.verdict is not None, duration * 4 + 120, "the monitor's verdict")
            cells = agents[0]._hub._cells
            form = (len(cells.cells), cells.subscribers, cells.wildcard)
            sent = (host.services.bundles_sent, host.services.bundled_messages, host.services.publishers_declared)
            return mon, agents, agents[0]._hub.rewatches, agents[0].margin, form, sent

    mon, agents, rewatches, margin, (watched, subscribers, wild), sent = asyncio.run(run())
    bundles, bundled, declared = sent
    if bundle:  # every broadcast went out in a bundle, several to a sample; none on its own key
        assert declared == 0 and bundled >= sum(a.sent for a in agents) - n and bundles < bundled, sent
    else:
        assert bundles == bundled == 0 and declared > 0, sent
    print(f"\nthe host watched {watched} cells through {subscribers} subscriber(s)")
    assert watched > 64 and wild == bool(wildcard) and subscribers == (1 if wildcard else watched)
    v = mon.verdict
    print(f"\nneighbourhood swarm n={n} r={radius} cell={cell}: {v.text}; rewatches={rewatches}")
    assert v.ok and f"delivery within {radius:g} m 100.0 %" in v.text, v.text
    d = mon.delivery
    r = d.result(mon.reports())
    assert r.expected == r.received > 100 and r.monitor_missed == 0
    reach = radius + margin + math.sqrt(2) * cell + 0.3  # a receiver's cells reach no farther (0.3: sampling)
    ranges = {a.id: a.ranges for a in agents}
    index = {f"r{i}": i for i in range(n)}
    out_of_reach = 0
    for sender, robot, seq, t in d.broadcasts():
        xy = d.positions_at(t)
        if xy is None:
            continue
        for a in agents:
            if a.id == sender:
                continue
            dist = float(np.hypot(*(xy[index[a.robot]] - xy[index[robot]])))
            got = any(lo <= seq <= hi for lo, hi in zip(*[iter(ranges[a.id].get(sender, []))] * 2, strict=True))
            if dist > reach:
                out_of_reach += 1
                assert not got, f"{a.id} got {sender}'s broadcast {seq} from {dist:.1f} m (reach {reach:.1f} m)"
    assert out_of_reach > 100, "the crowd must be wider than a neighbourhood for the test to mean anything"
    first, last = d.positions_at(d._truth_t[0]), d.positions_at(d._truth_t[-1])
    crossed = sum(cell_of(*first[i], cell) != cell_of(*last[i], cell) for i in range(n))
    assert crossed >= 4 and rewatches > 5, (crossed, rewatches)


def test_a_crowd_started_at_once_spreads_its_broadcasts_and_stats_over_their_periods():
    from agents.scenarios.swarm.agents import first_due

    due = np.array([first_due(f"swarm{i}", 100.0, 0.5, 10.0) for i in range(500)])
    for col, period in ((0, 0.5), (1, 10.0)):
        offsets = due[:, col] - 100.0
        assert offsets.min() >= 0.0 and offsets.max() <= period
        counts, _ = np.histogram(offsets, bins=10, range=(0.0, period))
        assert counts.max() < 100  # no tenth of the period holds a fifth of the crowd
    assert first_due("swarm7", 0.0, 0.5, 10.0) == first_due("swarm7", 0.0, 0.5, 10.0)  # by its id: repeatable
