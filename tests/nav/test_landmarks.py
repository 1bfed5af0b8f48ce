"""Neighbours as landmarks (mrs_bridge/nav/landmarks.py, ``known_obstacle_sigma`` > 0): an echo a
declared neighbour explains is scored against the neighbour's body; the compiled score equals a
per-particle reference, and a robot with no wall within its sonars' range keeps its estimate on
the true pose (the simulator's ground truth) from its neighbours' echoes where odometry drifts."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from agents.scenarios.swarm.world import crowd_world
from mrs_bridge.drivers.simmsgs import ranger_data, ranger_geometry
from mrs_bridge.nav import profile
from mrs_bridge.nav.amcl import Amcl
from mrs_bridge.nav.amclparams import AmclParams
from mrs_bridge.nav.conebeam import CONE_RAYS, ConeMap
from mrs_bridge.nav.grid import NavGrid
from mrs_bridge.nav.landmarks import landmark_beam_jit, landmark_beam_numpy
from rsal.geometry import compose, relative
from rsal.interfaces.ranger import RangerGeometry
from simulator.loader import load_world
from simulator.world import World

CONE = math.radians(15.0)


def _room() -> NavGrid:
    n = 200  # 10 m, 0.05 m cells
    occ = np.zeros((n, n), dtype=bool)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = True
    return NavGrid.from_occupancy(occ, 0.05, (0.0, 0.0))


def test_the_landmark_score_equals_the_per_particle_reference():
    g = _room()
    cm = ConeMap(~g.free, g.resolution, g.origin)
    rng = np.random.default_rng(2)
    poses = np.column_stack([rng.uniform(4.0, 6.0, 12), rng.uniform(4.0, 6.0, 12), rng.uniform(-math.pi, math.pi, 12)])
    ring = np.linspace(-math.pi, math.pi, 8, endpoint=False)
    bx, by = 0.15 * np.cos(ring), 0.15 * np.sin(ring)
    bang = (ring[:, None] + CONE * np.linspace(-0.5, 0.5, CONE_RAYS)).reshape(-1)
    z = np.array([1.0, 2.5, 0.8, 4.0, 1.5, 3.2, 0.6, 2.0])
    use = np.array([True, False, True, True, False, True, True, False])
    discs = np.array([[6.2, 5.0, 0.3], [4.0, 6.1, 0.3], [5.0, 3.6, 0.3]])
    prm = dict(rmax=5.0, z_hit=0.95, z_rand=0.05, sigma=0.2, sigma_nb=0.3)
    got = landmark_beam_jit(
        poses[:, 0].copy(), poses[:, 1].copy(), poses[:, 2].copy(), bx, by, bang, z, CONE_RAYS, use,
        discs[:, 0].copy(), discs[:, 1].copy(), discs[:, 2].copy(),
        cm.blocked, cm.clear, cm.resolution, cm.origin[0], cm.origin[1], *prm.values(),
    )  # fmt: skip
    ref = landmark_beam_numpy(cm.blocked, g.resolution, g.origin, poses, bx, by, bang, z, CONE_RAYS, use, discs, **prm)
    # the map's z* by fine marching ends within a tenth of a cell of the exact crossing
    np.testing.assert_allclose(got, ref, rtol=2e-3, atol=0.05)
    # the discs do change the score of the beams marked for them, and only of those
    none = landmark_beam_jit(
        poses[:, 0].copy(), poses[:, 1].copy(), poses[:, 2].copy(), bx, by, bang, z, CONE_RAYS, np.zeros(8, bool),
        discs[:, 0].copy(), discs[:, 1].copy(), discs[:, 2].copy(),
        cm.blocked, cm.clear, cm.resolution, cm.origin[0], cm.origin[1], *prm.values(),
    )  # fmt: skip
    assert np.abs(got - none).max() > 1.0


def _inner_run(tmp_path, sigma: float, seconds: float = 40.0) -> tuple[float, float]:
    """A Pioneer 3-AT at the centre of a 5 x 5 crowd of them 2 m apart in the middle of the 128 m
    arena (no wall within 15 m: none in its sonars' 5 m), driving back and forth and turning among
    the standing others for ``seconds``, its odometry eight times the Pioneer's error; AMCL on its
    16 sonars (the sonar profile) with the others declared at their true positions. Returns the
    worst position error of the estimate and of dead reckoning (odometry from the true start)
    against the true pose."""
    root = Path(__file__).resolve().parents[2]
    path = tmp_path / "crowd.world"
    path.write_text(crowd_world(25, spacing=2.0, model="pioneer3at", bitmap=str(root / "maps" / "arena.png"), seed=1))
    spec = load_world(str(path), seed=1)
    # a worn encoder (eight times the Pioneer's odom_error): dead reckoning drifts within the run
    spec.models[:] = [
        dataclasses.replace(m, odom_error=tuple(8 * e for e in m.odom_error)) if m.name == "r12" else m
        for m in spec.models
    ]
    w = World(spec)
    me = "r12"
    others = [n for n in w.robot_names if n != me]
    g = w.grid
    start = tuple(w.get_pose(me))
    o0 = w.odometry(me)
    p = AmclParams(
        **{**profile.AMCL, **profile.AMCL_SONAR, "known_obstacle_sigma": sigma},
        init_pose=start,
        init_pose_var=(0.01, 0.01, math.radians(3) ** 2),
        seed=5,
    )
    a = Amcl(NavGrid.from_occupancy(g.occupied, g.resolution, g.origin), p)
    a.set_obstacles([[*w.get_pose(n)[:2], 0.55] for n in others])
    geo = RangerGeometry(ranger_geometry(w.rangers(me)[0]))
    worst = drift = 0.0
    steps = int(round(seconds / w.spec.interval_sim))
    for k in range(steps):
        phase = (k * w.spec.interval_sim) % 8.0  # 2 s ahead, 2 s turning, 2 s back, 2 s turning back
        v, om = {0: (0.25, 0.0), 1: (0.0, 0.6), 2: (-0.25, 0.0), 3: (0.0, -0.6)}[int(phase // 2.0)]
        w.set_velocity(me, v, om)
        for n in others:
            w.set_velocity(n, 0.0, 0.0)
        w.step()
        odo = w.odometry(me)
        a.odometry(odo)
        sc = ranger_data(w.ranger(me, 0))
        ob, b = geo.beams(sc)
        a.sensor(sc.ranges, b, ob, sc.range_min, sc.range_max, beam_width=geo.beam_width(sc))
        m, _ = a.estimate()
        x, y, _ = w.get_pose(me)
        dr = compose(start, relative(o0, odo))
        worst = max(worst, math.hypot(m[0] - x, m[1] - y))
        drift = max(drift, math.hypot(dr[0] - x, dr[1] - y))
    return worst, drift


def test_an_inner_robot_stays_on_its_true_pose_from_its_neighbours_echoes(tmp_path):
    worst, drift = _inner_run(tmp_path, sigma=0.3)
    left_out, _ = _inner_run(tmp_path, sigma=0.0)
    print(f"\nworst error: landmarks {worst:.2f} m, left out {left_out:.2f} m, dead reckoning {drift:.2f} m")
    assert drift > 0.5, f"dead reckoning should drift past 0.5 m here (worst {drift:.2f} m)"
    assert left_out > 0.5, f"with the echoes left out the filter has only odometry (worst {left_out:.2f} m)"
    assert worst < 0.5, f"neighbours as landmarks: worst error {worst:.2f} m"
