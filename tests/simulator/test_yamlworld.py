"""YAML world loader (simulator.yamlworld) and the format dispatch of simulator.loader."""

from __future__ import annotations

import logging
import math
import random
import shutil
from pathlib import Path

import pytest
from PIL import Image

from simulator.errors import WorldFileError
from simulator.loader import load_world
from simulator.yamlworld import load_yaml_world

FIXTURES = Path(__file__).parent / "fixtures"
D = math.radians


def png(path: Path, w: int = 200, h: int = 160) -> Path:
    Image.new("L", (w, h), 255).save(path)
    return path


@pytest.fixture
def ydir(tmp_path: Path) -> Path:
    d = tmp_path / "yaml"
    shutil.copytree(FIXTURES / "yaml", d)
    png(d / "testroom.png")
    return d


@pytest.fixture
def spec(ydir: Path):
    return load_yaml_world(ydir / "world.yaml")


def write(tmp_path: Path, text: str, name: str = "w.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def error_of(path: Path) -> WorldFileError:
    with pytest.raises(WorldFileError) as ei:
        load_yaml_world(path)
    return ei.value


# ------------------------------------------------------------------------------ happy path
def test_world_and_floorplan(spec, ydir):
    assert spec.warnings == []
    assert spec.source == str(ydir / "world.yaml")
    assert (spec.interval_sim, spec.speedup, spec.seed) == (0.1, 1.0, 1)
    fp = spec.floorplan
    assert fp is not None and fp.bitmap == (ydir / "testroom.png").absolute()
    assert (fp.resolution, fp.origin, fp.size) == (0.05, (-5.0, -4.0), None)
    assert [m.name for m in spec.models] == ["r0", "r1", "r2", "blob0", "crate"]
    assert [r.name for r in spec.robots()] == ["r0", "r1", "r2"]


def test_robot_r0_from_the_brief(spec, ydir):
    r0 = spec.model("r0")
    assert r0.position and r0.type_name == "pioneer2dx" and r0.color == (255, 0, 0)
    assert r0.pose == pytest.approx((-3.0, 0.0, D(90)))
    assert r0.source == f"{ydir / 'world.yaml'}:5"
    assert [(r.kind, len(r.sensors)) for r in r0.rangers] == [("sonar", 8), ("laser", 1)]
    laser = r0.rangers[1]
    assert laser.pose == (0.13, 0.0, 0.0) and laser.sensors[0].samples == 682
    b = r0.blobfinders[0]
    assert b.colors == [(0, 255, 0)] and b.fov == pytest.approx(D(90)) and b.range_max == 3
    assert b.image == (80, 60)
    assert len(r0.grippers) == 1 and r0.grippers[0].pose == (0.23, 0.0, 0.0)


def test_robot_r1_explicit_devices(spec):
    r1 = spec.model("r1")
    assert r1.type_name == "pioneer3at" and r1.color == (0, 0, 255)
    assert r1.pose == pytest.approx((2.0, 1.0, D(-45)))
    assert r1.max_speed == pytest.approx((0.5, D(60))) and r1.odom_noise == (0.0, 0.0, 0.0)
    laser, bumpers = r1.rangers  # sonar: false dropped the preset's 16-sonar ring
    assert (laser.name, laser.kind) == ("front", "laser")
    s = laser.sensors[0]
    assert (s.samples, s.range_min, s.range_max, s.noise) == (361, 0.05, 8.0, 0.0)
    assert s.fov == pytest.approx(D(180))
    assert (bumpers.name, bumpers.kind, len(bumpers.sensors)) == ("bumpers", "sonar", 2)
    assert bumpers.sensors[0].pose == pytest.approx((-0.3, 0.1, D(180)))
    assert (bumpers.sensors[1].range_min, bumpers.sensors[1].range_max) == (0.0, 1.5)
    assert bumpers.sensors[0].fov == pytest.approx(D(30)) and bumpers.sensors[0].samples == 1


def test_robot_r2_defaults_and_presets(spec):
    r2 = spec.model("r2")
    assert r2.type_name == "pioneer2dx" and r2.pose == (0.0, 0.0, 0.0)  # type defaults to pioneer2dx
    assert [(r.kind, len(r.sensors)) for r in r2.rangers] == [("sonar", 8), ("laser", 1), ("sonar", 16)]
    utm = r2.rangers[1]
    assert utm.pose == (0.2, 0.0, 0.0) and utm.sensors[0].samples == 540 and utm.sensors[0].range_max == 30.0
    g = r2.grippers[0]
    assert (g.pose, g.size, g.paddle_time, g.lift_time) == ((0.3, 0.0, 0.0), (0.12, 0.2), 0.5, 2.0)


def test_objects(spec):
    blob = spec.model("blob0")
    assert not blob.position and blob.type_name == "blob" and blob.pose == (1.0, 2.0, 0.0)
    assert blob.gripper_return and blob.blob_return and not blob.laser_return and not blob.obstacle_return
    crate = spec.model("crate")
    assert crate.type_name == "box" and crate.size == (1.0, 0.5, 0.4) and crate.mass == 8.0
    assert crate.pose == pytest.approx((3.0, -2.0, D(30)))
    assert crate.gripper_return and crate.obstacle_return


def test_seed_override_and_speedup_max(tmp_path):
    p = write(tmp_path, "world: {seed: 3, speedup: max, interval_sim: 0.05}\n")
    spec = load_yaml_world(p)
    assert (spec.seed, spec.speedup, spec.interval_sim) == (3, math.inf, 0.05)
    assert load_yaml_world(p, seed=9).seed == 9
    assert spec.models == [] and spec.floorplan is None


def test_floorplan_stage_placement(tmp_path):
    png(tmp_path / "m.png", 200, 100)
    fp = load_yaml_world(write(tmp_path, "floorplan: {bitmap: m.png, size: [20, 10], pose: [1, 2]}\n")).floorplan
    assert fp is not None and fp.resolution == pytest.approx(0.1) and fp.size == (20.0, 10.0)
    assert fp.origin == pytest.approx((-9.0, -3.0))
    fp = load_yaml_world(write(tmp_path, "floorplan: {bitmap: m.png, resolution: 0.1}\n")).floorplan
    assert fp is not None and fp.origin == pytest.approx((-10.0, -5.0))  # centred on (0, 0)


def test_unknown_keys_warn_with_did_you_mean(tmp_path, caplog):
    text = "robots:\n  - name: r0\n    colr: red\nobjets: []\n"
    with caplog.at_level(logging.WARNING, logger="simulator.yamlworld"):
        spec = load_yaml_world(write(tmp_path, text))
    p = tmp_path / "w.yaml"
    assert len(spec.warnings) == 2
    assert spec.warnings[0].startswith(f"{p}:4: unknown key 'objets'") and "did you mean 'objects'?" in spec.warnings[0]
    assert spec.warnings[1].startswith(f"{p}:3: unknown key 'colr'") and "did you mean 'color'?" in spec.warnings[1]
    assert [r.getMessage() for r in caplog.records] == spec.warnings


def test_duplicate_yaml_key_warns(tmp_path):
    spec = load_yaml_world(write(tmp_path, "world: {seed: 1}\nworld: {seed: 2}\n"))
    assert spec.seed == 2 and len(spec.warnings) == 1 and "duplicate key 'world'" in spec.warnings[0]


# ------------------------------------------------------------------------------ errors
ERRORS = [
    # (content, line, words in the message)
    ("robots:\n  - name: r0\n    pose: foo\n", 3, "robots[0] (r0).pose must be a list of 2 or 3 numbers"),
    ("robots:\n  - type: pioneer2dx\n    pose: [0, 0, 0]\n", 2, "needs 'name'"),
    ("robots:\n  - name: r0\n    type: pioner2dx\n", 3, "did you mean 'pioneer2dx'?"),
    ("robots:\n  - {name: r0}\nobjects:\n  - {name: r0, type: blob}\n", 4, "two models are named 'r0'"),
    ("robots:\n  - name: r0\n    color: chartreuse-ish\n", 3, "unknown colour"),
    ("world:\n  speedup: -2\n", 2, "speedup must be a positive real-time factor or 'max'"),
    ("world:\n  interval_sim: 0\n", 2, "interval_sim must be a positive number"),
    ("world:\n  seed: 1.5\n", 2, "seed must be an integer"),
    ("robots:\n  - name: r0\n    pose: [0, 0\n", 4, "YAML syntax error"),
    ("- a\n- b\n", 1, "the world file must be a mapping"),
    ("", 1, "empty"),
    ("robots: 5\n", 1, "robots must be a list"),
    ("robots:\n  - 5\n", 2, "robots[0] must be a mapping"),
    ("floorplan: {resolution: 0.05}\n", 1, "floorplan needs 'bitmap'"),
    ("floorplan:\n  bitmap: missing.png\n", 2, "'missing.png' not found"),
    ("robots:\n  - name: r0\n    devices:\n      - {type: lidar}\n", 4, "did you mean 'laser'?"),
    (
        "robots:\n  - name: r0\n    devices:\n      - {type: laser, model: urg}\n",
        4,
        "use one of urg04lx, utm30lx",
    ),
    ("robots:\n  - name: r0\n    devices: {type: laser}\n", 3, "devices must be a list"),
    ("robots:\n  - name: r0\n    devices:\n      - {type: sonar}\n", 4, "a sonar needs 'model'"),
    ("robots:\n  - name: r0\n    devices:\n      - type: laser\n        fov: 400\n", 5, "at most 360"),
    ("robots:\n  - name: r0\n    devices:\n      - {type: laser, range: [5, 1]}\n", 4, "0 <= min <= max"),
    (
        "robots:\n  - name: r0\n    devices:\n      - {type: blobfinder, colors: [nope]}\n",
        4,
        "unknown colour",
    ),
    ("objects:\n  - {name: b, pose: [0, 0]}\n", 2, "needs 'type'"),
    ("objects:\n  - {name: b, type: blob, size: [0, 1]}\n", 2, "positive sizes"),
    ("objects:\n  - {name: b, type: blob, mass: -1}\n", 2, "mass must be a number >= 0"),
    ("objects:\n  - {name: b, type: blob, laser_return: maybe}\n", 2, "must be true or false"),
    ("robots:\n  - name: ''\n", 2, "must be a non-empty string"),
    ("robots:\n  - name: r0\n    1: x\n", 3, "key 1 must be a name"),
    ("? [a, b]\n: 1\n", 1, "unhashable key"),
    ("world: !!python/object:os.system {}\n", 1, "YAML value error"),
    ("a: 1\n---\nb: 2\n", 2, "YAML syntax error"),
    ("world: {}\nworld2:\n\tseed: 1\n", 3, "YAML syntax error"),
]


@pytest.mark.parametrize(("text", "line", "words"), ERRORS)
def test_errors(tmp_path, text, line, words):
    p = write(tmp_path, text)
    e = error_of(p)
    assert (e.file, e.line) == (str(p), line), str(e)
    assert words in e.message, e.message
    assert "\n" not in str(e)


def test_floorplan_both_placements_is_an_error(tmp_path):
    png(tmp_path / "m.png")
    p = write(tmp_path, "floorplan:\n  bitmap: m.png\n  size: [10, 8]\n  resolution: 0.05\n")
    e = error_of(p)
    assert e.line == 3 and "either size" in e.message


def test_bitmap_that_is_not_an_image(tmp_path):
    (tmp_path / "m.png").write_text("no image here")
    e = error_of(write(tmp_path, "\nfloorplan: {bitmap: m.png}\n"))
    assert e.line == 2 and "not an image" in e.message


def test_missing_and_binary_files(tmp_path):
    e = error_of(tmp_path / "nope.yaml")
    assert e.file == str(tmp_path / "nope.yaml") and "no such world file" in e.message
    p = tmp_path / "bin.yaml"
    p.write_bytes(b"\xff\xfe\x00garbage")
    assert "UTF-8" in error_of(p).message


def test_fuzz_mutated_yaml(ydir):
    src = (ydir / "world.yaml").read_text()
    p = ydir / "fuzz.yaml"
    rng = random.Random(5)
    alphabet = "{}[]:,-'\"#&*!|> \n\t0123456789.abcdefghijklmnopqrstuvwxyz_"
    for n in range(0, len(src), 7):
        p.write_text(src[:n])
        _load_or_error(p)
    for _ in range(800):
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
    for _ in range(300):
        p.write_bytes(bytes(rng.randrange(256) for _ in range(rng.randrange(200))))
        _load_or_error(p)


def _load_or_error(p: Path) -> None:
    try:
        load_yaml_world(p)
    except WorldFileError as e:
        assert "internal error" not in str(e), str(e)


# ------------------------------------------------------------------------------ simulator.loader
def test_load_world_dispatches_on_suffix(ydir, tmp_path):
    assert [m.name for m in load_world(ydir / "world.yaml").robots()] == ["r0", "r1", "r2"]
    (tmp_path / "w.yml").write_text("robots: [{name: a}]\n")
    assert load_world(tmp_path / "w.yml", seed=4).seed == 4
    (tmp_path / "w.world").write_text('position ( name "s" )\n')
    assert load_world(str(tmp_path / "w.world")).robots()[0].name == "s"
    (tmp_path / "d.inc").write_text('define x model ( )\nx ( name "i" )\n')
    assert load_world(tmp_path / "d.inc").models[0].name == "i"


def test_load_world_errors(tmp_path):
    (tmp_path / "w.txt").write_text("")
    with pytest.raises(WorldFileError, match=r"\.world, \.inc.*\.yaml, \.yml") as ei:
        load_world(tmp_path / "w.txt")
    assert ei.value.file == str(tmp_path / "w.txt")
    with pytest.raises(WorldFileError, match="no such world file") as ei:
        load_world(tmp_path / "missing.world")
    assert ei.value.file == str(tmp_path / "missing.world")
    (tmp_path / "dir.yaml").mkdir()
    with pytest.raises(WorldFileError, match="directory"):
        load_world(tmp_path / "dir.yaml")
