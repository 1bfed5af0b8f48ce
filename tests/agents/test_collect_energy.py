"""Find and Collect with energy (``deploy/scenarios/find_collect.yaml``, apps ``energy`` and
``energy_baseline``; docs/scenarios/find_collect.md, "With energy").

Unit tests: the master's ``dispatch`` allocation on an in-memory host (fetch tasks to the depots in
turn, the dispatcher's word followed, failures offered again as new tasks), the energy verdicts of
:mod:`agents.verdict` on a fake battery record, the run end's ``never_flat`` / ``charged`` keys,
and the collector's remaining way for its bids. The suite test runs the ``energy`` application with
``rsal run`` and judges it on ground truth: the runner's own verdict (every blob truly home, the
simulation's battery record) and, sampled by the test from the simulation device while it runs, a
collector truly docked with its charge rising and no collector's battery ever empty.
"""

from __future__ import annotations

import re
import time

import pytest

from agents.dispatch.tasks import Task, TaskStatus
from agents.scenario import ScenarioError, load_scenario
from agents.scenarios.collect import BLOB, BlobReport, FleetCollectAgent, MasterAgent
from agents.services import Message
from agents.verdict import GroundTruth
from rsal.msgs import RpcError
from tests.conftest import ROOT, rsal_cmd, wait_until

SCENARIO = ROOT / "deploy" / "scenarios" / "find_collect.yaml"
DEPOTS = [[-3.2, -2.0], [-3.2, 2.0]]
COLLECTORS = ("c1", "c2")


# ============================================================================ master, in memory
class _Recorder:
    def __init__(self):
        self.sent: list[tuple[str, object]] = []

    def publish(self, service, body, *, sender, conversation=None, cell=None):
        self.sent.append((service, body))
        return "c"


def _master(**kw) -> tuple[MasterAgent, _Recorder]:
    m = MasterAgent("master", allocation="dispatch", depots=DEPOTS, **kw)
    rec = _Recorder()
    m.host = type("H", (), {"services": rec})()
    return m, rec


def _msg(service: str, sender: str, body) -> Message:
    return Message(service, sender, "c", time.time(), body)


def _state(task_id: str, state: str, robot: str = "", text: str = "", sender: str = "dispatcher") -> Message:
    return _msg("task_state", sender, TaskStatus(task_id, "fetch", state, robot, "", text, "master").to_dict())


def _submitted(rec: _Recorder) -> list[dict]:
    return [b.task for s, b in rec.sent if s == "task_request" and b.op == "submit"]


def test_master_submits_each_blob_as_a_fetch_task_to_the_depots_in_turn():
    m, rec = _master(retry_after=0.2)
    m.on_blob(_msg(BLOB, "explorer1", BlobReport("e1", 0x00FF00, 1.0, 2.3).to_dict()))
    m.on_blob(_msg(BLOB, "explorer1", BlobReport("e1", 0x00FF00, 1.8, -1.6).to_dict()))
    m._assign_dispatch(time.monotonic())
    tasks = _submitted(rec)
    assert tasks == [
        {"id": "master-blob0-1", "kind": "fetch", "args": {"object": "blob0", "at": [1.0, 2.3], "to": DEPOTS[0]}},
        {"id": "master-blob1-1", "kind": "fetch", "args": {"object": "blob1", "at": [1.8, -1.6], "to": DEPOTS[1]}},
    ]
    m._assign_dispatch(time.monotonic())
    assert len(_submitted(rec)) == 2  # assigned: not submitted twice
    # the dispatcher's word: awarded, then done -> delivered at its depot; another sender is ignored
    m.on_task_state(_state("master-blob0-1", "assigned", "collector2"))
    assert m.board.get(("blob", "blob0")).data.assignee == "collector2"
    m.on_task_state(_state("master-blob0-1", "done", "collector2", sender="mallory"))
    assert m.blobs("delivered") == []
    m.on_task_state(_state("master-blob0-1", "done", "collector2"))
    outcomes = [b for s, b in rec.sent if s == "outcome"]
    assert [(o.event, o.subject) for o in outcomes] == [("delivered", "blob0")]
    assert "delivered home by collector2" in outcomes[0].text
    # a failed task: offered again after retry_after as a new task, to the same depot
    m.on_task_state(_state("master-blob1-1", "failed", "collector1", "no robot bid in 5 call(s)"))
    assert [n.data.id for n in m.blobs("new")] == ["blob1"]
    assert m.board.get(("blob", "blob1")).data.failures == ["no robot bid in 5 call(s)"]
    m._assign_dispatch(time.monotonic())
    assert len(_submitted(rec)) == 2  # not yet
    time.sleep(0.25)
    m._assign_dispatch(time.monotonic())
    again = _submitted(rec)[-1]
    assert again["id"] == "master-blob1-2" and again["args"]["to"] == DEPOTS[1]
    m.on_task_state(_state("master-blob1-1", "done", "collector1"))  # the old task: nothing
    assert len(m.blobs("delivered")) == 1


def test_master_sends_a_task_again_until_the_dispatcher_answers():
    m, rec = _master(bid_deadline=0.1)
    m.on_blob(_msg(BLOB, "explorer1", BlobReport("e1", 0x00FF00, 1.0, 2.3).to_dict()))
    t0 = time.monotonic()
    m._assign_dispatch(t0)
    m._assign_dispatch(t0 + 1.0)  # within bid_deadline + 2 s: waits
    assert [t["id"] for t in _submitted(rec)] == ["master-blob0-1"]
    m._assign_dispatch(t0 + 2.5)  # the dispatcher may have started after the request: the same task again
    assert [t["id"] for t in _submitted(rec)] == ["master-blob0-1", "master-blob0-1"]
    dup = TaskStatus("master-blob0-1", "fetch", "refused", "", "duplicate_id", "id in use", "master").to_dict()
    m.on_task_state(_msg("task_state", "dispatcher", dup))  # it had the first copy: still assigned
    assert [n.data.id for n in m.blobs("assigned")] == ["blob0"]
    m._assign_dispatch(t0 + 10.0)  # heard of: not sent again
    assert len(_submitted(rec)) == 2


def test_master_dispatch_needs_depots():
    with pytest.raises(ValueError, match="needs depots"):
        MasterAgent("m", allocation="dispatch")
    with pytest.raises(ValueError, match=r"depots\[1\]"):
        MasterAgent("m", allocation="dispatch", depots=[[0, 0], [1]])


def test_a_collector_bids_with_the_way_its_fetch_still_has_to_go():
    c = FleetCollectAgent("c", robot="c1")
    c.active = Task("t", "fetch", {"object": "b", "at": [1.0, 2.0], "to": [-3.0, 2.0]})
    c.pioneer = type("R", (), {"gripper": type("G", (), {"carrying": False})()})()
    assert c.places_left() == [(1.0, 2.0), (-3.0, 2.0)]
    c.pioneer.gripper.carrying = True
    assert c.places_left() == [(-3.0, 2.0)]
    c.active = None
    assert c.places_left() == []


# ============================================================================ verdicts
ENERGY = """
scenario: t
agent_types: {c: CollectAgent}
applications:
  a:
    simulator: {world: w.world}
    agents:
      - {type: c, robot: c1, id: k1}
      - {type: c, robot: c2, id: k2}
    end: {event: delivered, count: 1, never_flat: true, charged: 1}
"""


class FakeBatteries:
    def __init__(self, record):
        self.record = record

    def batteries(self):
        return self.record


def _bat(lowest=0.3, flat=0.0, charged=0.0, capacity=900.0, battery=True):
    return {"battery": battery, "capacity": capacity, "fraction": 0.5, "charging": False, "charger": None,
            "empty": False, "lowest": lowest, "flat": flat, "charged": charged}  # fmt: skip


@pytest.fixture
def energy_sc(tmp_path):
    (tmp_path / "w.world").write_text("")
    p = tmp_path / "s.yaml"
    p.write_text(ENERGY)
    return load_scenario(p)


def test_energy_verdicts_judge_the_simulations_battery_record(energy_sc):
    app = energy_sc.applications["a"]
    assert app.end.never_flat and app.end.charged == 1
    sim = FakeBatteries({"c1": _bat(charged=200.0), "c2": _bat(), "e1": _bat(lowest=0.0, flat=9.0)})
    g = GroundTruth(None, energy_sc, app, sim=sim, get_map=lambda: None)
    assert g.samples and not g.poses
    g.sample()
    assert g.flat_robots() == [] and g.problems() == []  # e1 is no robot of this application's agents
    assert "c1 battery lowest 30%, 0 s flat, charged 200 J" in g.summary()
    sim.record = {"c1": _bat(charged=50.0), "c2": _bat(lowest=0.0, flat=2.5)}  # a trace of charge: not charged
    g.sample()
    assert g.flat_robots() == ["c2's battery ran empty (the simulation's record: lowest 0%, 2.5 s empty)"]
    assert g.problems() == [g.flat_robots()[0], "0 robot(s) truly charged (< charged 1)"]
    sim.record = {"c1": _bat(charged=500.0, battery=False), "c2": _bat()}  # no battery model: not judged
    g.sample()
    assert g.problems() == ["0 robot(s) truly charged (< charged 1)"]


@pytest.mark.parametrize(
    "end, where",
    [
        ("{event: delivered, never_flat: yes please}", "end.never_flat"),
        ("{event: delivered, charged: -1}", "end.charged"),
    ],
)
def test_bad_energy_end_keys_are_one_line(tmp_path, end, where):
    (tmp_path / "w.world").write_text("")
    p = tmp_path / "s.yaml"
    p.write_text(ENERGY.replace("{event: delivered, count: 1, never_flat: true, charged: 1}", end))
    with pytest.raises(ScenarioError, match=re.escape(where)) as e:
        load_scenario(p)
    assert "\n" not in str(e.value)


# ============================================================================ the run
def test_collectors_recharge_between_fetches_and_bring_every_blob_home(procs, port, fabric_factory):
    """``rsal run --app energy``: its verdict (4 blobs truly home, no battery ever empty, a collector
    truly charged) and the test's own samples of the simulation's batteries while it runs."""
    ep = f"tcp/127.0.0.1:{port}"
    t0 = time.monotonic()
    run = procs(rsal_cmd("run", str(SCENARIO), "--app", "energy", "--listen", ep))
    fab = fabric_factory(port)
    node = fab.node("sim:simulation:0")
    node.wait_for("sim:simulation:0", 1, 120)
    sim = fab.device("sim:simulation:0")
    docked: dict[str, list[float]] = {c: [] for c in COLLECTORS}  # the charge while truly charging at a dock
    lowest = {c: 1.0 for c in COLLECTORS}

    def sample() -> bool:
        try:
            bats = sim.batteries()
        except RpcError:  # the run ended and stopped the simulator
            return not run.alive()
        for c in COLLECTORS:
            b = bats[c]
            lowest[c] = min(lowest[c], b["fraction"])
            if b["charging"] and b["charger"] in ("dock0", "dock1"):
                docked[c].append(b["fraction"])
        return not run.alive()

    wait_until(sample, 280, "the energy run to end", interval=0.3)
    took = time.monotonic() - t0
    out = run.output()
    print(out[-2500:])
    assert run.p.returncode == 0, out[-3000:]
    assert "ground truth: 4 bin(s) within 1 m of a collector's home" in out
    verdict = re.findall(r"(c\d) battery lowest (\d+)%, (\d+) s flat, charged (\d+) J", out)
    assert sorted(v[0] for v in verdict) == ["c1", "c2"], out[-1500:]
    assert all(int(v[2]) == 0 and int(v[1]) > 0 for v in verdict)  # the record: never empty
    assert any(int(v[3]) >= 90 for v in verdict)  # >= 10 % of 900 J gained on a dock
    assert min(lowest.values()) > 0.0, lowest
    rising = [c for c, f in docked.items() if len(f) >= 2 and f[-1] > f[0]]
    assert rising, f"no collector seen charging on a dock: {docked}"
    print(f"energy: 4 blobs home in {took:.0f} s; lowest charge {lowest}; charged on a dock: {rising}")
