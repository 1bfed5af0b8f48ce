"""Known moving obstacles in AMCL (mrs_bridge/nav/knownobstacles.py, ``Amcl.set_obstacles``, the
``amcl`` driver's ``set_obstacles``): a sonar echo that a declared neighbour explains is not scored
against the map, and with robots parked round a Pioneer 3-AT its estimate stays on its true pose
(the simulator's ground truth), where scoring their echoes against the map pulls it off."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mrs_bridge.drivers.simmsgs import ranger_data, ranger_geometry
from mrs_bridge.nav import profile
from mrs_bridge.nav.amcl import Amcl
from mrs_bridge.nav.amclparams import AmclParams
from mrs_bridge.nav.grid import NavGrid
from mrs_bridge.nav.knownobstacles import explained_by_obstacles, parse_obstacles
from rsal.interfaces.ranger import RangerGeometry
from simulator import load_world
from simulator.presets import pioneer3at
from simulator.world import World

FLOOR = Path(__file__).resolve().parents[2] / "maps" / "floor.world"
CONE = math.radians(15.0)


def _one_beam(z, bearing=0.0):
    return np.array([z]), np.array([bearing]), np.zeros((1, 2))


@pytest.mark.parametrize(
    ("z", "disc", "explained"),
    [
        (0.75, (1.0, 0.0, 0.3), True),  # the echo off the disc's near side
        (1.0, (1.0, 0.1, 0.3), True),  # off its side, within the cone
        (2.0, (1.0, 0.0, 0.3), False),  # a wall seen past it: the disc is well short of the echo
        (0.3, (1.0, 0.0, 0.3), False),  # something nearer than the disc answered
        (0.75, (1.0, 1.0, 0.3), False),  # 45 deg off a 15 deg cone
        (0.75, (0.0, 0.0, 0.3), True),  # the sonar inside the disc
    ],
)
def test_a_reading_is_explained_only_by_a_disc_in_its_cone_at_its_range(z, disc, explained):
    got = explained_by_obstacles((0.0, 0.0, 0.0), *_one_beam(z), CONE, [disc])
    assert got.tolist() == [explained]


def test_beams_are_taken_in_the_map_frame_from_the_robot_pose():
    # robot at (5, 5) facing +y; a sonar 0.2 m ahead looking left (world -x); a disc 1 m to its left
    pose = (5.0, 5.0, math.pi / 2)
    z, b, o = np.array([0.6, 0.6]), np.array([math.pi / 2, -math.pi / 2]), np.array([[0.2, 0.0], [0.2, 0.0]])
    got = explained_by_obstacles(pose, z, b, o, CONE, [(3.9, 5.2, 0.35)])
    assert got.tolist() == [True, False]
    assert not explained_by_obstacles(pose, z, b, o, CONE, np.zeros((0, 3))).any()


def test_parse_obstacles_names_the_bad_disc():
    assert parse_obstacles([[1, 2, 0.5]]).tolist() == [[1.0, 2.0, 0.5]]
    with pytest.raises(ValueError, match=r"obstacles\[1\] = \[1, 2\] must be \[x, y, radius\]"):
        parse_obstacles([[1, 2, 0.5], [1, 2]])
    with pytest.raises(ValueError, match="radius > 0"):
        parse_obstacles([[1, 2, 0]])
    with pytest.raises(ValueError, match="must be a list"):
        parse_obstacles("near")


def _room() -> NavGrid:
    n = 200  # 10 m, 0.05 m cells
    occ = np.zeros((n, n), dtype=bool)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = True
    return NavGrid.from_occupancy(occ, 0.05, (0.0, 0.0))


def test_a_beam_meeting_a_declared_obstacle_is_not_scored_against_the_map():
    """The filter with the obstacle declared weighs its particles exactly as one that never had the
    reading the obstacle explains: the other beams count, that one does not."""
    params = AmclParams(seed=4, init_pose=(8.5, 5.0, 0.0), init_pose_var=(0.04, 0.04, 0.01), pf_max_samples=800)
    ring = np.linspace(-math.pi, math.pi, 8, endpoint=False)
    z = np.full(8, 4.6)
    # straight ahead (ring[4] = 0) the wall is 1.25 m from the sonar; a robot parked before it echoes at 1 m
    z[4] = 1.0
    origins = 0.15 * np.column_stack([np.cos(ring), np.sin(ring)])
    declared, unaware, without = (Amcl(_room(), params) for _ in range(3))
    declared.set_obstacles([[9.75, 5.0, 0.35]])
    z_without = z.copy()
    z_without[4] = np.nan  # skipped as an invalid reading
    for a, ranges in ((declared, z), (unaware, z), (without, z_without)):
        assert a.sensor(ranges, ring, origins, 0.02, 5.0, beam_width=CONE)
    assert declared.n_explained == 1 and unaware.n_explained == 0
    np.testing.assert_allclose(declared.weights, without.weights, rtol=1e-12)
    assert not np.allclose(unaware.weights, without.weights)  # the reading does move an unaware filter
    declared.set_obstacles([])
    assert declared.obstacles.shape == (0, 3)
    with pytest.raises(ValueError, match="radius > 0"):
        declared.set_obstacles([[1.0, 1.0, -0.2]])


def _parked_run(parked, *, declare: bool, params: dict) -> tuple[float, int]:
    """A Pioneer 3-AT at (-14, 7.5) in the floor map's laboratory, 1.5 m from its east wall, turning
    in place for 30 s among 3-ATs ``parked`` round it; AMCL on its 16 sonars starts 0.14 m off with
    0.4 m standard deviations. ``declare``: the parked robots are declared where their broadcasts
    would put them (0.14 m off their true positions). Returns the worst error against the true pose
    and the filter updates."""
    w = World(load_world(FLOOR), seed=0)
    for n in list(w.robot_names):
        w.remove_model(n)
    x0, y0 = -14.0, 7.5
    w.add_model(pioneer3at("r1", (x0, y0, 0.0)))
    for i, (px, py) in enumerate(parked):
        w.add_model(pioneer3at(f"p{i}", (px, py, 0.0)))
    g = w.grid
    geo = RangerGeometry(ranger_geometry(w.rangers("r1")[0]))
    p = AmclParams(
        **{**profile.AMCL, **profile.AMCL_SONAR, **params},
        init_pose=(x0 + 0.1, y0 - 0.1, 0.0),
        init_pose_var=(0.16, 0.16, math.radians(10) ** 2),
        seed=3,
    )
    a = Amcl(NavGrid.from_occupancy(g.occupied, g.resolution, g.origin), p)
    if declare:
        a.set_obstacles([[px + 0.1, py - 0.1, 0.55] for px, py in parked])
    worst = 0.0
    for k in range(300):
        w.set_velocity("r1", 0.0, 0.35 if (k // 100) % 2 == 0 else -0.35)
        w.step()
        a.odometry(w.odometry("r1"))
        sc = ranger_data(w.ranger("r1", 0))
        o, b = geo.beams(sc)
        a.sensor(sc.ranges, b, o, sc.range_min, sc.range_max, beam_width=geo.beam_width(sc))
        m, _ = a.estimate()
        x, y, _ = w.get_pose("r1")
        worst = max(worst, math.hypot(m[0] - x, m[1] - y))
    return worst, a.n_updates


RING = [(-13.1, 7.5), (-14.0, 8.4), (-14.0, 6.6), (-14.9, 7.5)]  # ahead, left, right, behind, 0.9 m
CORNERS = [(-13.2, 8.3), (-13.2, 6.7), (-14.8, 8.3), (-14.8, 6.7)]


@pytest.mark.parametrize(
    ("parked", "params"),
    [
        # hemmed in by eight: most of the ring sees robots and the distance filter gives up
        (RING + CORNERS, {}),
        # four round it, the distance filter off: echoes of the robot ahead look like the wall behind it
        # (with 2000 particles, the sonar profile's cap before it was 500: with 500 and this seed the
        # unaware filter happens to stay within 0.1 m, and the case would show nothing)
        (RING, {"laser_unmodeled_margin": 0.0, "pf_max_samples": 2000}),
    ],
    ids=["eight-parked", "four-parked-no-distance-filter"],
)
def test_with_robots_parked_round_it_the_estimate_stays_on_the_true_pose_when_they_are_declared(parked, params):
    worst, updates = _parked_run(parked, declare=True, params=params)
    unaware, _ = _parked_run(parked, declare=False, params=params)
    print(f"\nworst error: declared {worst:.2f} m ({updates} updates), undeclared {unaware:.2f} m")
    assert worst < 0.3, f"declared neighbours: worst error {worst:.2f} m"
    assert unaware > 0.5, f"the parked robots should pull an unaware filter off (worst {unaware:.2f} m)"
    if len(parked) == 4:
        assert updates >= 10  # the wall's echoes still count
