"""Bumper and fiducial sensors, judged on the simulator's ground truth (body poses, wall faces)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from simulator.presets import fiducial_finder, pioneer_bumper
from simulator.spec import FloorplanSpec, ModelSpec, WorldSpec
from simulator.world import World

WALL_EAST, WALL_WEST = 4.85, -4.85  # inner wall faces of the room below


def room_png(tmp_path: Path, inner_wall: bool = False) -> Path:
    """10 x 8 m room, origin (-5, -4), 0.05 m/px: inner faces x = +-4.85, y = +-3.85; with
    ``inner_wall`` also a wall 0.1 m thick across x = 1.0 .. 1.1 for y in [-1, 1]."""
    img = np.full((160, 200), 255, dtype=np.uint8)
    img[:3, :] = img[-3:, :] = 0
    img[:, :3] = img[:, -3:] = 0
    if inner_wall:
        # rows count from the top: y = 4 - (row + 0.5) * 0.05
        img[60:100, 120:122] = 0
    p = tmp_path / ("room_wall.png" if inner_wall else "room.png")
    Image.fromarray(img).save(p)
    return p


def robot(name="r0", pose=(0.0, 0.0, 0.0), **kw):
    kw.setdefault("odom_error", (0.0, 0.0, 0.0))
    kw.setdefault("odom_noise", (0.0, 0.0, 0.0))
    return ModelSpec(name=name, position=True, pose=pose, size=(0.44, 0.38, 0.22), **kw)


def world(tmp_path, models, inner_wall=False) -> World:
    fp = FloorplanSpec(bitmap=room_png(tmp_path, inner_wall), resolution=0.05, origin=(-5.0, -4.0))
    return World(WorldSpec(floorplan=fp, models=list(models)), seed=0)


def segment_ends(w: World, name: str) -> np.ndarray:
    """World coordinates ``[x0, y0, x1, y1]`` of every bumper segment of ``name``, from the spec
    and the ground-truth pose (independent of the sensor's own tables)."""
    x, y, a = w.get_pose(name)
    out = []
    for seg in w.model_spec(name).bumpers[0].segments:
        sx, sy, sa = seg.pose
        cx, cy = x + math.cos(a) * sx - math.sin(a) * sy, y + math.sin(a) * sx + math.cos(a) * sy
        along = a + sa + math.pi / 2
        hx, hy = 0.5 * seg.length * math.cos(along), 0.5 * seg.length * math.sin(along)
        out.append((cx - hx, cy - hy, cx + hx, cy + hy))
    return np.array(out)


def drive_until_stalled(w: World, name: str, v: float, seconds: float = 6.0) -> None:
    w.set_velocity(name, v, 0.0)
    for _ in range(int(seconds / w.spec.interval_sim)):
        w.step()
        if w.stalled(name):
            w.step(5)  # keep pushing a little
            return
    raise AssertionError(f"{name} never reached the wall: pose {w.get_pose(name)}")


# ---------------------------------------------------------------------------------------- bumper
def test_front_ring_pressed_exactly_while_pushed_into_a_wall_ahead(tmp_path):
    w = world(tmp_path, [robot(pose=(4.0, 0.0, 0.0), bumpers=[pioneer_bumper()])])
    w.step()
    assert w.bumper("r0").pressed.tolist() == [0] * 10  # 0.6 m from the wall
    drive_until_stalled(w, "r0", 0.3)
    x = w.get_pose("r0")[0]
    assert x + 0.22 == pytest.approx(WALL_EAST, abs=0.015)  # the hull is at the wall (sunk ~1 cm)
    assert w.bumper("r0").pressed.tolist() == [1] * 5 + [0] * 5
    # Backing off releases the bumper.
    w.set_velocity("r0", -0.3, 0.0)
    w.step(5)
    assert w.get_pose("r0")[0] < x - 0.05
    assert w.bumper("r0").pressed.tolist() == [0] * 10


def test_rear_ring_pressed_exactly_while_pushed_into_a_wall_behind(tmp_path):
    w = world(tmp_path, [robot(pose=(-4.0, 0.0, 0.0), bumpers=[pioneer_bumper()])])
    drive_until_stalled(w, "r0", -0.3)
    assert w.get_pose("r0")[0] - 0.22 == pytest.approx(WALL_WEST, abs=0.015)
    assert w.bumper("r0").pressed.tolist() == [0] * 5 + [1] * 5


def test_segments_pressed_are_the_ones_crossing_the_wall_at_an_angle(tmp_path):
    """Driving into a wall at 25 degrees: at every step the segments that read 1 are the ones
    whose ground-truth geometry crosses the wall face (the corner first, all five once the
    contact has turned the robot flush)."""
    w = world(tmp_path, [robot(pose=(4.0, 0.0, math.radians(25)), bumpers=[pioneer_bumper()])])
    w.set_velocity("r0", 0.3, 0.0)
    partial = checked = 0
    for _ in range(60):
        w.step()
        ends = segment_ends(w, "r0")
        reach = np.maximum(ends[:, 0], ends[:, 2])  # each segment's furthest x
        pressed = w.bumper("r0").pressed
        clear = np.abs(reach - WALL_EAST) > 0.005  # leave out segments within 5 mm of the face
        assert pressed[clear].tolist() == (reach[clear] > WALL_EAST).astype(int).tolist()
        checked += int(clear.sum())
        partial += int(0 < pressed[:5].sum() < 5)
    assert partial >= 1  # the corner touched before the rest
    assert checked >= 0.9 * 60 * 10
    assert w.bumper("r0").pressed[5:].tolist() == [0] * 5


def test_bodies_press_a_bumper_only_when_they_are_obstacles(tmp_path):
    box = ModelSpec(name="box", pose=(0.33, 0.0, 0.0), size=(0.2, 0.2, 0.2), mass=100.0)  # hull at 0.22, box from 0.23
    ghost = replace(box, name="ghost", pose=(-0.33, 0.0, 0.0), obstacle_return=False)
    far = replace(box, name="far", pose=(0.0, 1.0, 0.0))
    w = world(tmp_path, [robot(bumpers=[pioneer_bumper()]), box, ghost, far])
    w.step()
    pressed = w.bumper("r0").pressed
    assert pressed[:5].tolist() == [0, 1, 1, 1, 0]  # the 0.2 m box covers the middle 3 of 0.076 m segments
    assert pressed[5:].tolist() == [0] * 5  # the ghost (obstacle_return 0) touches the rear but is not felt
    w.set_pose("box", 1.0, 0.0, 0.0)
    w.step()
    assert w.bumper("r0").pressed.tolist() == [0] * 10


def test_bumper_in_describe_and_index_errors(tmp_path):
    w = world(tmp_path, [robot(bumpers=[pioneer_bumper()])])
    assert w.describe()["robots"]["r0"]["bumpers"] == [("bumper", 10)]
    assert w.bumper("r0") is None  # before the first step
    with pytest.raises(Exception, match="has 1 bumper"):
        w.bumper("r0", 1)


# -------------------------------------------------------------------------------------- fiducial
def marker(name="m0", pose=(2.0, 1.0, 0.5), fid=7, key=0, **kw):
    return ModelSpec(name=name, pose=pose, size=(0.2, 0.2, 0.3), fiducial_return=fid, fiducial_key=key, **kw)


def test_fiducial_reports_id_range_bearing_and_yaw_of_a_marked_model(tmp_path):
    w = world(tmp_path, [robot(fiducials=[fiducial_finder()]), marker(), marker("plain", (1.5, -1.0, 0.0), fid=0)])
    w.step()
    seen = w.fiducial("r0")
    assert [f.name for f in seen] == ["m0"]  # fiducial_return 0 is never seen
    f = seen[0]
    x, y, a = w.get_pose("m0")
    assert f.id == 7
    assert f.range == pytest.approx(math.hypot(x, y), abs=1e-6)
    assert f.bearing == pytest.approx(math.atan2(y, x), abs=1e-6)
    assert f.yaw == pytest.approx(a, abs=1e-6)
    assert f.pose[:2] == pytest.approx((x, y), abs=1e-6)
    assert w.describe()["robots"]["r0"]["fiducials"] == 1


def test_fiducial_noise_stays_within_its_deviation(tmp_path):
    finder = replace(fiducial_finder(), range_noise=0.02, bearing_noise=0.01)
    w = world(tmp_path, [robot(fiducials=[finder]), marker(pose=(3.0, 0.0, 0.0))])
    r, b = [], []
    for _ in range(200):
        w.step()
        (f,) = w.fiducial("r0")
        r.append(f.range)
        b.append(f.bearing)
    r, b = np.array(r), np.array(b)
    assert np.abs(r - 3.0).max() < 5 * 0.02 and np.abs(b).max() < 5 * 0.01
    assert r.std() == pytest.approx(0.02, rel=0.25) and abs(r.mean() - 3.0) < 0.01
    assert b.std() == pytest.approx(0.01, rel=0.25)


def test_fiducial_hidden_by_a_wall_and_seen_past_its_end(tmp_path):
    w = world(tmp_path, [robot(fiducials=[fiducial_finder()]), marker(pose=(2.5, 0.0, 0.0))], inner_wall=True)
    w.step()
    assert w.fiducial("r0") == []  # the wall at x = 1.0 .. 1.1, |y| <= 1 is in the way
    w.set_pose("m0", 2.5, 2.6, 0.0)  # the line of sight passes the wall's end (y = 1.14 at x = 1.1)
    w.step()
    assert [f.name for f in w.fiducial("r0")] == ["m0"]


def test_fiducial_range_fov_and_id_range(tmp_path):
    w = world(tmp_path, [robot(pose=(-4.0, 0.0, 0.0), fiducials=[fiducial_finder()]), marker(pose=(4.2, 0.0, 0.0))])
    w.step()
    assert w.fiducial("r0") == []  # 8.2 m > range_max 8 m
    w.set_pose("m0", 3.5, 0.0, 0.0)
    w.step()
    (f,) = w.fiducial("r0")
    assert f.range == pytest.approx(7.5, abs=1e-6) and f.id == 0  # seen, but beyond range_max_id 5 m
    w.set_pose("m0", 0.0, 0.0, 0.0)
    w.step()
    assert w.fiducial("r0")[0].id == 7
    w.set_pose("m0", -4.0, -1.0, 0.0)  # at -90 degrees: on the edge of the 180-degree field of view
    w.set_pose("r0", -4.0, 0.0, math.radians(10))  # turned 10 degrees away: outside
    w.step()
    assert w.fiducial("r0") == []
    w.set_pose("r0", -4.0, 0.0, math.radians(-10))
    w.step()
    assert [f.name for f in w.fiducial("r0")] == ["m0"]


def test_fiducial_key_separates_finders(tmp_path):
    models = [
        robot("r0", fiducials=[fiducial_finder(key=0)], fiducial_return=1),
        robot("r1", (0.0, 2.0, 0.0), fiducials=[fiducial_finder(key=1)], fiducial_return=2, fiducial_key=1),
        marker("m0", (2.0, 0.5, 0.0), fid=7, key=1),
    ]
    w = world(tmp_path, models)
    w.step()
    assert w.fiducial("r0") == []  # m0 and r1 carry key 1; r0 looks for key 0 and never sees itself
    assert [(f.name, f.id) for f in w.fiducial("r1")] == [("m0", 7)]  # r0 (key 0) is not for r1


# ------------------------------------------------------------------------------------ YAML worlds
def test_yaml_world_with_bumper_and_fiducial_devices(tmp_path):
    from simulator.yamlworld import load_yaml_world

    room_png(tmp_path)
    (tmp_path / "w.yaml").write_text(
        "floorplan: {bitmap: room.png, resolution: 0.05, origin: [-5, -4]}\n"
        "robots:\n"
        "  - name: r0\n"
        "    sonar: false\n"
        "    fiducial_return: 3\n"
        "    devices:\n"
        "      - {type: bumper, model: pioneer}\n"
        "      - {type: bumper, name: whisker, segments: [{pose: [0.3, 0, 90], length: 0.05}]}\n"
        "      - {type: fiducial, range: [0.1, 6], range_id: 4, fov: 120, key: 2, noise: [0.01, 1]}\n"
        "objects:\n"
        "  - {name: m0, type: box, pose: [2, 0, 0], fiducial_return: 9, fiducial_key: 2}\n"
    )
    spec = load_yaml_world(tmp_path / "w.yaml")
    r0 = spec.model("r0")
    assert r0.fiducial_return == 3 and r0.fiducial_key == 0
    ring, whisker = r0.bumpers
    assert len(ring.segments) == 10 and ring.segments[0].pose[0] == pytest.approx(0.5 * r0.size[0] + 0.015)
    assert whisker.name == "whisker" and whisker.segments[0].pose == pytest.approx((0.3, 0.0, math.pi / 2))
    (f,) = r0.fiducials
    assert (f.range_min, f.range_max, f.range_max_id, f.key) == (0.1, 6.0, 4.0, 2)
    assert f.fov == pytest.approx(math.radians(120)) and f.bearing_noise == pytest.approx(math.radians(1))
    assert (spec.model("m0").fiducial_return, spec.model("m0").fiducial_key) == (9, 2)
    w = World(spec)
    w.step()
    assert [(x.name, x.id) for x in w.fiducial("r0")] == [("m0", 9)]
    assert w.describe()["robots"]["r0"]["bumpers"] == [("bumper", 10), ("whisker", 1)]


@pytest.mark.parametrize(
    ("device", "message"),
    [
        ("{type: bumper}", "a bumper needs 'model: pioneer' or 'segments:"),
        ("{type: bumper, segments: []}", "segments is empty"),
        ("{type: bumper, model: pioner}", "did you mean 'pioneer'?"),
        ("{type: bumper, segments: [{pose: [0.2, 0, 0], lenght: 0.1}]}", "did you mean 'length'?"),
        ("{type: fiducial, noise: [-1, 0]}", "noise must not be negative"),
        ("{type: fiducial, key: one}", "key must be an integer"),
    ],
)
def test_yaml_bumper_and_fiducial_errors_name_line_and_fix(tmp_path, device, message, caplog):
    from simulator.errors import WorldFileError
    from simulator.yamlworld import load_yaml_world

    (tmp_path / "w.yaml").write_text(f"robots:\n  - name: r0\n    devices:\n      - {device}\n")
    try:
        load_yaml_world(tmp_path / "w.yaml")
    except WorldFileError as e:
        assert "w.yaml:4" in str(e) and message in str(e)
    else:  # an unknown key is a warning with "did you mean", not an error
        assert any(message in r.getMessage() and "w.yaml:4" in r.getMessage() for r in caplog.records)
