"""Robots (rsal/robot.py) on real device proxies over an in-memory fabric: no Zenoh, no server.

:class:`rsal.testing.FakeFabric` stands in for :class:`rsal.client.Fabric` the way httpx's
``MockTransport`` stands in for the network: proxies declare their subscribers on its in-memory
session, the test pushes msgpack samples into them, and commands and RPCs are recorded
(``describe`` answered from a table).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from rsal.behaviours import BehaviourParams, ListSectors, fuse
from rsal.data import Position
from rsal.devices import Blobfinder, Gripper, Laser, Position2d, Ranger, Simulation, Sonar
from rsal.msgs import BlobData, BlobfinderData, Position2dData, RangerData
from rsal.robot import ExploreRobot, Pioneer, Robot, RobotError
from rsal.testing import FakeFabric
from tests.conftest import wait_until

LASER_GEOMETRY = {"kind": "laser", "pose": [0.0, 0.0, 0.0], "sensors": [{"pose": [0.0, 0.0, 0.0]}]}
# eight front sonars like a Pioneer-2DX: -90 .. +90 degrees
SONAR_ANGLES = np.radians([90, 50, 30, 10, -10, -30, -50, -90])
SONAR_GEOMETRY = {"kind": "sonar", "pose": [0.0, 0.0, 0.0], "sensors": [{"pose": [0.1, 0.0, a]} for a in SONAR_ANGLES]}
POSITION_GEOMETRY = {"max_speed": [0.3, 0.5]}


@pytest.fixture
def fab():
    return FakeFabric()


@pytest.fixture
def rig(fab):
    """position2d, laser, sonar, simulation, blobfinder and gripper proxies of robot r0."""
    return SimpleNamespace(
        pos=fab.device(Position2d, "r0:position2d:0", POSITION_GEOMETRY),
        laser=fab.device(Laser, "r0:laser:0", LASER_GEOMETRY),
        sonar=fab.device(Sonar, "r0:sonar:0", SONAR_GEOMETRY),
        sim=fab.device(Simulation, "sim:simulation:0", {}),
        blob=fab.device(Blobfinder, "r0:blobfinder:0", {}),
        gripper=fab.device(Gripper, "r0:gripper:0", {}),
    )


def laser_scan(front: float, n: int = 181, range_max: float = 5.6) -> RangerData:
    """A 180-degree scan: ``front`` m within +-20 degrees of straight ahead, nothing elsewhere."""
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = np.where(np.abs(angles) <= math.radians(20), front, range_max)
    return RangerData(0.0, ranges, -math.pi / 2, math.pi / (n - 1), 0.02, range_max)


def sonar_scan(front: float, range_max: float = 5.0) -> RangerData:
    ranges = np.where(np.abs(SONAR_ANGLES) <= math.radians(10), front, range_max)
    return RangerData(0.0, ranges, 0.0, 0.0, 0.1, range_max)


def sonar_reach(r: float) -> float:
    """Distance from the robot centre of an echo at ``r`` m from a front sonar (0.1 m ahead, +-10 deg)."""
    a = math.radians(10)
    return math.hypot(0.1 + r * math.cos(a), r * math.sin(a))


def odom(x: float = 0.0, y: float = 0.0, yaw: float = 0.0, stall: bool = False) -> Position2dData:
    return Position2dData(0.0, (x, y, yaw), (0.0, 0.0, 0.0), stall)


def front_distance(robot: Robot) -> float:
    pts = robot.obstacle_points()
    if not pts:
        return math.inf
    p = np.concatenate(pts)
    ahead = np.abs(np.arctan2(p[:, 1], p[:, 0])) < math.radians(25)
    return float(np.hypot(p[ahead, 0], p[ahead, 1]).min()) if ahead.any() else math.inf


# ---------------------------------------------------------------------------- the device list
def test_robot_sorts_its_devices(rig):
    r = Robot([rig.pos, rig.laser, rig.sonar, rig.sim, rig.blob, rig.gripper])
    assert r.position2d is rig.pos
    assert r.lasers == [rig.laser] and r.sonars == [rig.sonar]
    assert (r.simulation, r.blobfinder, r.gripper) == (rig.sim, rig.blob, rig.gripper)
    assert r.name == "r0" and r.laser_enabled


def test_robot_needs_a_position2d(rig):
    with pytest.raises(RobotError) as ei:
        Robot([rig.laser, rig.sonar])
    assert str(ei.value) == "a robot needs a position2d device; got r0:laser:0, r0:sonar:0"
    with pytest.raises(RobotError, match="got none"):
        Robot([])


def test_robot_needs_a_ranger(rig):
    with pytest.raises(RobotError) as ei:
        Robot([rig.pos, rig.blob], name="scout")
    assert str(ei.value) == "robot 'scout' needs a ranger (laser or sonar)"


def test_a_generic_ranger_counts_as_a_laser(fab, rig):
    ranger = fab.device(Ranger, "r0:ranger:1", LASER_GEOMETRY)
    r = Robot([rig.pos, ranger])
    assert r.lasers == [ranger] and r.sonars == []
    # ... but not when a dedicated laser or sonar is there
    assert Robot([rig.pos, ranger, rig.sonar]).lasers == []


def test_laser_disabled_without_a_sonar_is_refused(rig):
    """The "Laser" flag (thesis 3.5) leaves sonar only: with no sonar there is nothing to avoid with."""
    with pytest.raises(RobotError) as ei:
        Robot([rig.pos, rig.laser], laser=False)
    assert "'r0' has its laser disabled and no sonar" in str(ei.value)
    assert Robot([rig.pos, rig.laser, rig.sonar], laser=False).laser_enabled is False


def test_explore_robot_needs_a_blobfinder(rig):
    with pytest.raises(RobotError, match="needs a blobfinder; r0 has none"):
        ExploreRobot([rig.pos, rig.laser])


# ---------------------------------------------------------------------------- sensing
def test_obstacle_points_fuse_laser_and_sonar(fab, rig):
    r = Robot([rig.pos, rig.laser, rig.sonar])
    assert r.obstacle_points() == []  # no data yet
    fab.push(rig.laser, laser_scan(front=2.0))
    assert front_distance(r) == pytest.approx(2.0, abs=1e-6)
    fab.push(rig.sonar, sonar_scan(front=0.8))
    assert front_distance(r) == pytest.approx(sonar_reach(0.8), abs=1e-6)


def test_with_the_laser_disabled_only_sonar_is_used(fab, rig):
    r = Robot([rig.pos, rig.laser, rig.sonar], laser=False)
    fab.push(rig.laser, laser_scan(front=0.5))
    assert r.obstacle_points() == []  # the laser sees something; it does not count
    fab.push(rig.sonar, sonar_scan(front=1.5))
    assert front_distance(r) == pytest.approx(sonar_reach(1.5), abs=1e-6)
    assert not any(a == rig.laser.addr and op == "describe" for a, op, _ in fab.rpcs)


def test_beams_at_max_range_are_not_obstacles(fab, rig):
    r = Robot([rig.pos, rig.laser])
    fab.push(rig.laser, laser_scan(front=5.6))
    assert sum(len(p) for p in r.obstacle_points()) == 0


def test_a_lost_ranger_is_ignored(fab, rig):
    r = Robot([rig.pos, rig.laser, rig.sonar])
    fab.push(rig.laser, laser_scan(front=0.5))
    fab.push(rig.sonar, sonar_scan(front=2.0))
    rig.laser._set_alive(False)
    assert front_distance(r) == pytest.approx(sonar_reach(2.0), abs=1e-6)


def test_a_ranger_without_geometry_yet_is_skipped(fab, rig):
    mute = fab.device(Sonar, "r0:sonar:1")  # describe not answered
    r = Robot([rig.pos, rig.laser, mute])
    fab.push(mute, sonar_scan(front=0.3))
    fab.push(rig.laser, laser_scan(front=3.0))
    assert front_distance(r) == pytest.approx(3.0, abs=1e-6)


# ---------------------------------------------------------------------------- Pioneer
def test_pioneer_avoids_what_the_laser_sees_only_when_the_laser_is_enabled(fab, rig):
    fab.push(rig.pos, odom())
    fab.push(rig.laser, laser_scan(front=0.5))
    fab.push(rig.sonar, sonar_scan(front=3.0))
    with_laser = Pioneer([rig.pos, rig.laser, rig.sonar])
    without = Pioneer([rig.pos, rig.laser, rig.sonar], laser=False)
    for p in (with_laser, without):
        p.set_command(0.2, 0.0)
        p.update()
    assert with_laser.state == "avoid"
    assert without.state == "command"
    assert fab.velocities()[-1] == (0.2, 0.0)


def test_pioneer_with_the_laser_disabled_still_avoids_with_sonar(fab, rig):
    fab.push(rig.pos, odom())
    fab.push(rig.laser, laser_scan(front=4.0))
    fab.push(rig.sonar, sonar_scan(front=0.4))
    p = Pioneer([rig.pos, rig.laser, rig.sonar], laser=False)
    p.set_command(0.2, 0.0)
    p.update()
    assert p.state == "avoid"
    v, w = fab.velocities()[-1]
    assert v < 0.2 and w != 0.0


def test_pioneer_sectors_are_the_numpy_fusion_of_its_rangers(fab, rig):
    # A sonar ring alone takes the plain-Python path, a laser the numpy one: the same sectors.
    queries = [(-30, 30), (30, 100), (-100, -30), (60, 120), (-120, -60), (170, 190), (-180, 180)]
    rng = np.random.default_rng(2)
    mute = fab.device(Sonar, "r0:sonar:1")  # describe not answered: skipped by both
    sonar_only = Pioneer([rig.pos, rig.laser, rig.sonar, mute], laser=False)
    both = Pioneer([rig.pos, rig.laser, rig.sonar])
    fab.push(mute, sonar_scan(front=0.2))
    for _ in range(50):
        ranges = rng.uniform(0.05, 6.0, 8)
        ranges[rng.random(8) < 0.3] = 5.0  # no echo
        fab.push(rig.sonar, RangerData(0.0, ranges, 0.0, 0.0, 0.1, 5.0))
        fab.push(rig.laser, laser_scan(front=float(rng.uniform(0.3, 5.0))))
        for robot in (sonar_only, both):
            fast, ref = robot.sectors(), fuse(robot.obstacle_points())
            for a0, a1 in queries:
                assert fast.min_between(a0, a1) == pytest.approx(ref.min_between(a0, a1))
    assert isinstance(sonar_only.sectors(), ListSectors) and not isinstance(both.sectors(), ListSectors)
    rig.sonar._set_alive(False)
    assert sonar_only.sectors().min_between(-180, 180) == math.inf  # a lost ranger is ignored


def test_pioneer_takes_its_speed_limits_from_describe(rig):
    p = Pioneer([rig.pos, rig.laser])
    assert p.behaviour.p.cruise_speed == 0.3  # min(0.4 default, 0.3 of the device)
    assert p.behaviour.p.turn_rate == 0.5


def test_pioneer_without_describe_keeps_its_defaults(fab):
    pos = fab.device(Position2d, "r1:position2d:0")  # describe not answered
    laser = fab.device(Laser, "r1:laser:0", LASER_GEOMETRY)
    p = Pioneer([pos, laser])
    assert (p.behaviour.p.cruise_speed, p.behaviour.p.turn_rate) == (0.4, 0.8)


def test_pioneer_does_nothing_before_odometry(fab, rig):
    p = Pioneer([rig.pos, rig.laser])
    p.set_command(0.2, 0.0)
    p.update()
    assert fab.sent == []


def test_pioneer_sends_a_stop_once_and_motion_every_cycle(fab, rig):
    fab.push(rig.pos, odom())
    p = Pioneer([rig.pos, rig.laser])
    for _ in range(3):
        p.update()
    assert fab.velocities() == [(0.0, 0.0)]
    p.set_command(0.1, 0.2)
    for _ in range(3):
        p.update()
    assert fab.velocities()[1:] == [(0.1, 0.2)] * 3
    assert all(a == rig.pos.addr for a, _ in fab.sent)


def test_pioneer_escapes_when_stalled(fab, rig):
    fab.push(rig.pos, odom(stall=True))
    p = Pioneer([rig.pos, rig.laser], params=BehaviourParams(stuck_time=0.0))
    states = []
    p.on_state(states.append)
    p.set_command(0.2, 0.0)
    p.update()
    p.update()
    assert p.state == "escape" and states[-1] == "escape"
    assert fab.velocities()[-1][0] < 0


def test_pioneer_counts_the_distance_travelled(fab, rig):
    p = Pioneer([rig.pos, rig.laser])
    for x, y in ((0.0, 0.0), (3.0, 4.0), (3.0, 5.0)):
        fab.push(rig.pos, odom(x, y))
        p.update()
    assert p.distance == pytest.approx(6.0)


def test_set_position_sets_odometry_and_the_simulated_pose(fab, rig):
    r = Robot([rig.pos, rig.laser, rig.sim], name="r0")
    r.set_position(Position(1.0, 2.0, 0.5))
    calls = [(a, op, args) for a, op, args in fab.rpcs if op != "describe"]
    assert calls == [
        (rig.pos.addr, "set_odom", {"pose": [1.0, 2.0, 0.5]}),
        (rig.sim.addr, "set_pose", {"name": "r0", "pose": [1.0, 2.0, 0.5]}),
    ]


def test_robot_position_is_odometry_without_localize(fab, rig):
    r = Robot([rig.pos, rig.laser])
    assert r.position is None
    fab.push(rig.pos, odom(1.0, -1.0, 0.25))
    assert r.position == Position(1.0, -1.0, 0.25)


def test_run_loop_updates_until_shutdown_then_stops_the_motors(fab, rig):
    fab.push(rig.pos, odom())
    p = Pioneer([rig.pos, rig.laser], period=0.01)
    p.set_command(0.1, 0.0)
    p.start()
    try:
        wait_until(lambda: p.updates >= 3, 5.0, "three update cycles")
    finally:
        p.shutdown()
    n = p.updates
    assert not p._thread.is_alive()
    assert fab.velocities()[-1] == (0.0, 0.0)
    assert p.updates == n  # no cycle after shutdown


# ---------------------------------------------------------------------------- ExploreRobot
def blob_msg(*blobs: tuple[int, float, float]) -> BlobfinderData:
    """Blobs as (id, range, bearing)."""
    return BlobfinderData(
        0.0,
        80,
        60,
        [BlobData(i, 0x00FF00, 40, 30, 30, 50, 20, 40, 100, r, b) for i, r, b in blobs],
    )


def test_explore_robot_reports_each_new_blob_once_with_its_world_position(fab, rig):
    fab.push(rig.pos, odom(1.0, 2.0, math.pi / 2))
    e = ExploreRobot([rig.pos, rig.laser, rig.blob], merge_dist=0.5)
    seen = []
    e.on_blob(seen.append)
    fab.push(rig.blob, blob_msg((1, 2.0, 0.0)))  # 2 m straight ahead: world (1, 4)
    e.update()
    e.update()  # the same blob again: not reported twice
    fab.push(rig.blob, blob_msg((1, 2.1, 0.05)))  # a few cm away: the same blob
    e.update()
    assert len(seen) == 1 and e.found == seen
    assert (seen[0].discovered.x, seen[0].discovered.y) == pytest.approx((1.0, 4.0))
    fab.push(rig.blob, blob_msg((2, 1.0, math.pi / 2)))  # 1 m to the left: world (0, 2)
    e.update()
    assert len(seen) == 2
    assert (seen[1].discovered.x, seen[1].discovered.y) == pytest.approx((0.0, 2.0))
    assert seen[1].id == 2 and seen[1].color == 0x00FF00
