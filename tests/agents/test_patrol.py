"""The surveillance patrol scenario (``deploy/scenarios/patrol.yaml``) on the fleet dispatcher.

Unit tests: :func:`agents.dispatch.patrol.revisit_gaps` against a hand-computed track, and bad
routes refused in one line. The suite test runs the ``two`` application with ``rsal run`` (the
simulator with the navigation stack, two FleetAgents, the DispatcherAgent, the PatrolAgent) and
judges it on ground truth sampled from the simulation device while it runs: every point of both
routes truly visited by a robot, r0 (23 % at the start, one charger for two robots) truly docked
at the charger and its battery (the simulator's battery model, ``power:0``) rising there, and no
robot ever flat. The test stops the run (SIGINT) as soon as all of that is seen (about 80 of the
400 simulated seconds); until then the run must not have failed.
"""

from __future__ import annotations

import signal

import numpy as np
import pytest

from agents.dispatch.patrol import PatrolAgent, revisit_gaps
from rsal.msgs import RpcError
from tests.conftest import ROOT, SPEEDUP, rsal_cmd, wait_until

SCENARIO = str(ROOT / "deploy" / "scenarios" / "patrol.yaml")
ROUTES = [
    [[-3.5, -2.5], [-0.5, -2.5], [-0.5, 2.5], [-3.5, 2.5]],
    [[1.0, -2.5], [4.0, -2.5], [4.0, 2.5], [1.0, 2.5]],
]
DOCK = (-4.0, 0.0)


def test_revisit_gaps_by_hand():
    times = np.arange(0.0, 10.0)  # 0 .. 9 s, one robot
    x = np.array([0, 0, 5, 5, 5, 0, 0, 0, 5, 5], dtype=float)
    poses = np.stack([x, np.zeros(10)], axis=1)[:, None, :]
    gaps = revisit_gaps(times, poses, np.array([[0.0, 0.0], [5.0, 0.0], [9.0, 9.0]]), radius=0.5)
    # (0,0) seen at 0, 1, 5, 6, 7: longest gap 1 -> 5; (5,0) at 2, 3, 4, 8, 9: 4 -> 8; never: the run
    assert gaps.tolist() == [4.0, 4.0, 9.0]


@pytest.mark.parametrize(
    "routes, words",
    [
        ([], "must list one or more routes"),
        ([[[0, 0]]], "routes[0]: task route0: 'route' must list two or more points"),
        ([[[0, 0], ["a", 1]]], "'route point' must be a point [x, y]"),
    ],
)
def test_bad_routes_are_one_line(routes, words):
    with pytest.raises(ValueError) as e:
        PatrolAgent("patrol", routes=routes)
    assert words in str(e.value) and "\n" not in str(e.value)


@pytest.mark.timeout(900)
def test_patrol_two_robots_one_charger(procs, port, fabric_factory):
    ep = f"tcp/127.0.0.1:{port}"
    run = procs(rsal_cmd("run", SCENARIO, "--app", "two", "--listen", ep, "--speedup", SPEEDUP))
    fab = fabric_factory(port)
    node = fab.node("sim:*:*", "r0:*:*", "r1:*:*")
    node.wait_for("sim:simulation:0", 1, 120)
    node.wait_for("r1:power:0", 1, 120)
    sim = fab.device("sim:simulation:0")
    power = {r: fab.device(f"{r}:power:0") for r in ("r0", "r1")}
    pts = np.array([p for r in ROUTES for p in r])
    times, track, charge, docked = [], [], {"r0": [], "r1": []}, []
    visited = np.zeros(len(pts), dtype=bool)

    def verdict_in() -> bool:
        """Every route point truly visited (after the first sample) and r0 truly charged on the dock:
        what the assertions below judge."""
        return bool(visited.all()) and len(docked) >= 2 and docked[-1][1] > docked[0][1]

    def sample() -> bool:
        ready = verdict_in()  # judged on the samples so far: this one closes the revisit gaps
        t = sim.latest.t if sim.latest is not None else None
        try:
            p = [sim.get_pose(r) for r in ("r0", "r1")]
        except RpcError:  # the run ended and stopped the simulator
            return not run.alive()
        if t is not None:
            times.append(t)
            track.append([(q.x, q.y) for q in p])
            if len(times) > 1:
                xy = np.array(track[-1])
                visited[:] |= (np.linalg.norm(xy[:, None, :] - pts[None, :, :], axis=-1) <= 0.7).any(axis=0)
            for r in charge:
                if power[r].fraction is not None:
                    charge[r].append(power[r].fraction)
            if power["r0"].charging and np.hypot(p[0].x - DOCK[0], p[0].y - DOCK[1]) < 0.6:
                docked.append((t, power["r0"].fraction))
        return not run.alive() or ready

    wait_until(sample, 900, "the patrol run to end", interval=0.3)
    print(f"verdict in: {verdict_in()} after {times[-1] - times[0]:.0f} simulated s" if times else "no samples")
    stopped = run.alive()  # the verdict is in before the run's end: stop it (SIGINT, as a user would)
    if stopped:
        run.signal(signal.SIGINT)
        wait_until(lambda: not run.alive(), 60, "the patrol run to stop on SIGINT")
    out = run.output()
    print(out[-3000:])
    # the run went without a failure until the verdict (it would have ended itself with exit 1),
    # or ran its whole duration and judged itself a success
    assert run.p.returncode == (130 if stopped else 0), out[-3000:]
    gaps = revisit_gaps(np.array(times), np.array(track), pts, radius=0.7)
    run_s = times[-1] - times[0]
    assert (gaps < run_s).all(), f"route points never visited (gaps {gaps.round(0)} of a {run_s:.0f} s run)"
    assert len(docked) >= 2 and docked[-1][1] > docked[0][1], f"r0 never charged on the dock: {docked[:3]}"
    assert min(min(c) for c in charge.values()) > 0.0, "a robot ran flat"
