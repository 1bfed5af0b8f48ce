"""Hardware rehearsal (mrs_bridge/rehearse): the coupling of a simulated world to the emulated
Pioneer and URG, in-process against the known geometry of maps/testroom.world, and ``rsal rehearse``
as a real process: the real p2os driver drives the world's robot (judged by the world's ground
truth, ``world:simulation:0``), its command timeout and the emergency stop stop it, the real hokuyo
driver's laser sees the test room's walls where they are, and one-line errors for a wrong robot
name or world file."""

from __future__ import annotations

import math
import os
import re
import threading
import time

import numpy as np
import pytest

from mrs_bridge.emulators.urg import SENSORS
from mrs_bridge.rehearse.cli import user_config
from mrs_bridge.rehearse.coupling import WorldLaser, WorldRobot
from rsal.msgs import ErrorCode, RpcError, VelocityCmd
from tests.conftest import ROOT, rsal_cmd, wait_until

TESTROOM = ROOT / "maps" / "testroom.world"
URG = SENSORS["URG-04LX"]


@pytest.fixture(scope="module")
def world():
    from simulator.loader import load_world
    from simulator.world import World

    return World(load_world(TESTROOM))


# ---------------------------------------------------------------------------- in-process coupling
def test_the_laser_scene_is_the_test_rooms_geometry(world):
    """r0 at (-2, 0) facing +x, the URG 0.13 m ahead: the box's west face 3.87 m ahead, the north
    and south walls 3.80 m to either side (maps/testroom.world's header)."""
    scene = WorldLaser(world, "r0", URG, (0.13, 0.0, 0.0))
    quarter = URG.ares // 4
    mm = scene(np.array([URG.afrt, URG.afrt + quarter, URG.afrt - quarter]))
    assert mm[0] == pytest.approx(3870, abs=40)
    assert mm[1] == pytest.approx(3800, abs=40) and mm[2] == pytest.approx(3800, abs=40)
    assert URG.angle(URG.afrt + quarter) == pytest.approx(math.pi / 2)


def test_the_body_moves_in_the_world_and_reports_its_odometry(world):
    world.reset()
    body = WorldRobot(world, "r0")
    x0 = world.get_pose("r0")[0]
    body.drive(0.3, 0.0)
    for _ in range(20):  # 2 s
        body.before_step(world)
        world.step()
        body.after_step(world, world.spec.interval_sim)
    moved = world.get_pose("r0")[0] - x0
    s = body.sense()
    assert 0.45 < moved < 0.6  # accelerating, then 0.3 m/s
    assert s.odom[0] == pytest.approx(moved, rel=0.1) and s.vel[0] == pytest.approx(0.3, abs=0.02)
    assert s.paddles == "open" and s.lift == "down" and not s.inner_beam
    assert 12.0 < s.battery < 12.8
    body.gripper("close")
    for _ in range(15):
        body.before_step(world)
        world.step()
        body.after_step(world, world.spec.interval_sim)
    assert body.sense().paddles == "closed"
    world.reset()


def test_the_body_reports_bumpers_stall_and_sonars_from_the_world():
    """r0 with the Pioneer's bumper rings pushed into the test room's east wall (inner face x = 4.8):
    front bumpers pressed, rear ones not, stalled; its sonar ring as the world reads it."""
    from dataclasses import replace

    from simulator.loader import load_world
    from simulator.presets import pioneer_bumper
    from simulator.world import World

    spec = load_world(TESTROOM)
    spec.models = [replace(m, bumpers=[pioneer_bumper()]) if m.name == "r0" else m for m in spec.models]
    w = World(spec)
    w.set_pose("r0", 4.2, -2.0, 0.0)
    body = WorldRobot(w, "r0")
    assert body.sense().front_bumpers == 0 and not any(body.sense().stall)
    body.drive(0.3, 0.0)
    for _ in range(60):
        body.before_step(w)
        w.step()
        body.after_step(w, w.spec.interval_sim)
    s = body.sense()
    assert s.front_bumpers != 0 and s.rear_bumpers == 0 and s.stall == (True, True)
    sonar = next(i for i, r in enumerate(w.rangers("r0")) if r.kind == "sonar")
    assert s.sonars == pytest.approx(w.ranger("r0", sonar).ranges.tolist())


def test_a_user_configuration_gets_the_ptys_and_absolute_paths(tmp_path):
    doc = user_config(ROOT / "deploy" / "pioneer2dx-urg.toml", "r0", "/dev/pts/98", "/dev/pts/99")
    by = {d["name"]: d for d in doc["driver"]}
    assert by["p2os"]["port"] == "/dev/pts/98" and by["hokuyo"]["port"] == "/dev/pts/99"
    assert by["mapfile"]["filename"] == str((ROOT / "maps" / "floor.png").resolve())


# ---------------------------------------------------------------------------- rsal rehearse
def _rehearse(procs, port, fabric_factory, *extra: str):
    p = procs(rsal_cmd("rehearse", str(TESTROOM), "r0", "--listen", f"tcp/127.0.0.1:{port}", *extra))
    fab = fabric_factory(port)
    node = fab.node("r0/**")
    try:
        node.wait_for("r0/position2d/0", timeout=60)
        node.wait_for("r0/laser/0", timeout=30)
    except Exception:
        pytest.fail(f"the rehearsal did not come up:\n{p.output()}")
    fab.node("world/**").wait_for("world/simulation/0", timeout=30)
    sim = fab.device("world:simulation:0")
    return p, fab, sim


def _stop(p):
    assert p.stop() == 0, p.output()
    out = p.output()
    assert "Traceback" not in out
    child = int(re.search(r"rsal serve \(pid (\d+)\)", out).group(1))
    with pytest.raises(ProcessLookupError):  # the drivers' server went with the rehearsal
        os.kill(child, 0)


@pytest.fixture
def rehearsal(procs, port, fabric_factory):
    r = _rehearse(procs, port, fabric_factory)
    yield r
    _stop(r[0])


@pytest.fixture
def rehearsal_nav(procs, port, fabric_factory):
    r = _rehearse(procs, port, fabric_factory, "--nav", "vfh")
    yield r
    _stop(r[0])


def _truth(sim):
    q = sim.get_pose("r0")
    return np.array([q.x, q.y])


def _stopped(sim, dt: float = 0.3) -> bool:
    """Whether the robot's true position stays put for ``dt`` seconds."""
    a = _truth(sim)
    time.sleep(dt)
    return float(np.hypot(*(_truth(sim) - a))) < 1e-4


def _drive(pos, v: float, stop: threading.Event):
    while not stop.is_set():
        pos.send(VelocityCmd(v, 0.0))
        time.sleep(0.1)


def test_the_real_p2os_driver_drives_the_rehearsed_robot(rehearsal):
    p, fab, sim = rehearsal
    pos = fab.device("r0:position2d:0")
    odom0 = pos.wait_for_data(20).pose
    start = _truth(sim)
    stop = threading.Event()
    t = threading.Thread(target=_drive, args=(pos, 0.3, stop), daemon=True)
    t.start()
    try:
        wait_until(lambda: _truth(sim)[0] - start[0] > 0.8, 15, "the robot to drive 0.8 m (ground truth)")
    finally:
        stop.set()
        t.join()
    moved = _truth(sim) - start
    assert abs(moved[1]) < 0.05  # straight on
    wait_until(lambda: abs(pos.latest.vel[0]) < 1e-3, 5, "the odometry to report the robot stopped")
    end = _truth(sim) - start
    odom = np.array(pos.latest.pose[:2]) - np.array(odom0[:2])
    assert np.hypot(*odom) == pytest.approx(np.hypot(*end), rel=0.1)  # the odometry saw the motion, drifting
    power = fab.device("r0:power:0").wait_for_data(10)
    assert power.volts == pytest.approx(12.8, abs=0.15)  # the emulated charged pack, in the SIP's 0.1 V steps


def test_the_command_timeout_and_the_estop_stop_the_rehearsed_robot(rehearsal):
    p, fab, sim = rehearsal
    pos = fab.device("r0:position2d:0")
    pos.wait_for_data(20)
    start = _truth(sim)
    pos.send(VelocityCmd(0.3, 0.0))  # once, never refreshed: cmd_timeout 0.5 s
    wait_until(lambda: _truth(sim)[0] - start[0] > 0.02, 10, "the robot to start (ground truth)")

    wait_until(lambda: _stopped(sim), 5, "the command timeout to stop the robot (ground truth)")
    assert _truth(sim)[0] - start[0] < 0.5  # 0.5 s at 0.3 m/s, braking and the pipeline's latency; not on

    start = _truth(sim)
    stop = threading.Event()
    t = threading.Thread(target=_drive, args=(pos, 0.3, stop), daemon=True)
    t.start()
    try:
        wait_until(lambda: _truth(sim)[0] - start[0] > 0.2, 10, "the robot to drive again (ground truth)")
        pos.estop()
        at_estop = _truth(sim)
        wait_until(lambda: _stopped(sim), 5, "the e-stop to stop the robot while commands go on")
        time.sleep(0.5)  # commands keep coming: the robot must stay where it stopped
        assert np.hypot(*(_truth(sim) - at_estop)) < 0.2
        held = _truth(sim)
        time.sleep(0.5)
        assert np.hypot(*(_truth(sim) - held)) < 1e-3
    finally:
        stop.set()
        t.join()
    pos.release_estop()


def test_the_real_hokuyo_driver_sees_the_test_rooms_walls(rehearsal):
    p, fab, sim = rehearsal
    scan = fab.device("r0:laser:0").wait_for_data(20)
    angles = scan.angle_min + scan.angle_step * np.arange(len(scan.ranges))

    def at(deg):
        return float(scan.ranges[np.argmin(np.abs(angles - math.radians(deg)))])

    assert at(0) == pytest.approx(3.87, abs=0.05)  # the box's west face
    assert at(90) == pytest.approx(3.80, abs=0.05) and at(-90) == pytest.approx(3.80, abs=0.05)  # the walls


def test_the_gripper_fetches_a_bin_through_p2os(rehearsal):
    """The bin 0.5 m ahead: driven up to until the break beams (DIGIN through p2os) see it, gripped,
    lifted and carried 1 m back; judged by where the world says the bin is."""
    from rsal.data import Position

    p, fab, sim = rehearsal
    sim.set_pose("blob0", Position(-1.5, 0.0, 0.0))
    pos = fab.device("r0:position2d:0")
    grip = fab.device("r0:gripper:0")
    pos.wait_for_data(20)
    assert grip.wait_for_data(10).paddles == "open" and grip.beams == 0
    stop = threading.Event()
    t = threading.Thread(target=_drive, args=(pos, 0.1, stop), daemon=True)
    t.start()
    try:
        wait_until(lambda: grip.beams, 15, "the break beams to see the bin")
    finally:
        stop.set()
        t.join()
    pos.stop()
    grip.close().result(timeout=10)
    up = grip.lift_up().result(timeout=10)
    assert up.stored  # paddles closed on something between them
    bin0 = np.array(sim.get_pose("blob0").as_tuple()[:2])
    start = _truth(sim)
    stop.clear()
    t = threading.Thread(target=_drive, args=(pos, -0.2, stop), daemon=True)
    t.start()
    try:
        wait_until(lambda: np.hypot(*(_truth(sim) - start)) > 1.0, 20, "the robot to back up 1 m (ground truth)")
    finally:
        stop.set()
        t.join()
    moved = np.array(sim.get_pose("blob0").as_tuple()[:2]) - bin0
    assert np.hypot(*moved) > 0.9  # the bin came along
    r = _truth(sim)
    assert 0.1 < np.hypot(*(np.array(sim.get_pose("blob0").as_tuple()[:2]) - r)) < 0.5  # held in front


def test_the_navigation_stack_drives_the_rehearsed_robot_to_a_goal(rehearsal_nav):
    """amcl + wavefront + vfh (deploy/r0-nav.toml's stack) on the real drivers' devices: round the
    box's south side to (0.5, -2.5); judged by the world's ground truth."""
    from rsal.data import Position

    p, fab, sim = rehearsal_nav
    fab.node("r0/**").wait_for("r0/planner/0", timeout=60)
    planner = fab.device("r0:planner:0")
    goal = (0.5, -2.5)
    fab.device("r0:position2d:2").wait_for_data(60)  # amcl's first localized pose
    deadline = time.monotonic() + 30
    while True:  # the planner answers unavailable until that pose has reached it too
        try:
            done = planner.set_goal(Position(*goal, 0.0)).result(timeout=90)
            break
        except RpcError as e:
            if e.code != ErrorCode.UNAVAILABLE or time.monotonic() > deadline:
                raise
            time.sleep(0.2)
    assert done == "done"
    assert np.hypot(*(_truth(sim) - goal)) < 0.4, "the robot is not at the goal (ground truth)"
    loc = fab.device("r0:position2d:2").wait_for_data(5).pose
    assert np.hypot(*(_truth(sim) - loc[:2])) < 0.3  # localized to the thesis's 0.30 m


def test_the_deploy_configuration_serves_the_rehearsed_robot(procs, port, fabric_factory):
    """deploy/pioneer2dx-urg.toml as written for the real robot, its ports pointed at the emulators:
    the laser arrives through hokuyo + rangertolaser and reads what the world's own simulated laser
    on r0 (the same mount, laser240) reads, beam for beam within the URG's field of view."""
    from mrs_bridge.drivers.simmsgs import ranger_data
    from simulator.loader import load_world
    from simulator.world import World

    w = World(load_world(ROOT / "maps" / "floor.world"))
    w.step()
    ref = ranger_data(w.ranger("r0", next(i for i, r in enumerate(w.rangers("r0")) if r.kind != "sonar")))
    ref_angles = ref.angle_min + ref.angle_step * np.arange(len(ref.ranges))
    deploy = ROOT / "deploy" / "pioneer2dx-urg.toml"
    p = procs(
        rsal_cmd(
            "rehearse", str(ROOT / "maps" / "floor.world"), "r0", "--robot-config", str(deploy),
            "--listen", f"tcp/127.0.0.1:{port}",
        )
    )  # fmt: skip
    fab = fabric_factory(port)
    node = fab.node("r0/**")
    try:
        node.wait_for("r0/laser/0", timeout=60)
        node.wait_for("r0/map/0", timeout=30)
        node.wait_for("r0/gripper/0", timeout=30)
    except Exception:
        pytest.fail(f"the rehearsal did not come up:\n{p.output()}")
    scan = fab.device("r0:laser:0").wait_for_data(20)
    angles = scan.angle_min + scan.angle_step * np.arange(len(scan.ranges))
    near = np.abs(angles[:, None] - ref_angles[None, :]).argmin(axis=1)
    both = (scan.ranges < scan.range_max) & (ref.ranges[near] < scan.range_max)
    assert both.sum() > 100  # walls around
    diff = np.abs(scan.ranges[both] - ref.ranges[near][both])
    assert float(np.median(diff)) < 0.03 and float(np.mean(diff < 0.1)) > 0.9
    _stop(p)


def test_no_serve_prints_the_command_that_serves_the_robot(procs, port, fabric_factory):
    p = procs(rsal_cmd("rehearse", str(TESTROOM), "r0", "--no-serve", "--listen", f"tcp/127.0.0.1:{port}"))
    line = wait_until(
        lambda: re.search(r"run the robot's drivers yourself with: rsal (serve .*)", p.output()), 60, "the command"
    )
    assert "started the drivers" not in p.output()
    serve = procs(rsal_cmd(*line.group(1).split()))
    fab = fabric_factory(port)
    fab.node("r0/**").wait_for("r0/laser/0", timeout=60)
    scan = fab.device("r0:laser:0").wait_for_data(20)
    assert float(np.min(scan.ranges)) > 0.5  # the room seen by the real driver through the printed ptys
    assert serve.stop() == 0 and p.stop() == 0


BAD_WORLD = """\
include "devices.inc"
fancypioneer9dx( name "r0" pose [ 0 0 0 0 ] )
"""


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([str(TESTROOM), "r00"], "no robot named 'r00'; did you mean 'r0'?"),
        (["maps/nowhere.world", "r0"], "maps/nowhere.world: no such world file"),
        (["{bad}", "r0"], "bad.world:2: unknown model type 'fancypioneer9dx'; did you mean 'fancypioneer2dx'?"),
        ([str(TESTROOM), "r0", "--robot-config", "deploy/r0-nav.toml"], "needs a p2os and a hokuyo driver block"),
        ([str(TESTROOM), "r0", "--robot-config", "deploy/pioneer2dx-urg.toml", "--nav", "vfh"], "--nav adds to"),
    ],
)
def test_user_errors_are_one_line(procs, tmp_path, argv, message):
    bad = tmp_path / "bad.world"
    bad.write_text(BAD_WORLD)
    for inc in (ROOT / "maps" / "include").iterdir():
        (tmp_path / inc.name).symlink_to(inc)
    argv = [a.format(bad=bad) for a in argv]
    p = procs(rsal_cmd("rehearse", *argv, "--listen", "tcp/127.0.0.1:0"))
    wait_until(lambda: not p.alive(), 30, "the command to exit")
    lines = p.output().strip().splitlines()
    assert p.p.returncode == 1 and lines[-1].startswith("rsal rehearse: ") and message in lines[-1], lines
    assert all(ln.startswith("[rehearse] ") for ln in lines[:-1]), lines  # progress, then the one error line
