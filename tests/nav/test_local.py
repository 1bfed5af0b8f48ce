"""Local planners VFH, ND and SND (mrs_bridge.nav.local, .vfh, .nd, .snd).

Unit tests drive a kinematic unicycle (perfect velocity tracking) among synthetic obstacle points
that a 240-degree, 5.6 m scanner sees; closed-loop tests drive simulated Pioneers in the test room
and on the floor map with the planners' commands at 10 Hz, with a box that is not on the map and
other robots in the way, and check that nothing touches anything (pymunk contacts).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mrs_bridge.nav.local import (
    LocalPlanner,
    ScanMemory,
    Status,
    corridor_clear,
    free_path_length,
    polar_ranges,
)
from mrs_bridge.nav.nd import ND
from mrs_bridge.nav.snd import SND
from mrs_bridge.nav.vfh import VFH
from mrs_bridge.rigs.localsim import Agent, in_contact, laser_points, run
from rsal.geometry import wrap
from simulator import load_world
from simulator.presets import box, pioneer2dx, urg04lx
from simulator.world import World

MAPS = Path(__file__).resolve().parents[2] / "maps"
PIONEER = (0.44, 0.38)
PLANNERS = {"vfh": VFH, "nd": ND, "snd": SND}
FOV = math.radians(240.0)
RANGE = 5.6


def make(name: str, params: dict | None = None) -> LocalPlanner:
    return PLANNERS[name](params or {}, geometry=PIONEER)


# ----------------------------------------------------------------------------------------------- synthetic world
def wall(x0: float, y0: float, x1: float, y1: float, step: float = 0.02) -> np.ndarray:
    n = max(2, int(math.hypot(x1 - x0, y1 - y0) / step) + 1)
    t = np.linspace(0.0, 1.0, n)
    return np.column_stack((x0 + t * (x1 - x0), y0 + t * (y1 - y0)))


def visible(world_pts: np.ndarray, pose, fov: float = FOV) -> np.ndarray:
    """Robot-frame points a ``fov`` (240-degree) scanner of 5.6 m range at ``pose`` sees (no occlusion)."""
    x, y, a = pose
    c, s = math.cos(a), math.sin(a)
    dx, dy = world_pts[:, 0] - x, world_pts[:, 1] - y
    local = np.column_stack((c * dx + s * dy, -s * dx + c * dy))
    r = np.hypot(local[:, 0], local[:, 1])
    ang = np.arctan2(local[:, 1], local[:, 0])
    return local[(r < RANGE) & (np.abs(ang) <= fov / 2)]


def unicycle(pose, v: float, w: float, dt: float):
    x, y, a = pose
    if abs(w) < 1e-9:
        return (x + v * dt * math.cos(a), y + v * dt * math.sin(a), a)
    return (
        x + v / w * (math.sin(a + w * dt) - math.sin(a)),
        y - v / w * (math.cos(a + w * dt) - math.cos(a)),
        float(wrap(a + w * dt)),
    )


def drive(
    planner: LocalPlanner, obstacles: np.ndarray, start, goal, *, seconds: float = 60.0, dt: float = 0.1, fov=FOV
):
    """Kinematic closed loop; returns [(pose, (v, w), speed before), ...] and the clearance per step."""
    pose, speed = tuple(start), (0.0, 0.0)
    planner.set_goal(goal)
    trace, clearance = [], []
    for _ in range(int(seconds / dt)):
        cmd = planner.step(pose, speed, visible(obstacles, pose, fov), dt)
        trace.append((pose, cmd, speed))
        speed = (cmd.v, cmd.w)
        pose = unicycle(pose, cmd.v, cmd.w, dt)
        if len(obstacles):
            clearance.append(float(np.hypot(obstacles[:, 0] - pose[0], obstacles[:, 1] - pose[1]).min()))
        if planner.status == Status.DONE:
            break
    return trace, np.array(clearance)


# ----------------------------------------------------------------------------------------------- parameters
def test_unknown_parameter_names_the_closest_valid_one():
    with pytest.raises(ValueError, match=r"unknown parameter 'max_sped'.*did you mean 'max_speed'"):
        VFH({"max_sped": 0.3})
    with pytest.raises(ValueError, match=r"unknown parameter 'goal_tolerance'.*did you mean 'goal_tol'"):
        ND({"goal_tolerance": [0.3, 10]})
    with pytest.raises(ValueError, match=r"unknown parameter 'robot_radios'.*did you mean 'robot_radius'"):
        SND({"robot_radios": 0.3})


@pytest.mark.parametrize(
    ("cls", "params", "pattern"),
    [
        (VFH, {"max_speed": -0.1}, r"'max_speed' = -0.1 is invalid; expected a number in \[0, 5\] m/s"),
        (VFH, {"window_diameter": 60.5}, r"'window_diameter'.*an integer in \[5, 401\] cells"),
        (VFH, {"angle_epsilon": True}, r"'angle_epsilon' = True is invalid"),
        (VFH, {"sector_angle": 7}, r"'sector_angle' = 7 is invalid; expected a divisor of 360"),
        (VFH, {"free_space_cutoff_0ms": 5e5, "obs_cutoff_0ms": 1e5}, r"'obs_cutoff_0ms' = 100000.0 is invalid"),
        (VFH, {"cell_size": float("nan")}, r"'cell_size' = nan is invalid"),
        (
            ND,
            {"max_speed": 0.3},
            r"'max_speed' = 0.3 is invalid; expected a list of 2 numbers in \[0, 5\] x \[1, 720\]",
        ),
        (ND, {"goal_tol": [0.3, 10, 1]}, r"'goal_tol'.*a list of 2 numbers"),
        (ND, {"robot_geometry": "big"}, r"'robot_geometry' = 'big' is invalid"),
        (SND, {"max_turn_rate": 0}, r"'max_turn_rate' = 0 is invalid; expected a number in \[1, 720\] deg/s"),
        (SND, {"robot_radius": -1}, r"'robot_radius' = -1 is invalid"),
    ],
)
def test_bad_values_name_the_key_and_the_expected_range(cls, params, pattern):
    with pytest.raises(ValueError, match=pattern):
        cls(params)


def test_thesis_vfh_block_maps_one_to_one():
    """The vfh driver block of thesis listing A.3, as written (units: m, m/s, deg, deg/s)."""
    p = VFH(
        {
            "safety_dist_0ms": 0.1,
            "safety_dist_1ms": 0.4,
            "free_space_cutoff_1ms": 1000000.0,
            "max_speed": 0.4,
            "max_speed_narrow_opening": 0.1,
            "distance_epsilon": 0.2,
            "angle_epsilon": 3,
            "escape_speed": 0.1,
            "escape_time": 5.0,
            "escape_max_turnrate": 10,
        },
        geometry=PIONEER,
    )
    assert p.pos_tol == 0.2 and p.ang_tol == pytest.approx(math.radians(3))
    assert p.escape_turnrate == pytest.approx(math.radians(10)) and p.escape_time == 5.0
    assert p.safety(0.0) == pytest.approx(0.1) and p.safety(0.5) == pytest.approx(0.25)
    assert p.params["obs_cutoff_1ms"] == 2e6  # defaults to twice free_space_cutoff_1ms (Player: equal)
    assert p.params["max_speed_wide_opening"] == 0.4  # Player: defaults to max_speed
    assert p.v_narrow == 0.1


def test_robot_radius_from_params_or_geometry():
    diag = 0.5 * math.hypot(*PIONEER)
    assert VFH(geometry=PIONEER).robot_radius == pytest.approx(diag)
    assert VFH().robot_radius == 0.25
    assert SND({"robot_radius": 0.3}, geometry=PIONEER).robot_radius == 0.3
    snd = SND(geometry=PIONEER)
    assert snd.robot_radius == pytest.approx(diag) and snd.params["min_gap_width"] == pytest.approx(2 * diag + 0.3)
    assert ND({"robot_geometry": [0.6, 0.5]}).robot_radius == pytest.approx(0.5 * math.hypot(0.6, 0.5))
    assert ND(geometry=PIONEER).robot_radius == pytest.approx(diag)
    with pytest.raises(ValueError, match="geometry"):
        VFH(geometry=(0.4, -1))


@pytest.mark.parametrize("name", PLANNERS)
def test_bad_inputs_are_rejected(name):
    p = make(name)
    with pytest.raises(ValueError, match="goal"):
        p.set_goal((1.0, float("nan"), 0.0))
    p.set_goal((1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="points"):
        p.step((0, 0, 0), (0, 0), np.zeros((5, 3)), 0.1)
    with pytest.raises(ValueError, match="dt"):
        p.step((0, 0, 0), (0, 0), None, -1.0)
    # Non-finite points (a driver's bad readings) are dropped, not fatal.
    v, w = p.step((0, 0, 0), (0, 0), np.array([[np.nan, 1.0], [3.0, 3.0]]), 0.1)
    assert math.isfinite(v) and math.isfinite(w)


# ----------------------------------------------------------------------------------------------- helpers
def test_polar_ranges_and_corridor():
    pts = np.array([[1.0, 0.0], [2.0, 0.0], [0.0, 1.5], [-3.0, 0.0]])
    r = polar_ranges(pts, 4)
    assert r.tolist() == [1.0, 1.5, 3.0, math.inf]
    assert not corridor_clear(pts, 0.0, 1.5, 0.3)
    assert corridor_clear(pts, 0.0, 0.6, 0.3)  # the disc stops short of the point at 1 m
    assert corridor_clear(pts, math.radians(45), 3.0, 0.3)


def test_free_path_length_matches_brute_force():
    rng = np.random.default_rng(3)
    radius = 0.39
    for _ in range(40):
        pts = rng.uniform(-3, 3, size=(60, 2))
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) > radius + 0.01]
        kappa = rng.uniform(-3, 3, size=5)
        kappa[0] = 0.0
        got = free_path_length(pts, kappa, radius, horizon=3.0)
        for k, g in zip(kappa, got, strict=True):
            # Walk the arc in 1 mm steps until the disc touches a point.
            s = np.arange(0.0, 3.0, 0.001)
            if abs(k) < 1e-9:
                cx, cy = s, np.zeros_like(s)
            else:
                cx, cy = np.sin(k * s) / k, (1 - np.cos(k * s)) / k
            if abs(k) > 1e-9:
                keep = np.abs(k * s) <= math.pi  # the planner only looks half a turn ahead
                cx, cy, s = cx[keep], cy[keep], s[keep]
            d = np.hypot(cx[:, None] - pts[None, :, 0], cy[:, None] - pts[None, :, 1]).min(axis=1)
            touch = np.flatnonzero(d < radius)
            want = s[touch[0]] if touch.size else 3.0
            assert g == pytest.approx(want, abs=0.003), (k, g, want)


def test_scan_memory_fills_in_only_unseen_directions():
    mem = ScanMemory(keep=3.0, reach=2.0, coverage_time=1.0, interval=0.0, decimate=1)
    mem.update(0.0, (0.0, 0.0, 0.0), np.array([[1.0, 0.0], [0.5, 0.5]]))
    # Turned round on the spot; the scanner now has a hit straight ahead only.
    mem.update(1.5, (0.0, 0.0, math.pi), np.array([[1.0, 0.05]]))
    recalled = mem.recall(2.0, (0.0, 0.0, math.pi))
    # The two old points are now behind, where nothing has been seen for over a second; the live
    # direction ahead is never filled in from memory.
    assert recalled == pytest.approx(np.array([[-1.0, 0.0], [-0.5, -0.5]]))
    mem.update(3.6, (0.0, 0.0, math.pi), np.array([[1.0, 0.05]]))
    assert mem.recall(3.6, (0.0, 0.0, math.pi)).shape == (0, 2)  # older than `keep`: forgotten


# ----------------------------------------------------------------------------------------------- behaviour
@pytest.mark.parametrize("name", PLANNERS)
def test_status_cycle_and_free_space_straight_to_goal(name):
    p = make(name)
    assert p.status == "idle" and p.step((0, 0, 0), (0, 0), None, 0.1) == (0.0, 0.0)
    trace, _ = drive(p, np.empty((0, 2)), (0.0, 0.0, 0.0), (4.0, 0.0, 0.0))
    assert p.status == Status.DONE
    assert all(abs(cmd.w) < 1e-6 for _, cmd, _ in trace[:-5])  # straight, no weaving
    assert max(cmd.v for _, cmd, _ in trace) == pytest.approx(p.v_max)
    final = trace[-1][0]
    assert math.hypot(final[0] - 4.0, final[1]) <= p.pos_tol
    assert p.step(final, (0, 0), None, 0.1) == (0.0, 0.0) and p.status == "done"
    p.set_goal((5.0, 0.0, 0.0))
    assert p.status == "driving"
    p.stop()
    assert p.status == "idle" and p.command == (0.0, 0.0)


@pytest.mark.parametrize("name", PLANNERS)
def test_reaches_position_then_turns_in_place_to_goal_yaw(name):
    p = make(name)
    goal = (2.0, 1.0, math.radians(135))
    trace, _ = drive(p, np.empty((0, 2)), (0.0, 0.0, 0.0), goal)
    assert p.status == Status.DONE
    x, y, a = trace[-1][0]
    assert math.hypot(x - 2.0, y - 1.0) <= p.pos_tol
    assert abs(wrap(a - goal[2])) <= p.ang_tol + 1e-9
    # The yaw is corrected on the spot: once inside the tolerance, no forward motion.
    inside = [cmd for pose, cmd, _ in trace if math.hypot(pose[0] - 2.0, pose[1] - 1.0) <= p.pos_tol]
    assert len(inside) > 3 and all(cmd.v == 0.0 for cmd in inside) and any(cmd.w != 0.0 for cmd in inside)


@pytest.mark.parametrize("name", PLANNERS)
def test_wall_ahead_turns_toward_the_opening(name):
    """A wall across the way at 1.5 m, open 0.6 m left of the robot, far beyond sight on the right,
    the goal straight ahead behind it: turn left and go round the end of the wall."""
    obstacles = wall(1.5, -8.0, 1.5, 0.6)
    p = make(name)
    trace, clearance = drive(p, obstacles, (0.0, 0.0, 0.0), (4.0, 0.0, 0.0))
    turns = [cmd.w for _, cmd, _ in trace if abs(cmd.w) > math.radians(5)]
    assert turns and turns[0] > 0  # its first real turn is to the left, round the end of the wall
    assert p.status == Status.DONE
    assert clearance.min() >= p.robot_radius + p.safety(0.0) - 0.02


def test_vfh_narrow_doorway_at_narrow_opening_speed():
    """A 1 m door in a wall: VFH slows to max_speed_narrow_opening on its way into the door and
    speeds up beyond it. With a cautious free_space_cutoff the wall enters the histogram about
    1.2 m before the door, which makes the opening narrow from there on."""
    obstacles = np.vstack([wall(2.0, 0.5, 2.0, 4.0), wall(2.0, -4.0, 2.0, -0.5)])
    p = VFH({"max_speed": 0.5, "max_speed_narrow_opening": 0.15, "free_space_cutoff_0ms": 2e5}, geometry=PIONEER)
    trace, clearance = drive(p, obstacles, (-3.0, 0.2, 0.0), (4.5, 0.0, 0.0))
    assert p.status == Status.DONE
    at_door = [cmd.v for pose, cmd, _ in trace if 1.0 <= pose[0] <= 2.0]
    assert at_door and max(at_door) <= 0.15 + 1e-9
    assert max(cmd.v for _, cmd, _ in trace) > 0.4  # fast in the open before and after
    assert clearance.min() >= p.robot_radius + p.safety(0.0) - 0.02


@pytest.mark.parametrize("name", PLANNERS)
def test_doorway_passed_by_every_planner(name):
    obstacles = np.vstack([wall(2.0, 0.5, 2.0, 4.0), wall(2.0, -4.0, 2.0, -0.5)])
    p = make(name)
    trace, clearance = drive(p, obstacles, (-1.0, -1.2, 0.3), (4.0, 0.5, 0.0))
    assert p.status == Status.DONE
    assert clearance.min() >= p.robot_radius + p.safety(0.0) - 0.02


@pytest.mark.parametrize("name", PLANNERS)
def test_never_drives_into_an_obstacle_inside_the_safety_distance(name):
    """Random clutter and speeds: a command never moves the robot's centre, within the control
    period, closer than robot radius + safety distance to a point it sees that is not already
    that close; and with a point that close ahead, the command does not drive forward."""
    rng = np.random.default_rng(7)
    p = make(name)
    r_safe = p.robot_radius + p.safety(0.0)
    checked = close_ahead = 0
    for _ in range(300):
        pts = rng.uniform(-2.5, 2.5, size=(rng.integers(5, 80), 2))
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) > p.robot_radius + 0.02]
        p.set_goal((rng.uniform(-4, 4), rng.uniform(-4, 4), 0.0))
        p.memory.clear()  # independent scenes at the same pose
        speed = (rng.uniform(0.0, p.v_max), rng.uniform(-0.5, 0.5))
        v, w = p.step((0.0, 0.0, 0.0), speed, pts, 0.1)
        d = np.hypot(pts[:, 0], pts[:, 1])
        if np.any((d < r_safe) & (pts[:, 0] > 0)):
            close_ahead += 1
            assert v <= 0.0
        if v == 0.0:
            continue
        checked += 1
        margin = p.robot_radius + p.safety(max(abs(v), speed[0]))
        for t in np.linspace(0.0, 0.1, 21)[1:]:
            x, y, _ = unicycle((0.0, 0.0, 0.0), v, w, t)
            dd = np.hypot(pts[:, 0] - x, pts[:, 1] - y)
            newly = (dd < margin - 1e-6) & (d >= margin)
            assert not newly.any(), (v, w, t)
    assert checked > 50 and close_ahead > 5


@pytest.mark.parametrize("name", PLANNERS)
def test_speed_turn_rate_and_acceleration_limits(name):
    rng = np.random.default_rng(11)
    p = make(name)
    for i in range(400):
        if i % 20 == 0:
            p.set_goal((rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-3, 3)))
        pts = rng.uniform(-4, 4, size=(40, 2))
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) > 0.8]
        p.memory.clear()
        speed = (rng.uniform(-0.1, p.v_max), rng.uniform(-p.w_max, p.w_max))
        v, w = p.step((0.0, 0.0, 0.0), speed, pts, 0.1)
        assert abs(v) <= p.v_max + 1e-12 and abs(w) <= p.w_max + 1e-12
        if p.accel is not None and abs(v) > abs(speed[0]):
            assert abs(v - speed[0]) <= p.accel * 0.1 + 1e-9
    assert VFH({"max_acceleration": 0.2}).accel == 0.2


def _ring(radius: float) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, 400)
    return np.column_stack((radius * np.cos(a), radius * np.sin(a)))


@pytest.mark.parametrize("name", PLANNERS)
def test_boxed_in_is_blocked_and_keeps_turning_without_closing_in(name):
    """Inside a ring with no way out, seen all round: status "blocked"; the robot keeps turning to
    look for a way and never gets closer to the ring than its radius plus safety distance."""
    p = make(name)
    trace, clearance = drive(p, _ring(0.5), (0.0, 0.0, 0.0), (5.0, 0.0, 0.0), seconds=12.0, fov=2 * math.pi)
    assert p.status == "blocked"
    assert sum(1 for _, cmd, _ in trace if cmd.w != 0.0) > len(trace) // 2
    assert clearance.min() >= p.robot_radius + p.safety(0.0) - 1e-3


def test_escape_backs_up_at_escape_speed_when_the_rear_is_seen():
    """VFH with the escape of thesis listing A.3 (scaled up): blocked in a ring seen all round,
    it backs up at escape_speed while turning at escape_max_turnrate -- but only as far as the
    safety distance allows."""
    p = VFH({"escape_speed": 0.1, "escape_time": 3.0, "escape_max_turnrate": 40}, geometry=(0.3, 0.3))
    trace, clearance = drive(p, _ring(0.6), (0.0, 0.0, 0.0), (5.0, 0.0, 0.0), seconds=12.0, fov=2 * math.pi)
    escapes = [cmd for _, cmd, _ in trace if cmd.v < 0]
    assert escapes and min(c.v for c in escapes) == pytest.approx(-0.1)
    assert max(abs(c.w) for c in escapes) == pytest.approx(math.radians(40))
    assert clearance.min() >= p.robot_radius + p.safety(0.0) - 1e-3


@pytest.mark.parametrize("name", PLANNERS)
def test_never_backs_up_into_unseen_space(name):
    """The same ring seen by a 240-degree scanner: no reversing before the robot has turned far
    enough to have looked behind itself."""
    p = make(name)
    trace, clearance = drive(p, _ring(0.6), (0.0, 0.0, 0.0), (5.0, 0.0, 0.0), seconds=15.0)
    turned = np.cumsum([abs(cmd.w) * 0.1 for _, cmd, _ in trace])
    early = [cmd for (_, cmd, _), t in zip(trace, turned, strict=True) if t < math.radians(120)]
    assert early and all(cmd.v >= 0.0 for cmd in early)
    assert clearance.min() >= p.robot_radius + p.safety(0.0) - 1e-3


@pytest.mark.parametrize("name", PLANNERS)
def test_turns_round_out_of_a_dead_end(name):
    """Facing the end of a 1 m wide dead end with the goal behind: turn on the spot, drive out."""
    dead_end = np.vstack([wall(0.8, -0.5, 0.8, 0.5), wall(-1.5, 0.5, 0.8, 0.5), wall(-1.5, -0.5, 0.8, -0.5)])
    p = PLANNERS[name]({}, geometry=(0.3, 0.3))
    trace, clearance = drive(p, dead_end, (0.0, 0.0, 0.0), (-3.0, 0.5, math.pi), seconds=60)
    assert p.status == Status.DONE
    assert clearance.min() >= p.robot_radius + p.safety(0.0) - 0.02


# ----------------------------------------------------------------------------------------------- closed loop
def _assert_ok(results):
    for r in results:
        assert not r.collided, f"{r.robot} touched something at t={r.collided_at}"
        assert r.reached, f"{r.robot}: status {r.status}, {r.error:.2f} m from the goal after {r.time:.1f} s"


@pytest.fixture(scope="module")
def testroom():
    return load_world(MAPS / "testroom.world")


@pytest.fixture(scope="module")
def floor():
    return load_world(MAPS / "floor.world")


def _robot(name, pose, color="blue"):
    spec = pioneer2dx(name, pose, color=color)
    spec.rangers = [*spec.rangers, urg04lx()]
    spec.max_speed = (0.5, math.radians(90))
    spec.max_accel = (0.5, math.radians(90))
    return spec


@pytest.mark.parametrize("name", PLANNERS)
def test_sim_testroom_round_an_unmapped_box(testroom, name):
    world = World(testroom, seed=1)
    world.set_pose("r0", -3.8, 0.0, 0.0)
    world.add_model(box("crate", (-1.0, 0.1, 0.0), size=(0.5, 0.5, 0.5)))
    res = run(world, [Agent("r0", make(name), (1.0, 0.0, math.pi / 2))], timeout=60)
    _assert_ok(res)
    assert res[0].min_range > make(name).robot_radius


@pytest.mark.parametrize("name", PLANNERS)
def test_sim_testroom_two_robots_head_on(testroom, name):
    world = World(testroom, seed=2)
    world.set_pose("r0", -3.5, 0.1, 0.0)
    world.add_model(_robot("r1", (1.2, -0.1, math.pi)))
    agents = [
        Agent("r0", make(name), (1.2, 0.0, 0.0)),
        Agent("r1", make(name), (-3.5, 0.0, math.pi)),
    ]
    _assert_ok(run(world, agents, timeout=90))


@pytest.mark.parametrize("name", PLANNERS)
def test_sim_floor_corridor_box_and_oncoming_robot(floor, name):
    """In the corridor: r1 drives east past a box that is not on the map, then meets r2 coming
    west; both on odometry (goals converted to the odometry frame at the start)."""
    world = World(floor, seed=3)
    world.set_pose("r0", -20.5, 8.0, 0.0)  # parked in the lab, out of the way
    world.set_pose("r1", -6.0, 1.75, 0.0)
    world.set_pose("r2", 0.0, 1.6, math.pi)
    world.add_model(box("crate", (-4.5, 1.9, 0.0), size=(0.45, 0.45, 0.5)))
    agents = [
        Agent("r1", make(name), (0.0, 1.75, 0.0), odometry=True),
        Agent("r2", make(name), (-6.0, 1.75, math.pi), odometry=True),
    ]
    _assert_ok(run(world, agents, timeout=90))


@pytest.mark.parametrize("name", PLANNERS)
def test_sim_floor_through_the_lab_door(floor, name):
    """From the laboratory through its west door (1.1 m) into the corridor."""
    world = World(floor, seed=4)
    world.set_pose("r2", -14.0, 8.0, 0.0)
    world.set_pose("r0", -21.0, 5.0, -1.2)
    res = run(world, [Agent("r0", make(name), (-21.0, 1.6, -math.pi / 2))], timeout=60)
    _assert_ok(res)


def test_laser_points_and_contact_helpers(testroom):
    world = World(testroom, seed=0)
    world.step()
    pts = laser_points(world, "r0")
    ahead = pts[np.abs(pts[:, 1]) < 0.02]
    # The box's west face is 4.0 m ahead of the robot's centre (laser 0.13 m ahead, 3.87 m range).
    assert ahead[:, 0].min() == pytest.approx(4.0, abs=0.05)
    assert not in_contact(world, "r0")
    world.set_pose("r0", 1.8, 0.0, 0.0)  # against the box
    world.step()
    assert in_contact(world, "r0")
