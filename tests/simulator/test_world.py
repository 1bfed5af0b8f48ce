"""World behaviour: kinematics, odometry, rangers, blobfinder, gripper, simulation interface."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from simulator.errors import ModelError
from simulator.spec import (
    BlobfinderSpec,
    FloorplanSpec,
    GripperSpec,
    ModelSpec,
    RangerSensorSpec,
    RangerSpec,
    WorldSpec,
)
from simulator.world import World

GREEN = (0, 255, 0)


def room_png(tmp_path: Path) -> Path:
    """10 x 8 m room, origin (-5, -4), 0.05 m/px: inner wall faces x = +-4.85, y = +-3.85."""
    img = np.full((160, 200), 255, dtype=np.uint8)
    img[:3, :] = img[-3:, :] = 0
    img[:, :3] = img[:, -3:] = 0
    p = tmp_path / "room.png"
    Image.fromarray(img).save(p)
    return p


def laser(noise=0.0):
    return RangerSpec(
        name="laser",
        kind="laser",
        pose=(0.13, 0.0, 0.0),
        sensors=[RangerSensorSpec(range_min=0.02, range_max=5.6, fov=math.radians(240), samples=682, noise=noise)],
    )


def sonar8():
    angles = [90, 50, 30, 10, -10, -30, -50, -90]
    return RangerSpec(
        name="sonar",
        kind="sonar",
        sensors=[
            RangerSensorSpec(pose=(0.0, 0.0, math.radians(a)), range_max=5.0, fov=math.radians(15), samples=1)
            for a in angles
        ],
    )


def robot(name="r0", pose=(0.0, 0.0, 0.0), **kw):
    kw.setdefault("odom_error", (0.0, 0.0, 0.0))
    kw.setdefault("odom_noise", (0.0, 0.0, 0.0))
    return ModelSpec(name=name, position=True, pose=pose, **kw)


def blob(name="blob0", pose=(1.0, 0.0, 0.0), **kw):
    kw.setdefault("color", GREEN)
    return ModelSpec(
        name=name,
        pose=pose,
        size=(0.3, 0.3, 0.3),
        gripper_return=True,
        laser_return=False,
        obstacle_return=False,
        mass=0.5,
        **kw,
    )


def world(tmp_path, models, **kw) -> World:
    fp = FloorplanSpec(bitmap=room_png(tmp_path), resolution=0.05, origin=(-5.0, -4.0))
    return World(WorldSpec(floorplan=fp, models=list(models), **kw), seed=kw.pop("seed", 0))


# ---------------------------------------------------------------- kinematics and odometry
def test_commanded_arc_ends_where_the_unicycle_formula_says(tmp_path):
    w = world(tmp_path, [robot(max_accel=(100.0, 100.0))])
    v, om, t = 0.4, 0.5, 4.0
    w.set_velocity("r0", v, om)
    w.step(int(round(t / w.spec.interval_sim)))
    x, y, th = w.get_pose("r0")
    assert x == pytest.approx(v / om * math.sin(om * t), abs=1e-6)
    assert y == pytest.approx(v / om * (1 - math.cos(om * t)), abs=1e-6)
    assert th == pytest.approx(om * t, abs=1e-9)
    # Without odometry error, odometry equals the motion from the start pose.
    assert w.odometry("r0") == pytest.approx((x, y, th), abs=1e-6)


def test_velocity_limits_and_acceleration(tmp_path):
    w = world(tmp_path, [robot(max_speed=(0.5, 1.0), max_accel=(1.0, 2.0))])
    w.set_velocity("r0", 5.0, -9.0)
    assert w.commanded_velocity("r0") == pytest.approx((0.5, -1.0))
    w.step()
    assert w.velocity("r0")[0] == pytest.approx(0.1)  # 1 m/s^2 for 0.1 s
    w.step(10)
    assert w.velocity("r0") == pytest.approx((0.5, -1.0))


def test_odometry_drifts_with_error_and_noise(tmp_path):
    w = world(tmp_path, [robot(odom_error=(0.05, 0.05, 0.1), odom_noise=(0.02, 0.02, 0.05))], seed=4)
    w.set_velocity("r0", 0.3, 0.2)
    w.step(100)
    x, y, th = w.get_pose("r0")
    ox, oy, oth = w.odometry("r0")
    err = math.hypot(ox - x, oy - y)
    assert err > 0.01  # it drifts
    assert err < 0.5  # but stays plausible for 10 s of driving


def test_stepped_runs_are_deterministic_for_a_seed(tmp_path):
    def run(seed):
        w = world(
            tmp_path,
            [robot(odom_error=(0.05, 0.05, 0.1), odom_noise=(0.02, 0.02, 0.05), rangers=[laser(0.01)])],
            seed=seed,
        )
        w.set_velocity("r0", 0.3, 0.2)
        w.step(30)
        return w.odometry("r0"), w.ranger("r0").ranges.copy()

    (o1, r1), (o2, r2), (o3, _) = run(1), run(1), run(2)
    assert o1 == o2 and np.array_equal(r1, r2)
    assert o1 != o3


def test_robot_stops_at_wall_and_reports_stall(tmp_path):
    w = world(tmp_path, [robot(pose=(4.0, 0.0, 0.0))])
    w.set_velocity("r0", 0.5, 0.0)
    w.step(40)
    x, _, _ = w.get_pose("r0")
    assert x < 4.85 - 0.22 + 0.02  # half length 0.22 m from the wall face, within contact slop
    assert w.stalled("r0")


def test_robots_collide_with_each_other(tmp_path):
    w = world(tmp_path, [robot("a", (0.0, 0.0, 0.0)), robot("b", (1.0, 0.0, math.pi))])
    w.set_velocity("a", 0.5, 0.0)
    w.set_velocity("b", 0.5, 0.0)
    w.step(30)
    ax, ay, _ = w.get_pose("a")
    bx, by, _ = w.get_pose("b")
    assert bx - ax > 0.44 - 0.03  # never overlap by more than the contact slop


def test_contacts_count_every_robot_robot_and_robot_wall_contact_but_not_objects(tmp_path):
    box = ModelSpec(name="box", pose=(-2.0, 2.0, 0.0), size=(0.4, 0.4, 0.4), mass=2.0, obstacle_return=True)
    w = world(
        tmp_path,
        [
            robot("a", (0.0, 0.0, 0.0)),
            robot("b", (1.0, 0.0, math.pi)),
            robot("c", (4.0, -2.0, 0.0)),
            robot("dd", (-3.0, 2.0, 0.0)),
            box,
        ],
    )
    w.step(5)
    assert w.contacts() == {"robot_robot": 0, "robot_wall": 0, "robots": {}}  # standing apart
    w.set_velocity("dd", 0.5, 0.0)  # pushes the box: not a contact of robots or walls
    w.step(40)
    assert w.contacts()["robots"] == {}
    w.set_velocity("a", 0.5, 0.0)
    w.set_velocity("b", 0.5, 0.0)
    w.step(30)
    c = w.contacts()
    assert c["robot_robot"] >= 1 and c["robot_wall"] == 0
    assert c["robots"]["a"][0] >= 1 and c["robots"]["b"][0] >= 1 and "c" not in c["robots"]
    w.set_velocity("c", 0.5, 0.0)  # into the wall at x = 4.85
    w.step(40)
    c = w.contacts()
    assert c["robot_wall"] >= 1 and c["robots"]["c"][1] >= 1 and c["robots"]["c"][0] == 0
    w.reset()
    assert w.contacts()["robot_robot"] == 0


def test_robot_pushes_an_obstacle_object(tmp_path):
    box = ModelSpec(name="box", pose=(1.0, 0.0, 0.0), size=(0.4, 0.4, 0.4), mass=2.0, obstacle_return=True)
    w = world(tmp_path, [robot(), box])
    w.set_velocity("r0", 0.4, 0.0)
    w.step(40)
    assert w.get_pose("box")[0] > 1.5


# ---------------------------------------------------------------- rangers
def test_laser_reads_distance_to_wall_within_noise(tmp_path):
    noise = 0.01
    w = world(tmp_path, [robot(pose=(0.0, 0.5, 0.0), rangers=[laser(noise)])])
    w.step()
    z = w.ranger("r0").ranges
    assert z.shape == (682,) and z.dtype == np.float32
    centre = z[340:342]  # the two beams around straight ahead
    assert np.all(np.abs(centre - (4.85 - 0.13)) < 4 * noise)
    # The beam at +90 degrees (index 85 + 512 = ...) reads the north wall 3.35 m away.
    k = int(round((math.radians(90) + math.radians(120)) / (math.radians(240) / 681)))
    assert abs(z[k] - 3.35) < 0.05


def test_laser_sees_other_robot_and_not_laser_invisible_objects(tmp_path):
    w = world(tmp_path, [robot(rangers=[laser()]), robot("r1", (2.0, 0.0, 0.0)), blob(pose=(1.0, 0.0, 0.0))])
    w.step()
    ahead = w.ranger("r0").ranges[340:342]
    # r1 is seen as a circle of radius 0.22 around (2, 0): 2 - 0.22 - 0.13 from the laser; the blob
    # in between has laser_return 0 and is not seen.
    assert np.all(np.abs(ahead - (2.0 - 0.22 - 0.13)) < 0.01)


def test_sonar_cone_reads_minimum_across_its_width(tmp_path):
    # A thin pole 0.5 m ahead and 0.06 m to the side is inside the 15-degree cone of the 10-degree
    # transducer... but not on its axis.
    pole = ModelSpec(name="pole", pose=(1.0, 0.12, 0.0), size=(0.06, 0.06, 1.0), obstacle_return=True)
    w = world(tmp_path, [robot(rangers=[sonar8()]), pole])
    w.step()
    z = w.ranger("r0").ranges
    assert z.shape == (8,)
    assert z[3] == pytest.approx(1.0 - 0.03, abs=0.02)  # transducer at +10 degrees sees the pole
    assert z[0] == pytest.approx(3.85, abs=0.02)  # +90 degrees: north wall
    assert z[7] == pytest.approx(3.85, abs=0.02)  # -90 degrees: south wall


def test_ranger_interval_slower_than_the_step(tmp_path):
    lz = laser()
    lz.interval = 0.3
    w = world(tmp_path, [robot(rangers=[lz])])
    w.step()
    first = w.ranger("r0")
    w.step()
    assert w.ranger("r0") is first
    w.step(2)
    assert w.ranger("r0").time > first.time


# ---------------------------------------------------------------- blobfinder
def finder(**kw):
    kw.setdefault("colors", [GREEN])
    kw.setdefault("fov", math.radians(90))
    kw.setdefault("range_max", 3.0)
    return BlobfinderSpec(**kw)


def test_blobfinder_fov_range_and_colour(tmp_path):
    models = [
        robot(blobfinders=[finder()]),
        blob("ahead", (2.0, 0.3, 0.0)),
        blob("far", (3.6, 0.0, 0.0)),  # beyond 3 m
        blob("behind", (-1.5, 0.0, 0.0)),  # outside the 90-degree field
        blob("red", (1.5, -0.6, 0.0), color=(255, 0, 0)),  # wrong colour
    ]
    w = world(tmp_path, models)
    w.step()
    seen = w.blobfinder("r0")
    assert [b.name for b in seen] == ["ahead"]
    b = seen[0]
    assert b.range == pytest.approx(math.hypot(2.0, 0.3), abs=1e-6)
    assert b.bearing == pytest.approx(math.atan2(0.3, 2.0), abs=1e-6)
    assert b.color == GREEN
    assert b.x < 40  # left of the image centre (80 px wide) since the blob is to the left
    assert 0 <= b.left <= b.x <= b.right < 80 and 0 <= b.top <= b.bottom < 60 and b.area > 0


def test_blobfinder_occlusion_by_walls_and_robots(tmp_path):
    wall_png = tmp_path / "wall.png"
    img = np.full((160, 200), 255, dtype=np.uint8)
    img[:3, :] = img[-3:, :] = 0
    img[:, :3] = img[:, -3:] = 0
    img[60:100, 118:122] = 0  # a short wall at x in [0.9, 1.1], y in [-1, 1]
    Image.fromarray(img).save(wall_png)
    fp = FloorplanSpec(bitmap=wall_png, resolution=0.05, origin=(-5.0, -4.0))
    models = [
        robot(blobfinders=[finder()]),
        blob("hidden_by_wall", (2.0, 0.0, 0.0)),
        robot("r1", (0.0, 1.5, 0.0)),
        blob("hidden_by_robot", (0.0, 2.5, 0.0)),
        blob("visible", (1.0, -2.0, 0.0)),
    ]
    w = World(WorldSpec(floorplan=fp, models=models))
    w.set_pose("r0", 0.0, 0.0, math.radians(45))  # looks north-east: sees r1 side and both blobs
    w.step()
    names = {b.name for b in w.blobfinder("r0")}
    assert "hidden_by_wall" not in names
    w.set_pose("r0", 0.0, 0.0, math.pi / 2)
    w.step()
    assert "hidden_by_robot" not in {b.name for b in w.blobfinder("r0")}
    w.set_pose("r0", 0.0, 0.0, math.atan2(-2.0, 1.0))
    w.step()
    assert "visible" in {b.name for b in w.blobfinder("r0")}


# ---------------------------------------------------------------- gripper
def test_gripper_picks_up_carries_and_drops(tmp_path):
    g = GripperSpec(pose=(0.23, 0.0, 0.0), size=(0.1, 0.3), paddle_time=0.5)
    w = world(tmp_path, [robot(grippers=[g], max_accel=(10.0, 10.0)), blob(pose=(0.25, 0.0, 0.0))])
    w.step()
    st = w.gripper("r0")
    assert st.paddles == "open" and (st.inner_beam or st.outer_beam) and st.carrying is None
    w.gripper_command("r0", "close")
    w.step()
    assert w.gripper("r0").paddles == "closing"
    w.step(5)
    st = w.gripper("r0")
    assert st.paddles == "closed" and st.carrying == "blob0"
    # Carry it 1 m forward and turn: it stays between the paddles.
    w.set_velocity("r0", 0.5, 0.0)
    w.step(20)
    w.set_velocity("r0", 0.0, 0.0)
    w.step(2)
    rx, ry, rth = w.get_pose("r0")
    bx, by, _ = w.get_pose("blob0")
    assert rx > 0.9
    assert bx == pytest.approx(rx + 0.23 * math.cos(rth), abs=1e-6)
    assert by == pytest.approx(ry + 0.23 * math.sin(rth), abs=1e-6)
    w.gripper_command("r0", "open")
    w.step(6)
    st = w.gripper("r0")
    assert st.paddles == "open" and st.carrying is None
    w.set_velocity("r0", -0.5, 0.0)
    w.step(10)
    assert w.get_pose("blob0")[0] == pytest.approx(bx, abs=1e-6)  # left behind


def test_closing_on_nothing_carries_nothing(tmp_path):
    w = world(tmp_path, [robot(grippers=[GripperSpec(paddle_time=0.2)]), blob(pose=(2.0, 0.0, 0.0))])
    w.gripper_command("r0", "close")
    w.step(5)
    st = w.gripper("r0")
    assert st.paddles == "closed" and st.carrying is None and not st.inner_beam
    with pytest.raises(ModelError, match="unknown gripper command"):
        w.gripper_command("r0", "squeeze")


def _finish_times(w: World, steps: int) -> dict[str, float]:
    """Step and note the simulated time at which the gripper first shows each state."""
    seen: dict[str, float] = {}
    for _ in range(steps):
        w.step()
        st = w.gripper("r0")
        seen.setdefault(st.paddles, st.time)
        seen.setdefault(st.lift, st.time)
    return seen


def test_paddles_and_lift_move_on_their_own_clocks(tmp_path):
    g = GripperSpec(paddle_time=0.6, lift_time=1.0)
    w = world(tmp_path, [robot(grippers=[g])])
    # Started together: each finishes after its own duration.
    w.gripper_command("r0", "close")
    w.gripper_command("r0", "up")
    seen = _finish_times(w, 15)
    assert seen["closed"] == pytest.approx(0.6)
    assert seen["up"] == pytest.approx(1.0)
    # Started apart: a paddle command during a lift motion neither restarts nor hurries the lift.
    w.gripper_command("r0", "down")
    w.step(5)
    w.gripper_command("r0", "open")
    start = w.time
    seen = _finish_times(w, 15)
    assert seen["down"] == pytest.approx(start + 0.5)
    assert seen["open"] == pytest.approx(start + 0.6)
    # And the other way round: a lift command during a paddle motion.
    w.gripper_command("r0", "close")
    w.step(3)
    w.gripper_command("r0", "up")
    start = w.time
    seen = _finish_times(w, 15)
    assert seen["closed"] == pytest.approx(start + 0.3)
    assert seen["up"] == pytest.approx(start + 1.0)


# ---------------------------------------------------------------- simulation interface
def test_set_get_pose_add_remove_pause_reset(tmp_path):
    w = world(tmp_path, [robot(rangers=[laser()])])
    w.set_pose("r0", 1.0, -1.0, 0.5)
    assert w.get_pose("r0") == pytest.approx((1.0, -1.0, 0.5))
    assert w.odometry("r0") == (0.0, 0.0, 0.0)  # teleporting does not move odometry
    w.add_model(robot("proxy", (-2.0, 0.0, 0.0)))
    assert "proxy" in w.robot_names
    w.set_pose("r0", -1.0, 0.0, 0.0)
    w.step()
    # The laser of r0 now sees the proxy 1 m behind... no, ahead is east: proxy is west; turn round.
    w.set_pose("r0", -1.0, 0.0, math.pi)
    w.step()
    assert w.ranger("r0").ranges[340:342].max() == pytest.approx(1.0 - 0.22 - 0.13, abs=0.01)
    w.remove_model("proxy")
    w.step()
    assert w.ranger("r0").ranges[340:342].min() > 3.0
    with pytest.raises(ModelError, match="no model named 'proxy'"):
        w.get_pose("proxy")
    w.pause()
    t = w.time
    assert w.advance() is False and w.time == t
    w.step()
    assert w.time > t
    w.reset()
    assert w.time == 0.0 and w.get_pose("r0") == pytest.approx((0.0, 0.0, 0.0)) and "proxy" not in w.model_names


def test_each_robot_drives_by_its_own_command_as_models_come_and_go(tmp_path):
    """Robots are driven in one batched pass over the physics bodies; removing, adding and
    picking up models reorders those bodies, and every robot must still follow its own command."""
    g = GripperSpec(paddle_time=0.1)
    models = [
        robot("a", (-3.0, -2.0, 0.0), max_accel=(100.0, 100.0)),
        robot("b", (-3.0, 0.0, 0.0), max_accel=(100.0, 100.0)),
        blob("blob0", (3.23, 2.0, 0.0)),
        robot("c", (3.0, 2.0, 0.0), grippers=[g], max_accel=(100.0, 100.0)),
    ]
    w = world(tmp_path, models)
    w.remove_model("b")  # the body list is reordered
    w.add_model(robot("d", (-3.0, 2.0, math.pi / 2), max_accel=(100.0, 100.0)))
    w.gripper_command("c", "close")
    w.step(2)
    assert w.gripper("c").carrying == "blob0"  # the blob's body has left the space
    cmds = {"a": (0.5, 0.0), "c": (0.0, -0.4), "d": (0.3, 0.6)}
    start = {n: w.get_pose(n) for n in cmds}
    for n, (v, om) in cmds.items():
        w.set_velocity(n, v, om)
    t = 2.0
    w.step(int(round(t / w.spec.interval_sim)))
    for n, (v, om) in cmds.items():
        x0, y0, th0 = start[n]
        if om:
            dx = v / om * (math.sin(th0 + om * t) - math.sin(th0))
            dy = -v / om * (math.cos(th0 + om * t) - math.cos(th0))
        else:
            dx, dy = v * t * math.cos(th0), v * t * math.sin(th0)
        x, y, th = w.get_pose(n)
        assert (x, y) == pytest.approx((x0 + dx, y0 + dy), abs=1e-6), n
        assert math.remainder(th - th0 - om * t, 2 * math.pi) == pytest.approx(0.0, abs=1e-9), n


def test_errors_name_the_model_and_the_fix(tmp_path):
    w = world(tmp_path, [robot(), blob()])
    with pytest.raises(ModelError, match="not a robot"):
        w.set_velocity("blob0", 1.0, 0.0)
    with pytest.raises(ModelError, match="must be finite"):
        w.set_velocity("r0", float("nan"), 0.0)
    with pytest.raises(ModelError, match="already exists"):
        w.add_model(robot())
    with pytest.raises(ModelError, match="has 0 ranger"):
        w.ranger("r0", 0)


def test_clearance_of_a_single_point_off_the_map_is_zero():
    import numpy as np

    from simulator.gridmap import GridMap

    g = GridMap(np.zeros((10, 10), dtype=bool), 0.1, (0.0, 0.0))
    assert g.clearance(50.0, 50.0) == 0.0
    assert g.clearance(0.55, 0.55) > 0.0
    assert g.clearance(np.array([0.55, 50.0]), np.array([0.55, 50.0])).tolist()[1] == 0.0
