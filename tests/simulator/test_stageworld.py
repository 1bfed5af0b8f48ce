"""Stage ``.world`` loader (simulator.stageworld): includes, defines, mapping to the spec, errors.

The fixtures under ``fixtures/stage/`` follow the thesis appendix (A.1 devices.inc, A.5 urg.inc,
A.6 utm30lx.inc); the bitmaps are generated here with Pillow.
"""

from __future__ import annotations

import logging
import math
import random
import shutil
from pathlib import Path

import pytest
from PIL import Image

from simulator import stageworld
from simulator.errors import WorldFileError
from simulator.stageworld import load_stage_world

FIXTURES = Path(__file__).parent / "fixtures" / "stage"
MAPS = Path(__file__).resolve().parents[2] / "maps"
D = math.radians


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def png(path: Path, w: int = 200, h: int = 100) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("L", (w, h), 255).save(path)
    return path


@pytest.fixture
def stage_dir(tmp_path: Path) -> Path:
    d = tmp_path / "stage"
    shutil.copytree(FIXTURES, d)
    png(d / "testmap.png")
    return d


@pytest.fixture
def tams(stage_dir: Path):
    return load_stage_world(stage_dir / "tams.world")


def error_of(path: Path, **kw) -> WorldFileError:
    with pytest.raises(WorldFileError) as ei:
        load_stage_world(path, **kw)
    return ei.value


# ------------------------------------------------------------------------------ the fixture world
def test_include_chain_and_macros_resolve(tams, stage_dir):
    assert tams.warnings == []
    assert tams.source == str(stage_dir / "tams.world")
    assert [r.name for r in tams.robots()] == ["r0", "r1", "r2", "r3"]
    assert [m.name for m in tams.models if not m.position] == ["blob0", "model:2", "model:3"]
    r0 = tams.model("r0")
    # robot -> fancypioneer2dx -> pioneer2dx -> pioneer_base -> position
    assert r0.type_name == "robot" and r0.position
    assert r0.source == f"{stage_dir / 'tams.world'}:30"
    assert r0.size == (0.44, 0.38, 0.22) and r0.mass == 23.0
    assert r0.color == (255, 0, 0)  # the instance overrides fancypioneer2dx's gray
    assert r0.blob_return is False  # "robot" overrides pioneer_base's blob_return 1
    assert r0.laser_return is True and r0.obstacle_return is True
    assert r0.max_speed == pytest.approx((0.5, D(90)))
    assert r0.max_accel == pytest.approx((0.5, D(90)))
    assert r0.odom_error == (0.03, 0.03, 0.05)


def test_poses_in_degrees(tams):
    assert tams.model("r0").pose == pytest.approx((-3.0, 1.0, D(90)))
    assert tams.model("r1").pose == pytest.approx((2.0, -1.0, D(-45)))
    assert tams.model("r2").pose == pytest.approx((0.0, 0.0, D(180)))  # [x y a]
    assert tams.model("r3").pose == (5.0, 5.0, 0.0)


def test_r0_devices(tams):
    r0 = tams.model("r0")
    assert [(r.kind, len(r.sensors)) for r in r0.rangers] == [("sonar", 8), ("laser", 1)]
    sonar, laser = r0.rangers
    assert sonar.pose == (0.0, 0.0, 0.0)
    assert sonar.sensors[0].pose == pytest.approx((0.069, 0.136, D(90)))
    assert sonar.sensors[7].pose == pytest.approx((0.069, -0.136, D(-90)))
    assert all(s.samples == 1 and s.fov == pytest.approx(D(15)) for s in sonar.sensors)
    assert all((s.range_min, s.range_max) == (0.0, 5.0) for s in sonar.sensors)
    assert laser.pose == (0.13, 0.0, 0.0)
    s = laser.sensors[0]
    assert (s.samples, s.range_min, s.range_max) == (682, 0.02, 5.6)
    assert s.fov == pytest.approx(D(240))
    assert len(r0.blobfinders) == 1
    b = r0.blobfinders[0]
    assert b.colors == [(0, 255, 0)] and b.fov == pytest.approx(D(90)) and b.range_max == 3.0
    assert b.image == (80, 60)
    assert len(r0.grippers) == 1 and r0.grippers[0].pose == (0.23, 0.0, 0.0)
    # auto names as Stage: <type>:<n> per robot
    assert [r.name for r in r0.rangers] == ["ranger:0", "ranger:1"]
    assert (b.name, r0.grippers[0].name) == ("blobfinder:0", "gripper:0")


def test_r1_utm30lx_with_decoration_child(tams):
    r1 = tams.model("r1")
    assert r1.color == (0, 0, 255) and r1.blob_return is True
    assert [r.kind for r in r1.rangers] == ["sonar", "laser"]
    laser = r1.rangers[1]
    assert laser.pose == (0.15, 0.0, 0.0)
    s = laser.sensors[0]
    assert (s.samples, s.range_min, s.range_max) == (1080, 0.1, 30.0)
    assert s.fov == pytest.approx(D(270))
    assert r1.blobfinders == [] and r1.grippers == []


def test_r2_overrides(tams):
    r2 = tams.model("r2")
    b = r2.blobfinders[0]
    assert b.colors == [(255, 0, 0), (0, 0, 255)]  # colors_count 2 of three listed
    assert b.fov == pytest.approx(D(60)) and b.range_max == 5.0
    assert r2.odom_error == (0.01, 0.02, 0.03)
    assert r2.odom_noise == (0.005, 0.005, 0.01)
    assert r2.max_speed == pytest.approx((1.0, D(120)))
    assert [r.kind for r in r2.rangers] == ["sonar"]


def test_r3_stage3_syntax(tams):
    r3 = tams.model("r3")
    assert r3.type_name == "position" and r3.size == (0.5, 0.4, 0.22)
    laser, ring = r3.rangers
    assert laser.kind == "laser" and laser.name == "laser:0" and laser.pose == (0.1, 0.0, 0.0)
    s = laser.sensors[0]
    assert (s.samples, s.range_min, s.range_max) == (361, 0.0, 8.0) and s.fov == pytest.approx(D(180))
    assert ring.kind == "sonar" and len(ring.sensors) == 2
    assert ring.sensors[0].pose == pytest.approx((0.2, 0.1, D(45)))
    assert ring.sensors[1].pose == pytest.approx((0.2, -0.1, D(-45)))
    assert all((x.range_min, x.range_max) == (0.1, 4.0) for x in ring.sensors)
    assert ring.sensors[0].fov == pytest.approx(D(20))
    g = r3.grippers[0]
    assert g.pose == (0.3, 0.0, 0.0) and g.size == (0.15, 0.25)
    assert (g.paddle_time, g.lift_time) == (0.5, 2.0)


def test_blobs(tams):
    blobs = [m for m in tams.models if not m.position]
    for b in blobs:
        assert b.type_name == "blob" and b.size == (0.3, 0.3, 0.0)
        assert b.gripper_return and b.blob_return
        assert not b.laser_return and not b.obstacle_return
    assert blobs[0].pose == (1.0, 2.0, 0.0) and blobs[0].color == (0, 255, 0)
    assert blobs[2].color == (0, 0, 255)  # color_rgba


def test_floorplan_from_size_and_pose(tams, stage_dir):
    fp = tams.floorplan
    assert fp is not None and fp.name == "testmap"
    assert fp.bitmap == (stage_dir / "testmap.png").absolute()
    assert fp.resolution == pytest.approx(20.0 / 200)
    assert fp.origin == pytest.approx((1.0 - 10.0, 2.0 - 5.0))
    assert fp.size == (20.0, 10.0)


def test_clock(tams):
    assert tams.interval_sim == pytest.approx(0.05)
    assert tams.speedup == pytest.approx(2.0)


# ------------------------------------------------------------------------------ world keywords
@pytest.mark.parametrize(
    ("text", "interval", "speedup"),
    [
        ("interval_sim 100\ninterval_real 0\n", 0.1, math.inf),
        ("interval_sim 100\ninterval_real 100\n", 0.1, 1.0),
        ("interval_sim 10\ninterval_real 100\n", 0.01, 0.1),
        ("speedup -1\n", 0.1, math.inf),
        ("speedup 3.5\n", 0.1, 3.5),
        ("", 0.1, 1.0),
    ],
)
def test_world_clock_keywords(tmp_path, text, interval, speedup):
    spec = load_stage_world(write(tmp_path / "w.world", text))
    assert spec.interval_sim == pytest.approx(interval)
    assert spec.speedup == pytest.approx(speedup)
    assert spec.models == [] and spec.floorplan is None  # no robots is fine


def test_stage4_ranger_return_is_a_float_seen_when_not_negative(tmp_path):
    text = "".join(f'model ( name "{n}" ranger_return {v} )\n' for n, v in (("a", 0.5), ("b", 0), ("c", -1), ("d", 1)))
    spec = load_stage_world(write(tmp_path / "w.world", text))
    assert not spec.warnings
    seen = {n: spec.model(n).laser_return for n in "abcd"}
    assert seen == {"a": True, "b": True, "c": False, "d": True}


def test_the_return_flag_set_last_wins(tmp_path):
    p = write(
        tmp_path / "w.world",
        'model ( name "a" laser_return 0 ranger_return 0.5 )\nmodel ( name "b" ranger_return 1 laser_return 0 )\n',
    )
    spec = load_stage_world(p)
    assert spec.model("a").laser_return is True and spec.model("b").laser_return is False


def test_stage3_laser_return_levels(tmp_path):
    p = write(tmp_path / "w.world", 'model ( name "a" laser_return 2 )\nmodel ( name "b" laser_return 0 )\n')
    spec = load_stage_world(p)
    assert spec.model("a").laser_return is True and spec.model("b").laser_return is False


def test_seed(tmp_path):
    p = write(tmp_path / "w.world", "seed 42\n")
    assert load_stage_world(p).seed == 42
    assert load_stage_world(p, seed=7).seed == 7


def test_threads_sets_the_ray_casting_threads_as_stage_counts_them(tmp_path):
    # Stage: ``threads N`` worker threads, 0 none (the stepping thread alone); absent: every core here.
    assert load_stage_world(write(tmp_path / "a.world", 'name "a"\n')).threads is None
    assert load_stage_world(write(tmp_path / "b.world", "threads 0\n")).threads == 1
    assert load_stage_world(write(tmp_path / "c.world", "threads 3\n")).threads == 3
    with pytest.raises(WorldFileError, match=r"d\.world:1.*threads 1"):
        load_stage_world(write(tmp_path / "d.world", "threads -2\n"))


def test_known_stage_keywords_are_silent(tmp_path):
    p = write(
        tmp_path / "w.world",
        """
name "quiet" quit_time 10 threads 2 show_clock 1 show_clock_interval 100 resolution 0.02 paused 1
window ( size [ 600 600 ] scale 30 center [ 0 0 ] rotate [ 0 0 ] show_data 1 anything [ 1 ] )
position
(
  name "r0" gui_nose 1 gui_grid 0 gui_move 1 gui_outline 0 gui_boundary 1 boundary 1 watts 2
  fiducial_return 1 stack_children 1 ctrl "wander" localization "gps" localization_origin [ 0 0 0 0 ]
  update_interval 100 ranger_return 1 block ( points 3 point[0] [ 0 0 ] point[1] [ 1 0 ] z [ 0 1 ] )
  ranger ( sensor ( samples 3 ranger_return 1 watts 1 ) obstacle_return 0 laser_return 0 gui_nose 0 )
  blobfinder ( obstacle_return 0 pan 0 )
  gripper ( paddle_size [ 0.66 0.1 0.4 ] paddle_state "open" lift_state "down" autosnatch 0 )
)
""",
    )
    spec = load_stage_world(p)
    # No "unknown keyword" warning; what is known but not simulated is named in one warning.
    nosim = ", ".join(
        f"'{k}' at {p}:{line}"
        for k, line in [("paused", 2), ("boundary", 6), ("stack_children", 7), ("paddle_size", 11),
                        ("paddle_state", 11), ("lift_state", 11)]
    )  # fmt: skip
    assert spec.warnings == [f"{p}: not simulated (ignored): {nosim}"]
    r0 = spec.model("r0")
    assert [r.kind for r in r0.rangers] == ["laser"] and len(r0.blobfinders) == len(r0.grippers) == 1
    assert r0.ctrl == "wander" and r0.localization == "gps"


def test_unknown_keyword_warns_once_per_keyword_and_file(tmp_path, caplog):
    write(tmp_path / "bot.inc", 'define bot position\n(\n  colr "red"\n)\n')
    p = write(
        tmp_path / "w.world",
        """include "bot.inc"
define bot2 bot
(
  laser_retrun 1
)
bot2( name "r0" )
bot2( name "r1" )
bot2( name "r2" colr "red" )
bot2( name "r3" colr "blue" )
""",
    )
    with caplog.at_level(logging.WARNING, logger="simulator.stageworld"):
        spec = load_stage_world(p)
    inc, world = tmp_path / "bot.inc", tmp_path / "w.world"
    assert len(spec.warnings) == 3, spec.warnings
    assert spec.warnings[0].startswith(f"{inc}:3: unknown keyword 'colr'")
    assert "did you mean 'color'?" in spec.warnings[0]
    assert spec.warnings[1].startswith(f"{world}:4: unknown keyword 'laser_retrun'")
    assert "did you mean 'laser_return'?" in spec.warnings[1]
    assert spec.warnings[2].startswith(f"{world}:8: unknown keyword 'colr'")
    assert [r.getMessage() for r in caplog.records] == spec.warnings
    assert len(spec.robots()) == 4


def test_unknown_world_keyword_warns(tmp_path):
    spec = load_stage_world(write(tmp_path / "w.world", "\ninterval_simm 50\n"))
    assert spec.warnings == [f"{tmp_path / 'w.world'}:2: unknown world keyword 'interval_simm' ignored; "
                             "did you mean 'interval_sim'?"]  # fmt: skip
    assert spec.interval_sim == 0.1


def test_not_simulated_devices_warn(tmp_path):
    text = 'position\n(\n  name "r0"\n  camera ( )\n  ptz ( )\n  actuator ( )\n)\n'
    p = write(tmp_path / "w.world", text)
    spec = load_stage_world(p)
    # One warning names every model type that is not simulated, each with its line (fiducial
    # finders and bumpers are simulated: tests/simulator/test_stage_bumper_fiducial.py).
    assert spec.warnings == [
        f"{p}: not simulated (ignored): model type 'camera' at {p}:4, model type 'ptz' at {p}:5, "
        f"model type 'actuator' at {p}:6"
    ]
    assert len(spec.robots()) == 1


def test_drive_other_than_diff_warns(tmp_path):
    spec = load_stage_world(write(tmp_path / "w.world", 'position ( name "r0" drive "omni" )\n'))
    assert len(spec.warnings) == 1 and "drive 'omni' is not simulated" in spec.warnings[0]
    assert spec.model("r0").drive == "diff"


def test_devices_on_a_decoration_are_found_with_composed_pose(tmp_path):
    p = write(
        tmp_path / "w.world",
        'position ( name "r0" model ( pose [ 0.1 0 0 90 ]\n  ranger ( pose [ 0.1 0 0 0 ] sensor ( samples 10 ) ) ) )\n',
    )
    r = load_stage_world(p).model("r0").rangers[0]
    assert r.kind == "laser" and r.pose == pytest.approx((0.1, 0.1, D(90)))


def test_unnamed_models_are_numbered_per_type(tmp_path):
    p = write(tmp_path / "w.world", 'model ( )\nposition ( )\nmodel ( name "box" )\nmodel ( )\nposition ( )\n')
    names = [m.name for m in load_stage_world(p).models]
    assert names == ["model:0", "position:0", "box", "model:2", "position:1"]


# ------------------------------------------------------------------------------ includes
def test_stagepath(monkeypatch):
    world = FIXTURES / "uses_stagepath.world"
    monkeypatch.setenv("STAGEPATH", f"/nonexistent/dir:{FIXTURES / 'extra'}")
    spec = load_stage_world(world)
    assert spec.model("c0").size == (0.5, 0.5, 0.5) and spec.model("c0").color == (165, 42, 42)
    monkeypatch.delenv("STAGEPATH")
    e = error_of(world)
    assert (e.file, e.line) == (str(world), 2)
    assert "stagepath_only.inc" in e.message and "STAGEPATH" in e.message


def test_project_include_dir_is_searched_last(tmp_path, monkeypatch):
    write(tmp_path / "lib" / "crate.inc", "define crate model ( mass 7 )\n")
    write(tmp_path / "local" / "crate.inc", "define crate model ( mass 3 )\n")
    monkeypatch.delenv("STAGEPATH", raising=False)
    monkeypatch.setattr(stageworld, "INCLUDE_DIR", tmp_path / "lib")
    p = write(tmp_path / "w.world", 'include "crate.inc"\ncrate( name "c" )\n')
    assert load_stage_world(p).model("c").mass == 7.0
    q = write(tmp_path / "local" / "w.world", 'include "crate.inc"\ncrate( name "c" )\n')
    assert load_stage_world(q).model("c").mass == 3.0  # the including file's directory first


def test_default_include_dir_is_the_projects_maps_include():
    assert stageworld.INCLUDE_DIR == MAPS / "include"


def test_bitmap_is_relative_to_the_file_that_sets_it(tmp_path):
    png(tmp_path / "sub" / "m.png", 100, 50)
    write(tmp_path / "sub" / "map.inc", 'define mymap model\n(\n  bitmap "m.png"\n)\n')
    p = write(tmp_path / "w.world", 'include "sub/map.inc"\nmymap( size [ 10 5 ] pose [ 0 0 0 0 ] )\n')
    fp = load_stage_world(p).floorplan
    assert fp is not None and fp.bitmap == (tmp_path / "sub" / "m.png").absolute()
    assert fp.resolution == pytest.approx(0.1) and fp.origin == pytest.approx((-5.0, -2.5))
    assert fp.name == "model:0"


def test_floorplan_without_size_uses_mapfile_placement(tmp_path):
    png(tmp_path / "m.png", 200, 100)
    text = 'define floorplan model ( )\nfloorplan ( name "a" bitmap "m.png" map_resolution 0.1 '
    text += "origin [ -3 -4 ] )\n"
    fp = load_stage_world(write(tmp_path / "a.world", text)).floorplan
    assert fp is not None and (fp.resolution, fp.origin, fp.size) == (0.1, (-3.0, -4.0), None)
    text = 'define floorplan model ( )\nfloorplan ( bitmap "m.png" pose [ 1 1 0 0 ] )\n'
    fp = load_stage_world(write(tmp_path / "b.world", text)).floorplan
    assert fp is not None and fp.resolution == 0.05
    assert fp.origin == pytest.approx((1 - 5.0, 1 - 2.5))  # centred on the pose


def test_second_floorplan_is_skipped_with_a_warning(tmp_path):
    png(tmp_path / "m.png")
    text = 'model ( name "a" bitmap "m.png" size [ 2 1 ] )\nmodel ( name "b" bitmap "m.png" )\n'
    p = write(tmp_path / "w.world", text)
    spec = load_stage_world(p)
    assert spec.floorplan is not None and spec.floorplan.name == "a" and spec.models == []
    assert len(spec.warnings) == 1 and spec.warnings[0].startswith(f"{p}:2: second floorplan 'b'")


# ------------------------------------------------------------------------------ malformed files
MALFORMED = [
    # (content, line, words in the message)
    ('position\n(\n  name "r0"\n', 2, "never closed"),
    ('model ( name "a" )\n)\n', 2, "unmatched ')'"),
    ("model\n(\n  pose [ 1 2 0 0\n)\n", 3, "'[' of 'pose' is never closed"),
    ("\n]\n", 2, "unmatched ']'"),
    ('model\n(\n  name "r0 )\n', 3, "string never closed"),
    ('model\n(\n  size "abc"\n)\n', 3, "'size' needs [x y z]"),
    ("model ( size [ 1 2 3 ] )\nmodel ( pose [ 1 ] )\n", 2, "'pose' needs"),
    ("\ndefine thing gizmo ( )\n", 2, "unknown base type 'gizmo'"),
    ('\n\nposiiton ( name "r0" )\n', 3, "did you mean 'position'?"),
    ("model ( name )\n", 1, "has no value"),
    ("pose\n", 1, "has no value"),
    ("model ( mass 5m )\n", 1, "malformed number '5m'"),
    ('model\n(\n  include "x.inc"\n)\n', 3, "only allowed at the top level"),
    ("define loop model ( loop() )\nloop()\n", 1, "contains itself"),
    ("model (" * 100, 1, "nested more than"),
    ("define ( )\n", 1, "define needs a new type name"),
    ("define thing\n", 1, "needs a base type"),
    ('model ( name "a" )\nmodel ( name "a" )\n', 2, "two models are named 'a'"),
    ('position ( blobfinder (\n colors_count 3 colors [ "red" ] ) )\n', 2, "colors_count' is 3"),
    ("include nothing\n", 1, "include needs a quoted file name"),
    ("interval_sim -5\n", 1, "positive number of milliseconds"),
    ("5 model ( )\n", 1, "expected a keyword"),
    ('model ( color_rgba [ 1 "x" 0 ] )\n', 1, "'color_rgba' needs"),
    ("position ( ranger ( sensor ( range [ 5 1 ] ) ) )\n", 1, "0 <= min <= max"),
    ("position ( laser (\n samples 1.5 ) )\n", 2, "'samples' needs an integer"),
    ("position ( ranger ( sensor ( fov 400 ) ) )\n", 1, "'fov' needs"),
    ("model ( size [ -1 1 1 ] )\n", 1, "positive sizes"),
    ("define model model ( )\n", 1, "built-in type"),
    ("model ( pose [ 1 [ 2 ] ] )\n", 1, "never closed"),
    ("model ( é )\n", 1, "unexpected character"),
    ("model ( obstacle_return 2 )\n", 1, "0 or 1"),
    ("seed 1.5\n", 1, "'seed' needs an integer"),
]


@pytest.mark.parametrize(("text", "line", "words"), MALFORMED)
def test_malformed(tmp_path, text, line, words):
    p = write(tmp_path / "bad.world", text)
    e = error_of(p)
    assert (e.file, e.line) == (str(p), line), str(e)
    assert words in e.message
    assert str(e).startswith(f"{p}:{line}: ")
    assert "\n" not in str(e)


def test_missing_bitmap(tmp_path):
    p = write(tmp_path / "w.world", 'define floorplan model ( )\nfloorplan\n(\n  bitmap "missing.png"\n)\n')
    e = error_of(p)
    assert (e.file, e.line) == (str(p), 4) and "'missing.png' not found" in e.message


def test_bitmap_that_is_not_an_image(tmp_path):
    write(tmp_path / "notimage.png", "this is text")
    p = write(tmp_path / "w.world", 'model\n(\n  size [ 1 1 ]\n  bitmap "notimage.png"\n)\n')
    e = error_of(p)
    assert (e.file, e.line) == (str(p), 4) and "not an image" in e.message


def test_missing_include_names_the_including_file(tmp_path):
    write(tmp_path / "a.inc", '# a\n\ninclude "nope.inc"\n')
    p = write(tmp_path / "w.world", 'include "a.inc"\n')
    e = error_of(p)
    assert (e.file, e.line) == (str(tmp_path / "a.inc"), 3)
    assert "cannot find include file 'nope.inc'" in e.message


def test_include_cycle(tmp_path):
    write(tmp_path / "a.inc", '# a\ninclude "b.inc"\n')
    write(tmp_path / "b.inc", 'include "a.inc"\n')
    p = write(tmp_path / "w.world", 'include "a.inc"\n')
    e = error_of(p)
    assert (e.file, e.line) == (str(tmp_path / "b.inc"), 1)
    assert "include cycle" in e.message and "a.inc -> " in e.message
    # a world including itself
    q = write(tmp_path / "self.world", '\ninclude "self.world"\n')
    e = error_of(q)
    assert (e.file, e.line) == (str(q), 2) and "include cycle" in e.message


def test_errors_inside_included_defines_name_the_include(tmp_path):
    write(tmp_path / "bot.inc", "define bot position\n(\n  lazer( )\n)\n")
    e = error_of(write(tmp_path / "w.world", 'include "bot.inc"\nbot( name "r0" )\n'))
    assert (e.file, e.line) == (str(tmp_path / "bot.inc"), 3)
    assert "unknown model type 'lazer'" in e.message and "did you mean 'laser'?" in e.message
    write(tmp_path / "box.inc", 'define box model\n(\n  size "abc"\n)\n')
    e = error_of(write(tmp_path / "v.world", 'include "box.inc"\nbox( )\n'))
    assert (e.file, e.line) == (str(tmp_path / "box.inc"), 3)


def test_missing_world_file(tmp_path):
    e = error_of(tmp_path / "nope.world")
    assert e.file == str(tmp_path / "nope.world") and "no such world file" in e.message
    e = error_of(tmp_path)
    assert e.file == str(tmp_path) and "cannot read" in e.message


# ------------------------------------------------------------------------------ fuzzing
def _load_or_error(path: Path) -> None:
    try:
        load_stage_world(path)
    except WorldFileError as e:
        assert "internal error" not in str(e), str(e)
        assert e.file


def test_fuzz_random_bytes(tmp_path):
    rng = random.Random(1)
    p = tmp_path / "f.world"
    for _ in range(400):
        p.write_bytes(bytes(rng.randrange(256) for _ in range(rng.randrange(200))))
        _load_or_error(p)


VOCAB = [
    "(", ")", "[", "]", '"', '"x"', '"m.png"', '"f.world"', "define", "include", "model", "position",
    "ranger", "sensor", "laser", "blobfinder", "gripper", "camera", "window", "block", "blob", "name",
    "pose", "size", "bitmap", "colors", "colors_count", "color", "scount", "spose[0]", "sview", "range",
    "fov", "samples", "interval_sim", "interval_real", "speedup", "seed", "1", "0", "-2.5", "1e999",
    "360", "90", "x", "\n", "# c\n", "foo", "drive", '"diff"', "velocity_bounds", "image", "ptz",
]  # fmt: skip


def test_fuzz_token_soup(tmp_path):
    rng = random.Random(2)
    png(tmp_path / "m.png", 20, 10)
    p = tmp_path / "f.world"
    for _ in range(1500):
        p.write_text(" ".join(rng.choice(VOCAB) for _ in range(rng.randrange(60))))
        _load_or_error(p)


FUZZ_KEYS = [
    "name", "pose", "size", "color", "color_rgba", "mass", "obstacle_return", "laser_return", "ranger_return",
    "blob_return", "gripper_return", "drive", "velocity_bounds", "acceleration_bounds", "odom_error",
    "odom_noise", "bitmap", "map_resolution", "origin", "range", "range_min", "range_max", "fov", "samples",
    "noise", "scount", "spose[0]", "spose[1]", "sview", "colors", "channels", "colors_count", "image", "ptz",
    "paddle_time", "lift_time", "update_interval", "interval_sim", "interval_real", "speedup", "seed",
    "resolution", "threads", "paused", "gui_nose", "nonsense",
]  # fmt: skip
FUZZ_TYPES = ["model", "position", "ranger", "sensor", "laser", "blobfinder", "gripper", "camera", "window",
              "block", "thing", "other"]  # fmt: skip
FUZZ_ATOMS = ["-1", "0", "1", "2", "0.5", "90", "1e9", "400", "1.5", "-0.0", '"m.png"', '"nope.png"', '"red"',
              '"diff"', '"x"', '""', '"r0"', "green"]  # fmt: skip


def _fuzz_value(rng: random.Random) -> str:
    if rng.random() < 0.4:
        return rng.choice(FUZZ_ATOMS)
    return "[ " + " ".join(rng.choice(FUZZ_ATOMS[:10]) for _ in range(rng.randrange(10))) + " ]"


def _fuzz_body(rng: random.Random, depth: int) -> str:
    nprops = rng.randrange(5) if depth or rng.random() < 0.2 else 0  # few world keywords
    parts = [f"{rng.choice(FUZZ_KEYS)} {_fuzz_value(rng)}" for _ in range(nprops)]
    if depth < 3:
        parts += [f"{rng.choice(FUZZ_TYPES)} ( {_fuzz_body(rng, depth + 1)} )" for _ in range(rng.randrange(4))]
    rng.shuffle(parts)
    return "\n".join(parts)


def test_fuzz_structured(tmp_path):
    """Syntactically valid worlds with random types, keys and values: only WorldFileError escapes."""
    rng = random.Random(4)
    png(tmp_path / "m.png", 20, 10)
    p = tmp_path / "f.world"
    loaded = 0
    for _ in range(1500):
        defines = [
            f"define {name} {rng.choice(FUZZ_TYPES[:7])} ( {_fuzz_body(rng, 1)} )"
            for name in ("thing", "other")
            if rng.random() < 0.8
        ]
        top = [_fuzz_body(rng, 0) for _ in range(rng.randrange(1, 4))]
        p.write_text("\n".join(defines + top))
        try:
            load_stage_world(p)
            loaded += 1
        except WorldFileError as e:
            assert "internal error" not in str(e), str(e)
    assert loaded > 100  # the generator reaches the conversion code, not only the parser


def test_fuzz_truncated_and_mutated_fixture(stage_dir):
    src = (stage_dir / "tams.world").read_text()
    p = stage_dir / "fuzz.world"
    for n in range(0, len(src), 5):
        p.write_text(src[:n])
        _load_or_error(p)
    rng = random.Random(3)
    alphabet = '()[]"# \n0123456789.-abcdefghijklmnopqrstuvwxyz_'
    for _ in range(600):
        chars = list(src)
        for _ in range(rng.randrange(1, 6)):
            i = rng.randrange(len(chars))
            op = rng.randrange(3)
            if op == 0:
                del chars[i]
            elif op == 1:
                chars.insert(i, rng.choice(alphabet))
            else:
                chars[i] = rng.choice(alphabet)
        p.write_text("".join(chars))
        _load_or_error(p)


# ------------------------------------------------------------------------------ the project's maps
@pytest.mark.parametrize("name", ["testroom.world", "floor.world", "arena.world"])
def test_project_worlds_load(name):
    path = MAPS / name
    if not path.exists():
        pytest.skip(f"{path} not present")
    spec = load_stage_world(path)
    assert spec.warnings == []
    assert spec.floorplan is not None and spec.floorplan.bitmap.exists()
    assert spec.robots() and all(r.rangers for r in spec.robots())
