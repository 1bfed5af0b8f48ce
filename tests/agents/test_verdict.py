"""rsal run's ground-truth verdicts (:mod:`agents.verdict`) against an in-memory simulation: claims
the true poses contradict are refused with the reason, true ones pass; a duration run's travel and
wall clearance come from sampled true poses and the map's distance transform."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.scenario import load_scenario
from agents.services import Outcome
from agents.verdict import ARRIVE_TOLERANCE, CATCH_SLACK, DELIVER_TOLERANCE, GroundTruth
from rsal.data import Position
from rsal.interfaces.map import MapData

SCENARIO = """
scenario: t
agent_types: {hunter: FollowAgent, prey: EscapeAgent, nav: NavAgent, wf: WallfollowAgent}
applications:
  hunt:
    simulator: {world: w.world}
    agents:
      - {type: prey, robot: r0}
      - {type: hunter, robot: r1, id: h1, args: {prey: r0}}
      - {type: hunter, robot: r2, id: h2, args: {prey: r0, capture_distance: 2.0}}
      - {type: nav, robot: r3, id: n3}
    end: {event: caught}
  wander:
    simulator: {world: w.world}
    agents:
      - {type: wf, robot: r0, id: wf0}
    end: {duration: 10, travel: 1.0, clearance: 0.5}
"""


class FakeSim:
    def __init__(self, poses):
        self.poses = dict(poses)

    def get_pose(self, name):
        return Position(*self.poses[name], 0.0)


def room() -> MapData:
    """A 4 m x 4 m room at 0.1 m per cell, walls one cell thick, origin (-2, -2)."""
    cells = -np.ones((40, 40), dtype=np.int8)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 1
    return MapData(40, 40, 0.1, (-2.0, -2.0), cells)


@pytest.fixture
def sc(tmp_path):
    (tmp_path / "w.world").write_text("")
    p = tmp_path / "s.yaml"
    p.write_text(SCENARIO)
    return load_scenario(p)


def judge(sc, app, poses):
    sim = FakeSim(poses)
    return GroundTruth(None, sc, sc.applications[app], sim=sim, get_map=room), sim


def test_a_catch_counts_only_within_the_capture_distance_on_ground_truth(sc):
    g, sim = judge(sc, "hunt", {"r0": (0.0, 0.0), "r1": (1.0 + CATCH_SLACK - 0.05, 0.0), "r2": (5.0, 0.0)})
    assert g.check("h1", Outcome("caught", "r0", "prey r0 caught by r1")) is None
    assert g.note == "ground truth: r1 1.45 m from r0 at the catch"
    why = g.check("h2", Outcome("caught", "r0", "prey r0 caught by r2"))  # its own capture distance, 2 m
    assert why == "ground truth: r2 is 5.00 m from the prey r0 (capture distance 2 m + 0.5 m)"
    sim.poses["r1"] = (3.0, 4.0)  # the class default, 1 m, for h1
    assert "r1 is 5.00 m from the prey r0 (capture distance 1 m" in g.check("h1", Outcome("caught", "r0", "x"))
    assert g.check("stranger", Outcome("caught", "r0", "x")) is None  # no robot known: nothing to judge


def test_arrival_and_a_distribution_verdict_are_judged_by_true_distance(sc):
    g, sim = judge(sc, "hunt", {"r3": (1.0, 1.0), "r1": (0.0, 0.0)})
    assert g.check("n3", Outcome("arrived", "r3", "r3 arrived", at=(1.0, 1.0 + ARRIVE_TOLERANCE - 0.05))) is None
    why = g.check("n3", Outcome("arrived", "r3", "r3 arrived", at=(4.0, 5.0)))
    assert why == f"ground truth: r3 is 5.00 m from its goal (4.00, 5.00) (> {ARRIVE_TOLERANCE:g} m)"
    assert g.check("n3", Outcome("arrived", "r3", "no goal")) is None  # no place claimed
    assert g.check("d", Outcome("assigned", "r3", "r3 -> target 0", at=(1.0, 1.2))) is None
    assert g.check("d", Outcome("assigned", "r1", "r1 -> target 1", at=(3.0, 0.0))) is None
    why = g.check("d", Outcome("verdict", "distribution", "2 robots reached 2 targets", final=True))
    assert why == f"ground truth: not at the assigned target (> {ARRIVE_TOLERANCE:g} m): r1 3.00 m from (3.00, 0.00)"
    sim.poses["r1"] = (3.0, 0.3)
    assert g.check("d", Outcome("verdict", "distribution", "ok", final=True)) is None
    assert g.note == "ground truth: r1 0.30 m, r3 0.20 m from the assigned targets"


def test_duration_run_travel_and_wall_clearance_from_sampled_truth(sc):
    g, sim = judge(sc, "wander", {"r0": (0.0, 0.0)})
    assert g.samples and g.robots == ["r0"]
    g.sample()
    assert g.nearest_wall["r0"] == pytest.approx(1.9, abs=0.11)  # the walls' inner cells at +-1.9 m
    assert g.wall_distance(-1.75, 0.0) == pytest.approx(0.2, abs=0.11) and g.wall_distance(9.0, 0.0) == 0.0
    assert g.problems() == ["r0 travelled 0.00 m (< travel 1 m)"]  # standing still fails
    for x in (0.3, 0.6, 0.9, 1.2):
        sim.poses["r0"] = (x, 0.0)
        g.sample()
    assert g.travelled["r0"] == pytest.approx(1.2) and g.problems() == []
    sim.poses["r0"] = (1.6, 0.0)  # 0.3 m from the east wall's cells
    g.sample()
    (p,) = g.problems()
    assert p.startswith("r0 came 0.") and p.endswith("m from a wall (< clearance 0.5 m)")
    assert math.isclose(g.travelled["r0"], 1.6)
    assert "r0 travelled 1.6 m, nearest wall 0." in g.summary()


def test_truth_keys_need_a_simulator(tmp_path):
    from agents.scenario import ScenarioError

    p = tmp_path / "s.yaml"
    p.write_text(
        "scenario: t\nagent_types: {wf: WallfollowAgent}\napplications:\n  a:\n"
        "    agents: [{type: wf, robot: r0}]\n    end: {duration: 5, travel: 1}\n"
    )
    with pytest.raises(ScenarioError, match=r"applications\.a\.end\.travel.*ground truth; add a 'simulator'"):
        load_scenario(p)


COLLECT = """
scenario: c
agent_types: {master: MasterAgent, collector: CollectAgent, explorer: ExploreAgent}
applications:
  mixed:
    simulator: {world: w.world}
    rehearse: {world: w.world, robot: c1}
    agents:
      - {type: master, id: master}
      - {type: explorer, robot: e1, id: ex}
      - {type: collector, robot: c1, id: col1}
    end: {event: delivered}
  two:
    simulator: {world: w.world}
    agents:
      - {type: master, id: master}
      - {type: collector, robot: c1, id: col1}
      - {type: collector, robot: c2, id: col2, args: {home: [5.0, 5.0, 90]}}
    end: {event: delivered, count: 2}
"""


class FakeWorld(FakeSim):
    def __init__(self, poses, objects):
        super().__init__(poses)
        self.objects = list(objects)

    def models(self):
        return {"robots": [n for n in self.poses if n not in self.objects], "objects": self.objects}


def test_a_delivery_counts_only_with_a_bin_truly_home_in_the_collectors_world(tmp_path):
    """Mixed reality: c1 is rehearsed, so its home and the bin are the real world's, not the
    virtual one's (where the blob the explorer saw stays put and c1's proxy stands)."""
    (tmp_path / "w.world").write_text("")
    (tmp_path / "s.yaml").write_text(COLLECT)
    sc = load_scenario(tmp_path / "s.yaml")
    real = FakeWorld({"c1": (-22.0, 1.75), "bin0": (-16.0, 1.9)}, ["bin0"])
    virtual = FakeWorld({"e1": (-19.0, 1.75), "c1": (-22.0, 1.75), "blob0": (-22.0, 1.8)}, ["c1", "blob0"])
    g = GroundTruth(None, sc, sc.applications["mixed"], sim=virtual, get_map=room, real=real)
    assert [a.robot for a in g.collectors()] == ["c1"]
    g.record_homes()
    real.poses["c1"] = (-17.0, 1.8)  # on its way: the home stays where it started
    assert g.homes == {"c1": (-22.0, 1.75)}
    why = g.check("master", Outcome("delivered", "blob0", "blob0 delivered home by col1"))
    assert why == (
        f"ground truth: 0 bin(s) within {DELIVER_TOLERANCE:g} m of a collector's home for 1 deliveries; "
        "nearest: bin0 6.00 m from c1's home (-22.00, 1.75)"
    )
    real.poses["bin0"] = (-21.3, 1.6)
    assert g.check("master", Outcome("delivered", "blob0", "blob0 delivered home by col1")) is None
    assert g.note == "ground truth: 1 bin(s) within 1 m of a collector's home" and g.delivered == 1
    # a second claim needs a second bin home
    assert "1 bin(s) within 1 m of a collector's home for 2 deliveries" in g.check(
        "master", Outcome("delivered", "blob1", "blob1 delivered home by col1")
    )
    assert g.check("master", Outcome("delivered", "blob1", "failed", ok=False)) is None  # no claim


def test_a_real_collector_without_a_rehearsal_is_not_judged_in_the_virtual_world(tmp_path):
    """On real hardware c1 is only a proxy of the virtual world, where the blob it fetched stays:
    that world cannot judge the delivery, and must not refuse it."""
    (tmp_path / "w.world").write_text("")
    (tmp_path / "s.yaml").write_text(COLLECT.replace("    rehearse: {world: w.world, robot: c1}\n", ""))
    sc = load_scenario(tmp_path / "s.yaml")
    assert sc.applications["mixed"].rehearse is None
    virtual = FakeWorld({"e1": (-19.0, 1.75), "c1": (-22.0, 1.75), "blob0": (-16.0, 1.9)}, ["c1", "blob0"])
    g = GroundTruth(None, sc, sc.applications["mixed"], sim=virtual, get_map=room)
    g.record_homes()
    assert g.check("master", Outcome("delivered", "blob0", "blob0 delivered home by col1")) is None
    assert g.note == "ground truth: no collector lives in a simulated world; the delivery is not judged"


def test_a_collectors_home_argument_is_its_home(tmp_path):
    (tmp_path / "w.world").write_text("")
    (tmp_path / "s.yaml").write_text(COLLECT)
    sc = load_scenario(tmp_path / "s.yaml")
    sim = FakeWorld({"c1": (0.0, 0.0), "c2": (9.0, 9.0), "b0": (5.5, 5.0), "b1": (0.5, 0.5)}, ["b0", "b1"])
    g = GroundTruth(None, sc, sc.applications["two"], sim=sim, get_map=room)
    g.record_homes()
    assert g.homes == {"c1": (0.0, 0.0), "c2": (5.0, 5.0)}
    assert g.check("master", Outcome("delivered", "blob0", "x")) is None
    assert g.check("master", Outcome("delivered", "blob1", "x")) is None
    assert g.note == "ground truth: 2 bin(s) within 1 m of a collector's home"


def _runner(sc, app, poses):
    """rsal run's Runner with the in-memory simulation as its ground truth and no fabric."""
    import argparse

    from agents.run import Runner, _Out

    args = argparse.Namespace(timeout=None, progress=0, connect=None, listen=None, config=None, cfg=None)
    r = Runner(sc, sc.applications[app], args, _Out())
    r.truth, _ = judge(sc, app, poses)
    r.phase = "run"
    return r


def test_a_refused_claim_of_the_end_event_ends_the_run_at_once_as_failed(sc, capsys):
    r = _runner(sc, "hunt", {"r0": (0.0, 0.0), "r1": (4.0, 0.0), "r2": (0.5, 0.0)})
    r._handle(("outcome", "h1", Outcome("caught", "r0", "prey r0 caught by r1")))
    r._check(now=1.0, t0=0.0)
    assert r.result is not None and r.result[0] is False
    assert r.result[1].startswith("a caught claim that ground truth refuses: prey r0 caught by r1 -- ground truth:")
    assert "not confirmed" in capsys.readouterr().out


def test_a_confirmed_claim_of_the_end_event_ends_the_run_with_success(sc):
    r = _runner(sc, "hunt", {"r0": (0.0, 0.0), "r1": (4.0, 0.0), "r2": (0.5, 0.0)})
    r._handle(("outcome", "h2", Outcome("caught", "r0", "prey r0 caught by r2")))
    r._check(now=1.0, t0=0.0)
    assert r.result == (True, "prey r0 caught by r2")
