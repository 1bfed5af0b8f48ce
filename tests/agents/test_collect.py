"""Tests of the Find and Collect scenario's agents (thesis 4.2.2): ExploreAgent, CollectAgent, MasterAgent.

The master's blackboard logic (merging repeated blob reports, ignoring blobs in a gripper, choosing the
nearest free collector, re-offering failed blobs) is tested on an agent host whose published messages
are recorded in memory. The integration tests start a real ``rsal sim maps/collect.world`` process
with the navigation stack for the collectors and run the agents on an :class:`AgentHost` in the test
process; the simulation's ground truth (``simulation`` rpc ``get_pose``) says where the blobs end up.
The two tests of one collector share one simulation (class-scoped, each with its own robot); the whole
scenario gets a fresh one.
"""

from __future__ import annotations

import asyncio
import math
import time
from contextlib import contextmanager

import pytest

from agents.runtime import AgentHost
from agents.scenarios.collect import BLOB, COLLECT, BlobReport, CollectAgent, ExploreAgent, MasterAgent
from agents.services import Hello, Message, SendPosition
from rsal.client import Fabric
from rsal.keys import parse_device
from rsal.msgs import RpcError
from rsal.transport import TransportArgs
from tests.conftest import MAPS, SPEEDUP, LoopThread, Proc, free_port, rsal_cmd, wait_until

WORLD = MAPS / "collect.world"
BLOBS = ("blob0", "blob1", "blob2")
# m between a reported blob and the true one: AMCL's 0.30 m plus the blobfinder's range estimate (the
# master's merge distance: a report farther off would count as another blob)
REPORT_TOLERANCE = 0.5


# ============================================================================ master, in memory
class _Recorder:
    """Stands in for the host's services: records what an agent publishes."""

    def __init__(self):
        self.sent: list[tuple[str, object]] = []

    def publish(self, service, body, *, sender, conversation=None, cell=None):
        self.sent.append((service, body))
        return "c"


def _master(**kw) -> tuple[MasterAgent, _Recorder]:
    m = MasterAgent("master", **kw)
    rec = _Recorder()
    m.host = type("H", (), {"services": rec})()
    return m, rec


def _msg(service: str, sender: str, body) -> Message:
    return Message(service, sender, "c", time.time(), body)


def _blob(x: float, y: float, robot: str = "e1") -> Message:
    return _msg(BLOB, "explorer1", BlobReport(robot, 0x00FF00, x, y).to_dict())


def test_master_merges_repeated_reports_of_one_blob():
    m, _ = _master()
    m.on_blob(_blob(-16.0, 1.9))
    m.on_blob(_blob(-16.0, 1.9))  # the explorer's periodic repeat
    m.on_blob(_blob(-15.6, 2.2))  # seen again from elsewhere, 0.5 m off
    m.on_blob(_blob(-11.0, 1.6))  # another blob
    assert [n.data.id for n in m.blobs()] == ["blob0", "blob1"]
    assert m.duplicates == 2
    assert m.blobs()[0].data.reports == 3


def test_master_drops_malformed_reports():
    m, _ = _master()
    m.on_blob(_msg(BLOB, "explorer1", {"robot": "e1", "x": "far", "y": 1.0}))
    m.on_blob(_msg(BLOB, "explorer1", {"robot": "e1", "x": math.nan, "y": 1.0}))
    assert m.blobs() == []


def test_master_assigns_nearest_free_collector_and_reoffers_failures():
    m, rec = _master(retry_after=0.2)
    for cid in ("collector1", "collector2"):
        m.on_hello(Hello(cid, "CollectAgent", cid[-1], ("send_position", "collect")))
    m.on_position(_msg("send_position", "collector1", SendPosition("c1", -21.0, 4.6, 0.0, "map")))
    m.on_position(_msg("send_position", "collector2", SendPosition("c2", -14.4, 4.6, 0.0, "map")))
    m.on_blob(_blob(-16.0, 1.9))
    m._assign_direct(time.monotonic())
    collects = [b for s, b in rec.sent if s == COLLECT]
    assert collects == [{"to": "collector2", "blob": "blob0", "x": -16.0, "y": 1.9}]  # 2.9 m against 5.7 m
    # a second blob goes to the other, free collector although collector2 is nearer
    m.on_blob(_blob(-13.8, 1.5))
    m._assign_direct(time.monotonic())
    assert [b["to"] for s, b in rec.sent if s == COLLECT] == ["collector2", "collector1"]
    # a blob carried past an explorer (within carry_dist of a collector) is not a new blob, nor its repeats
    m.on_position(_msg("send_position", "collector2", SendPosition("c2", -9.0, 1.5, 0.0, "map")))
    m.on_blob(_blob(-8.7, 1.5))
    m.on_position(_msg("send_position", "collector2", SendPosition("c2", -3.0, 1.5, 0.0, "map")))
    m.on_blob(_blob(-8.7, 1.5))
    assert len(m.blobs("new") + m.blobs("assigned")) == 2 and m.ignored == 1
    # collector1 fails: the blob is offered again after retry_after
    m.on_collected(_msg("collected", "collector1", {"to": "master", "blob": "blob1", "ok": False, "x": 0.0, "y": 0.0}))
    assert [n.data.id for n in m.blobs("new")] == ["blob1"]
    m._assign_direct(time.monotonic())
    assert len([1 for s, _ in rec.sent if s == COLLECT]) == 2  # not yet
    time.sleep(0.25)
    m._assign_direct(time.monotonic())
    assert [b["to"] for s, b in rec.sent if s == COLLECT][-1] == "collector1"
    # collector2 delivers: one outcome; later reports at the old spot or the drop spot are the same blob
    m.on_collected(_msg("collected", "collector2", {"to": "master", "blob": "blob0", "ok": True, "x": -14.2, "y": 4.3}))
    outcomes = [b for s, b in rec.sent if s == "outcome"]
    assert len(outcomes) == 1 and outcomes[0].event == "delivered" and outcomes[0].subject == "blob0"
    assert "delivered home by collector2" in outcomes[0].text
    m.on_blob(_blob(-16.0, 1.9))
    m.on_blob(_blob(-14.2, 4.3))
    assert len(m.blobs()) == 2 and [n.data.id for n in m.blobs("delivered")] == ["blob0"]


def test_agents_reject_bad_arguments():
    with pytest.raises(ValueError, match="allocation"):
        MasterAgent("m", allocation="auction")
    with pytest.raises(TypeError):
        MasterAgent("m", laser=True)
    with pytest.raises(ValueError, match="home"):
        CollectAgent("c", robot="c1", home=[1.0])
    with pytest.raises(ValueError, match="side"):
        ExploreAgent("e", robot="e1", side="up")


# ============================================================================ with the simulator


@contextmanager
def _running_sim(start, follow):
    """``rsal sim maps/collect.world`` with the navigation stack for e1, c1 and c2 (the explorer
    localizes with AMCL like the collectors), started by ``start(argv) -> Proc``, an agent host and a
    simulation proxy on its endpoint; ``follow(session)`` makes this process follow its clock."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    p = start(
        rsal_cmd("sim", str(WORLD), "--listen", ep, "--nav", "vfh", "--nav-robots", "e1,c1,c2", "--speedup", SPEEDUP)
    )
    lt = LoopThread(120.0)
    host = None
    fabric = None
    try:
        host = AgentHost.connect(TransportArgs(connect=[ep]))
        lt.run(host.__aenter__())
        fabric = Fabric(host.session, own_session=False)
        node = fabric.node("sim:simulation:0")
        wait_until(lambda: node.search(node="sim"), 60, f"the simulator on {ep}\n{p.output()}", interval=0.2)
        simdev = fabric.device(parse_device("sim:simulation:0"))

        def answers() -> bool:  # the server's first seconds may go to compiling the planners' kernels
            try:
                simdev.rpc("models", timeout=2.0)
                return True
            except RpcError:
                return False

        wait_until(answers, 90, f"the simulation to answer rpcs\n{p.output()}", interval=0.5)
        follow(host.session)
        yield {"host": host, "loop": lt, "sim": simdev, "proc": p}
    finally:
        if host is not None:
            lt.run(host.stop())
        if fabric is not None:
            fabric.close()
        lt.close()


@pytest.fixture
def sim(procs, sim_time):
    """A fresh simulation for one test (the whole scenario needs every robot and blob where the world
    file puts them)."""
    with _running_sim(procs, sim_time) as s:
        yield s


@pytest.fixture(scope="class")
def lab():
    """One simulation shared by the tests of one collector (:class:`TestOneCollector`): each uses its
    own collector and blob, and kills its agent at its end (the reset), so none depends on another's
    order. Started and stopped here by PID, on the simulation's clock until the class ends."""
    from rsal.clock import WallClock, set_clock, use_sim_time

    started: list[Proc] = []
    clocks = []

    def start(argv) -> Proc:
        started.append(Proc(argv))
        return started[-1]

    def follow(session) -> None:
        clocks.append(use_sim_time(session, "sim"))
        assert clocks[-1].wait_started(60.0), "no time from the simulation of node 'sim'"

    try:
        with _running_sim(start, follow) as s:
            yield s
    finally:
        set_clock(WallClock())
        for c in clocks:
            c.close()
        for p in started:
            p.close()


def _where(simdev, name: str):
    p = simdev.get_pose(name)
    return p.x, p.y


class TestOneCollector:
    """One collector at a time on a simulation the class shares (fixture ``lab``): collector1 (c1)
    with blob1, collector2 (c2) with no blob at all; neither touches the other's robot or blob, and
    each kills its agent at its end."""

    @pytest.mark.timeout(300)
    def test_collector_fetches_a_blob_home(self, lab):
        """One collector, one blob put 2 m from it: driven to, gripped, brought home and put down there."""
        simdev, host, lt = lab["sim"], lab["host"], lab["loop"]
        simdev.set_pose("blob1", _pose(-21.5, 7.6))  # in the laboratory, 2 m ahead of c1
        c = CollectAgent("collector1", robot="c1", startup_timeout=60)
        lt.run(host.start(c), timeout=90)
        try:
            home = c.home
            assert math.hypot(home.x + 21.5, home.y - 9.6) < 0.3  # its start pose, localized
            t0 = time.monotonic()
            res = lt.run(c.fetch("blob1", -21.5, 7.6), timeout=240)
            took = time.monotonic() - t0
            assert res.ok, res.reason
            bx, by = _where(simdev, "blob1")
            assert math.hypot(bx - home.x, by - home.y) < 1.0, (bx, by, home)
            assert math.hypot(bx - res.x, by - res.y) < 0.3  # the reported drop spot is where it lies
            assert not c.pioneer.gripper.carrying
            print(f"fetched one blob home in {took:.1f} s")
        finally:
            lt.run(host.kill(c))

    @pytest.mark.timeout(300)
    def test_collector_reports_a_missing_blob_as_failure(self, lab):
        host, lt = lab["host"], lab["loop"]
        c = CollectAgent("collector2", robot="c2", startup_timeout=60)
        lt.run(host.start(c), timeout=90)
        try:
            # nothing there: 1.7 m ahead of c2, in the laboratory's free east side (blob1, the only
            # blob moved by this class, lies by c1 at the west end)
            res = lt.run(c.fetch("ghost", -15.0, 6.0), timeout=240)
            assert not res.ok and "not found" in res.reason
            assert c.busy is None and c.failed == ["ghost"]
        finally:
            lt.run(host.kill(c))


def _pose(x, y):
    from rsal.data import Position

    return Position(x, y, 0.0)


@pytest.mark.timeout(900)
# The whole scenario once, in its advanced form (collectors bid by contract net), the more involved
# of the two allocations; the direct one is covered by the master's unit test above, and both
# applications run the same way under `rsal run` (measured: virtual 143 s, advanced 155 s).
@pytest.mark.parametrize("allocation", ["contract_net"])
def test_whole_scenario_brings_all_blobs_home(sim, allocation):
    """1 explorer, 2 collectors, 1 master: all 3 blobs reported once each and brought home."""
    simdev, host, lt = sim["sim"], sim["host"], sim["loop"]
    outcomes: list = []
    master = MasterAgent("master", allocation=allocation)
    lt.run(host.start(master))
    master.subscribe("outcome", lambda m: outcomes.append(m.body))
    truth = {name: _where(simdev, name) for name in BLOBS}  # where the blobs lie before anyone moves them
    agents = [
        ExploreAgent("explorer1", robot="e1", startup_timeout=60),  # no oracle: it localizes with AMCL
        CollectAgent("collector1", robot="c1", startup_timeout=60),
        CollectAgent("collector2", robot="c2", startup_timeout=60),
    ]

    async def start_all():
        await asyncio.gather(*(host.start(a) for a in agents))

    lt.run(start_all(), timeout=120)
    assert agents[0].pioneer.localize is not None
    wait_until(lambda: getattr(agents[0].pose_message(), "frame", "") == "map", 30, "the explorer's AMCL pose")
    homes = [(a.home.x, a.home.y) for a in agents[1:]]
    t0 = time.monotonic()
    wait_until(lambda: len({o.subject for o in outcomes if o.event == "delivered"}) >= 3, 700, "3 blobs delivered", 1.0)
    took = time.monotonic() - t0
    for name in BLOBS:
        bx, by = _where(simdev, name)
        assert min(math.hypot(bx - hx, by - hy) for hx, hy in homes) < 1.0, (name, bx, by, homes)
    spots = [(n.data.id, round(n.data.spot.x, 2), round(n.data.spot.y, 2), n.data.reports) for n in master.blobs()]
    print("blob notes (id, x, y, reports):", spots, "true:", truth)
    assert len(master.blobs()) == 3, (spots, truth)  # one note per blob, however often each was reported
    # the explorer's reports (its AMCL pose + the blobfinder's range) name where the blobs truly lay
    for note in master.blobs():
        p = note.data.spot  # where it was first reported (the note's position moves with the blob)
        off = min(math.hypot(p.x - x, p.y - y) for x, y in truth.values())
        assert off < REPORT_TOLERANCE, (note.data, p, truth)
    assert master.duplicates > 0
    if allocation == "contract_net":  # every blob went through a contract: 3 inform-done in all
        assert sum(list(a.cnp.outcomes.values()).count("done") for a in agents[1:]) == 3
    print(f"{allocation}: 3 blobs home in {took:.0f} s; {[o.text for o in outcomes]}")
