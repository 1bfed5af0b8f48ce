"""Subsumption behaviours (rsal/behaviours.py) on synthetic scans: fusion, sectors and every layer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rsal.behaviours import (
    SECTOR_COUNT,
    BehaviourParams,
    ListSectors,
    Sectors,
    Subsumption,
    beam_points,
    fuse,
    fuse_beams,
    lane_distance,
)


def polar(*pairs: tuple[float, float]) -> np.ndarray:
    """Obstacle points in the robot frame from (range m, bearing deg) pairs."""
    a = np.array(pairs, dtype=float).reshape(-1, 2)
    return np.column_stack([a[:, 0] * np.cos(np.radians(a[:, 1])), a[:, 0] * np.sin(np.radians(a[:, 1]))])


def arc(r: float, deg0: float, deg1: float, step: float = 2.0) -> np.ndarray:
    """Points at range ``r`` for every ``step`` degrees from ``deg0`` to ``deg1``."""
    return polar(*[(r, d) for d in np.arange(deg0, deg1 + 1e-9, step)])


def wall_scan(x: float, y: float, yaw: float, wall_y: float, range_max: float = 5.6) -> np.ndarray:
    """A 360-degree, 1-degree scan (robot frame points) of the infinite wall ``y = wall_y``."""
    a = np.radians(np.arange(-180.0, 180.0, 1.0))
    s = np.sin(yaw + a)
    toward = np.sign(wall_y - y) * s > 1e-6
    r = np.full(a.shape, np.inf)
    r[toward] = (wall_y - y) / s[toward]
    hit = (r > 0) & (r < range_max)
    return np.column_stack([r[hit] * np.cos(a[hit]), r[hit] * np.sin(a[hit])])


# ---------------------------------------------------------------------------- fusion and sectors
def test_no_points_means_every_sector_is_far():
    assert np.all(np.isinf(fuse([]).dist))
    assert np.all(fuse([None, np.empty((0, 2))], far=8.0).dist == 8.0)
    assert fuse([]).dist.shape == (SECTOR_COUNT,)


@pytest.mark.parametrize(("bearing", "sector"), [(0, 0), (4.9, 0), (5.1, 1), (90, 9), (180, 18), (-90, 27), (-5.1, 35)])
def test_points_are_binned_by_bearing(bearing, sector):
    s = fuse([polar((1.5, bearing))])
    assert s.dist[sector] == pytest.approx(1.5)
    assert np.isinf(np.delete(s.dist, sector)).all()


@pytest.mark.parametrize(("laser", "sonar"), [(2.0, 0.8), (0.8, 2.0)])
def test_fusion_keeps_the_nearer_of_laser_and_sonar(laser, sonar):
    """Fig. 3.23: "the minimum of the two values is adopted for reasons of safety"."""
    s = fuse([polar((laser, 0)), polar((sonar, 2))])
    assert s.dist[0] == pytest.approx(0.8)
    # the order of the sensors does not matter
    assert fuse([polar((sonar, 2)), polar((laser, 0))]).dist[0] == pytest.approx(0.8)


def test_a_glass_wall_the_laser_misses_is_still_seen_by_the_sonar():
    laser = beam_points(np.zeros((3, 3)), np.array([5.6, 5.6, 5.6]), 5.6)  # all at max range: no hit
    sonar = polar((0.5, 0))
    assert len(laser) == 0
    assert fuse([laser, sonar]).min_between(-30, 30) == pytest.approx(0.5)


def test_min_between_covers_the_sectors_of_the_angle_range():
    d = np.full(SECTOR_COUNT, 9.0)
    d[3] = 1.0  # 30 degrees
    d[33] = 2.0  # -30 degrees
    d[18] = 0.5  # behind
    s = Sectors(d)
    assert s.min_between(-30, 30) == 1.0
    assert s.min_between(-30, 20) == 2.0
    assert s.min_between(40, 170) == 9.0
    assert s.min_between(170, 190) == 0.5  # across the back
    assert s.min_between(-100, -30) == 2.0  # wraps to sectors 26..33


def test_sectors_empty():
    assert Sectors.empty().min_between(-180, 180) == math.inf
    assert Sectors.empty(far=3.0).min_between(0, 10) == 3.0


def test_beam_points_use_the_sensor_pose_and_drop_misses():
    poses = np.array([[0.1, 0.0, 0.0], [0.0, 0.2, math.pi / 2], [0.0, 0.0, math.pi], [0.0, 0.0, 0.0]])
    ranges = np.array([1.0, 0.5, 5.0, np.nan])
    pts = beam_points(poses, ranges, range_max=5.0)
    np.testing.assert_allclose(pts, [[1.1, 0.0], [0.0, 0.7]], atol=1e-12)


def test_beam_points_with_more_ranges_than_poses_use_the_common_length():
    pts = beam_points(np.zeros((2, 3)), np.array([1.0, 2.0, 3.0]), range_max=5.0)
    assert pts.shape == (2, 2)


# ---------------------------------------------------------------------------- command (lowest layer)
def test_idle_without_a_command():
    b = Subsumption()
    assert b.step(Sectors.empty(), 0.0) == (0.0, 0.0)
    assert b.state == "idle"


def test_command_passes_through_in_free_space():
    b = Subsumption()
    b.set_command(0.3, -0.2)
    assert b.step(Sectors.empty(), 0.0) == (0.3, -0.2)
    assert b.state == "command"


def test_turning_on_the_spot_is_a_command_not_idle():
    b = Subsumption()
    b.set_command(0.0, 0.5)
    assert b.step(fuse([polar((0.2, 0))]), 0.0) == (0.0, 0.5)
    assert b.state == "command"


def test_a_standing_robot_does_not_avoid_or_escape():
    b = Subsumption()
    near = fuse([polar((0.1, 0))])
    for t in range(10):
        assert b.step(near, float(t), stalled=True) == (0.0, 0.0)
    assert b.state == "idle" and b.escapes == 0


# ---------------------------------------------------------------------------- avoid
@pytest.mark.parametrize("nearer", ["left", "right"])
def test_avoid_turns_away_from_the_nearer_side(nearer):
    sign = 1.0 if nearer == "left" else -1.0
    # something 0.5 m ahead, slightly to the nearer side, and a wall 0.6 m on that side
    s = fuse([polar((0.5, 10 * sign)), arc(0.6, 40, 90) * [1, sign]])
    b = Subsumption()
    b.set_command(0.4, 0.0)
    v, w = b.step(s, 0.0)
    assert b.state == "avoid"
    assert w == pytest.approx(-sign * b.p.turn_rate)  # away from the nearer side
    assert 0.0 < v < 0.4


def test_avoid_subsumes_the_command():
    b = Subsumption()
    b.set_command(0.4, 0.7)  # the user wants to turn left ...
    s = fuse([polar((0.5, 0)), arc(0.5, 40, 90)])  # ... but the left is the nearer side
    v, w = b.step(s, 0.0)
    assert b.state == "avoid"
    assert (v, w) != (0.4, 0.7)
    assert w < 0


def test_avoid_slows_down_the_closer_the_obstacle_and_stops_inside_stop_dist():
    p = BehaviourParams()
    assert p.stop_dist < 0.4 < 0.65 < p.avoid_dist
    speeds = []
    for r in (0.65, 0.5, 0.4, p.stop_dist - 0.05):
        b = Subsumption(BehaviourParams())
        b.set_command(0.4, 0.0)
        speeds.append(b.step(fuse([polar((r, 0))]), 0.0)[0])
        assert b.state == "avoid"
    assert speeds[0] > speeds[1] > speeds[2] > 0.0
    assert speeds[3] == 0.0


def test_obstacles_beside_or_behind_do_not_trigger_avoid():
    b = Subsumption()
    b.set_command(0.4, 0.0)
    s = fuse([arc(0.3, 60, 120), arc(0.3, -120, -60), arc(0.2, 150, 210)])
    assert b.step(s, 0.0) == (0.4, 0.0)
    assert b.state == "command"


def test_avoid_while_wall_following_turns_away_from_the_wall():
    b = Subsumption()
    b.set_wallfollow(True, "left")
    # obstacle ahead, and the right side is the nearer one: still turn right, away from the left wall
    s = fuse([polar((0.5, 0)), arc(0.5, -90, -40), arc(0.8, 60, 120)])
    _, w = b.step(s, 0.0)
    assert b.state == "avoid"
    assert w < 0


# ---------------------------------------------------------------------------- escape (highest)
def test_escape_triggers_when_blocked_for_stuck_time():
    p = BehaviourParams(stuck_time=2.0, escape_time=1.5)
    b = Subsumption(p)
    b.set_command(0.4, 0.0)
    blocked = fuse([polar((0.3, 0)), arc(0.4, -90, -40)])  # right side nearer: escape turns left
    t = 0.0
    while t < p.stuck_time - 1e-9:
        b.step(blocked, t)
        assert b.state == "avoid", t
        t += 0.1
    v, w = b.step(blocked, p.stuck_time)
    assert b.state == "escape" and b.escapes == 1
    assert v == p.escape_speed < 0  # backs up
    assert w == pytest.approx(p.turn_rate)  # towards the more open (left) side


def test_escape_subsumes_everything_until_escape_time_is_over():
    p = BehaviourParams(stuck_time=0.5, escape_time=1.0)
    b = Subsumption(p)
    b.set_command(0.4, 0.0)
    b.step(fuse([polar((0.2, 0))]), 0.0)
    b.step(fuse([polar((0.2, 0))]), 0.5)
    assert b.state == "escape"
    free = Sectors.empty()
    for t in (0.6, 1.0, 1.49):  # the obstacle is gone, the escape manoeuvre goes on
        assert b.step(free, t)[0] == p.escape_speed
        assert b.state == "escape"
    assert b.step(free, 1.5) == (0.4, 0.0)
    assert b.state == "command" and b.escapes == 1


def test_a_stall_alone_triggers_escape_in_free_space():
    p = BehaviourParams(stuck_time=1.0)
    b = Subsumption(p)
    b.set_command(0.4, 0.0)
    b.step(Sectors.empty(), 0.0, stalled=True)
    assert b.state == "command"
    b.step(Sectors.empty(), 1.0, stalled=True)
    assert b.state == "escape"


def test_being_free_in_between_restarts_the_stuck_clock():
    p = BehaviourParams(stuck_time=1.0)
    b = Subsumption(p)
    b.set_command(0.4, 0.0)
    blocked, free = fuse([polar((0.2, 0))]), Sectors.empty()
    b.step(blocked, 0.0)
    b.step(blocked, 0.9)
    b.step(free, 0.95)
    b.step(blocked, 1.0)
    b.step(blocked, 1.9)
    assert b.state == "avoid" and b.escapes == 0
    b.step(blocked, 2.0)
    assert b.state == "escape"


# ---------------------------------------------------------------------------- wall-follow
def drive_along_wall(side: str, start_dist: float, start_yaw: float, seconds: float = 30.0, dt: float = 0.1):
    """Close the loop: unicycle kinematics and a synthetic scan of a straight wall; returns the
    distances to the wall over time and the states seen."""
    sign = 1.0 if side == "left" else -1.0
    b = Subsumption()
    b.set_wallfollow(True, side)
    x, y, yaw = 0.0, 0.0, sign * start_yaw
    wall_y = sign * start_dist
    dists, states = [], set()
    for i in range(int(seconds / dt)):
        v, w = b.step(fuse([wall_scan(x, y, yaw, wall_y)]), i * dt)
        states.add(b.state)
        x += v * math.cos(yaw) * dt
        y += v * math.sin(yaw) * dt
        yaw += w * dt
        dists.append(abs(wall_y - y))
    return np.array(dists), states, yaw, x


@pytest.mark.parametrize("side", ["left", "right"])
@pytest.mark.parametrize(("start_dist", "start_yaw"), [(0.3, 0.0), (1.0, 0.0), (0.6, 0.3), (1.2, -0.3)])
def test_wallfollow_keeps_wall_dist(side, start_dist, start_yaw):
    dists, states, yaw, x = drive_along_wall(side, start_dist, start_yaw)
    wall_dist = BehaviourParams().wall_dist
    settled = dists[len(dists) // 2 :]  # the last 15 s
    assert np.all(np.abs(settled - wall_dist) < 0.05), (settled.min(), settled.max())
    assert abs(math.remainder(yaw, 2 * math.pi)) < 0.05  # parallel to the wall
    assert x > 8.0  # and it kept going along it
    assert "wallfollow" in states
    assert dists.min() > BehaviourParams().stop_dist - 0.1  # never ran into it


def test_wallfollow_turns_towards_a_far_wall_and_away_from_a_near_one():
    b = Subsumption()
    b.set_wallfollow(True, "left")
    _, w_far = b.step(fuse([wall_scan(0, 0, 0, 1.0)]), 0.0)
    _, w_near = b.step(fuse([wall_scan(0, 0, 0, 0.45)]), 0.1)
    _, w_at = b.step(fuse([wall_scan(0, 0, 0, 0.6)]), 0.2)
    assert w_far > 0 > w_near
    assert abs(w_at) < 0.05


def test_wallfollow_without_a_wall_curves_towards_the_side_to_find_one():
    for side, sign in (("left", 1), ("right", -1)):
        b = Subsumption()
        b.set_wallfollow(True, side)
        v, w = b.step(Sectors.empty(), 0.0)
        assert b.state == "wallfollow"
        assert v > 0 and sign * w > 0


def test_wallfollow_is_below_avoid_and_replaced_by_a_command():
    b = Subsumption()
    b.set_wallfollow(True)
    assert b.wallfollow
    b.set_command(0.2, 0.0)
    assert not b.wallfollow
    assert b.step(fuse([wall_scan(0, 0, 0, 0.6)]), 0.0) == (0.2, 0.0)


def test_wallfollow_side_is_checked():
    b = Subsumption()
    with pytest.raises(ValueError, match="'left' or 'right'"):
        b.set_wallfollow(True, "up")
    b.set_wallfollow(True, "right")
    assert b.p.side == "right"


def test_plain_python_fusion_matches_the_numpy_fusion():
    deg = np.radians([90, 50, 30, 10, -10, -30, -50, -90])  # the Pioneer 2DX sonar ring
    poses = np.column_stack([[0.069, 0.114, 0.148, 0.166, 0.166, 0.148, 0.114, 0.069], np.zeros(8), deg])
    poses[:, 1] = [0.136, 0.119, 0.078, 0.027, -0.027, -0.078, -0.119, -0.136]
    beams = [(x, y, math.cos(a), math.sin(a)) for x, y, a in poses.tolist()]
    rng = np.random.default_rng(1)
    queries = [(-30, 30), (30, 100), (-100, -30), (60, 120), (-120, -60), (30, 60), (-60, -30), (170, 190), (-180, 180)]
    for _ in range(300):
        ranges = rng.uniform(0.05, 6.0, 8).astype(np.float32)
        ranges[rng.random(8) < 0.3] = 5.0  # no echo: the sonar's maximum
        ref = fuse([beam_points(poses, ranges, 5.0)])
        fast = ListSectors(fuse_beams(beams, ranges, 5.0))
        for a0, a1 in queries:
            assert fast.min_between(a0, a1) == pytest.approx(ref.min_between(a0, a1)), (a0, a1, ranges)


# ---------------------------------------------------------------------------- body-aware checks
# A Pioneer 3-AT: 0.626 x 0.505 m; lane half-width 0.35 m, sweep 0.45 m (agents.scenarios.swarm.thesis)
BODY = dict(radius=0.35, stop_dist=0.5, avoid_dist=1.0, corridor=0.35, sweep=0.45)


def test_lane_distance_sees_what_the_front_corners_would_hit_and_not_what_lies_beside():
    # 40 deg off the heading at 0.5 m: outside the +-30 deg cone, 0.32 m from the axis, in the lane
    s = fuse([polar((0.5, 40))])
    assert s.min_between(-30, 30) == math.inf
    assert lane_distance(s, 0.35) == pytest.approx(0.5 * math.cos(math.radians(40)), abs=1e-9)
    assert lane_distance(s, 0.25) == math.inf  # a narrower body passes it
    assert lane_distance(fuse([arc(0.3, 60, 120), arc(0.3, -120, -60)]), 0.35) == math.inf  # beside
    assert lane_distance(fuse([polar((0.6, 180))]), 0.35, behind=True) == pytest.approx(0.6)
    assert lane_distance(fuse([polar((0.6, 180))]), 0.35) == math.inf
    assert lane_distance(ListSectors(list(fuse([polar((0.5, -40))]).dist)), 0.35) == pytest.approx(0.383, abs=1e-3)


def test_the_lane_makes_avoid_stop_for_an_obstacle_at_the_front_corner():
    plain = Subsumption(BehaviourParams(**{**BODY, "corridor": 0.0, "sweep": 0.0}))
    aware = Subsumption(BehaviourParams(**BODY))
    s = fuse([polar((0.52, 40))])  # 0.40 m ahead, 0.33 m aside: the front-left corner's path
    for b in (plain, aware):
        b.set_command(0.4, 0.0)
    assert plain.step(s, 0.0) == (0.4, 0.0) and plain.state == "command"
    v, w = aware.step(s, 0.0)
    assert aware.state == "avoid" and v == 0.0 and w < 0  # stops and turns away (right)


def test_no_turn_in_place_while_something_is_within_the_sweep():
    b = Subsumption(BehaviourParams(**BODY))
    b.set_command(0.4, 0.0)
    boxed = fuse([polar((0.45, 0)), polar((0.4, 90))])  # ahead, and alongside within the sweep
    assert b.step(boxed, 0.0) == (0.0, 0.0) and b.state == "avoid"  # waits
    free_side = fuse([polar((0.46, 0))])
    v, w = b.step(free_side, 0.1)
    assert v == 0.0 and w != 0.0  # nothing within the sweep but ahead at 0.46: turns in place


def test_escape_backs_up_only_into_a_clear_lane_and_turns_only_with_room():
    p = BehaviourParams(**BODY, stuck_time=0.5, escape_time=2.0)

    def escaping(s):
        b = Subsumption(p)
        b.set_command(0.4, 0.0)
        b.step(s, 0.0, stalled=True)
        out = b.step(s, 0.5, stalled=True)
        assert b.state == "escape"
        return out

    v, w = escaping(Sectors.empty())
    assert v == p.escape_speed and abs(w) == pytest.approx(p.turn_rate)  # free: as before
    v, w = escaping(fuse([polar((0.46, 180))]))  # a robot behind, outside the sweep
    assert v == 0.0 and w != 0.0  # turns in place, does not back into it
    assert escaping(fuse([polar((0.4, 180))])) == (0.0, 0.0)  # behind and within the sweep: waits
    # beside within the sweep, the lane behind clear: backs up, straight (turning right, away from
    # it, would swing the rear-left corner into it)
    assert escaping(fuse([polar((0.4, 90))])) == (p.escape_speed, 0.0)
    v, w = escaping(fuse([polar((0.42, -60))]))  # front-right: turns left, the front corner swinging away
    assert v == p.escape_speed and w > 0


def test_a_turn_never_swings_a_corner_towards_something_within_the_sweep():
    b = Subsumption(BehaviourParams(**BODY))
    rear_left = fuse([polar((0.42, 135))])
    assert b.guard_turn(rear_left, 0.3, -0.5) == (0.3, 0.0)  # turning right: the rear-left swings in
    assert b.guard_turn(rear_left, 0.3, 0.5) == (0.3, 0.5)  # turning left: it swings away
    front_left = fuse([polar((0.42, 45))])
    assert b.guard_turn(front_left, 0.0, 0.5) == (0.0, 0.0)
    assert b.guard_turn(front_left, 0.0, -0.5) == (0.0, -0.5)
    assert b.guard_turn(fuse([polar((0.5, 45))]), 0.0, 0.5) == (0.0, 0.5)  # outside the sweep
    assert Subsumption().guard_turn(front_left, 0.0, 0.5) == (0.0, 0.5)  # sweep 0: off
    # the corners beside the heading and the tail: turning right in place swings the front-left
    # corner (39 deg off the axis of a 3-AT) towards the heading, and the rear-right one to the tail
    ahead_left = fuse([polar((0.42, 20))])
    assert b.guard_turn(ahead_left, 0.0, -0.5) == (0.0, 0.0)
    assert b.guard_turn(fuse([polar((0.42, -20))]), 0.0, 0.5) == (0.0, 0.0)  # mirrored
    assert b.guard_turn(fuse([polar((0.42, -170))]), 0.0, -0.5) == (0.0, 0.0)
    assert b.guard_turn(fuse([polar((0.42, 170))]), 0.0, 0.5) == (0.0, 0.0)
    assert b.guard_turn(fuse([polar((0.42, 65))]), 0.0, -0.5) == (0.0, -0.5)  # the left side recedes
    # wall-following a robot alongside on the left at 0.42 m: the controller turns right, away from
    # it, which would swing the rear-left corner into it: it drives straight on instead
    b.set_wallfollow(True, "left")
    alongside = fuse([arc(0.42, 80, 100), polar((0.55, 135))])
    v, w = b.step(alongside, 0.0)
    assert v > 0 and w == 0.0
    assert b.state == "wallfollow"
