"""Stage ``bumper`` and ``fiducial`` models with Stage 4's meaning (``model_bumper.cc``,
``model_fiducial.cc``): the mapping to :class:`BumperSpec` / :class:`FiducialSpec`, the
``fiducial_return`` / ``fiducial_key`` of any model, errors with file:line, and the simulated
readings judged on the simulator's ground truth. The worlds are written here."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from simulator import WorldFileError
from simulator.spec import FiducialSpec
from simulator.stageworld import load_stage_world
from simulator.world import World

WORLD = """\
interval_sim 100
define mybumper bumper
(
  bcount 3
  blength 0.1
  bpose[0] [ 0.25 0.1 0 0 ]
  bpose[1] [ 0.25 0 0 0 ]
  bpose[2] [ -0.25 0 0 180 ]
  blength[2] 0.2
)
position
(
  name "r0"
  size [ 0.44 0.38 0.22 ]
  odom_error [ 0 0 0 0 ]
  mybumper( pose [ 0.01 0 0 0 ] update_interval 200 )
  fiducial( pose [ 0.1 0 0 0 ] range_max 6 range_max_id 3 fov 90 fiducial_key 2 )
)
model( name "box" pose [ 0.40 0 0 0 ] size [ 0.3 0.3 0.3 ] mass 1000 )
model( name "beacon" pose [ 2 1.2 0 0 ] size [ 0.1 0.1 0.1 ] obstacle_return 0 fiducial_return 4 fiducial_key 2 )
model( name "wrongkey" pose [ 2 -1.2 0 0 ] size [ 0.1 0.1 0.1 ] obstacle_return 0 fiducial_return 5 )
model( name "far" pose [ 3.5 3.0 0 0 ] size [ 0.1 0.1 0.1 ] obstacle_return 0 fiducial_return 6 fiducial_key 2 )
"""


def write(tmp_path: Path, text: str, name: str = "w.world") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_bumper_and_fiducial_map_to_their_specs(tmp_path):
    spec = load_stage_world(write(tmp_path, WORLD))
    assert spec.warnings == []  # nothing is left "not simulated"
    r0 = spec.model("r0")
    (b,) = r0.bumpers
    assert b.pose == pytest.approx((0.01, 0.0, 0.0)) and b.interval == pytest.approx(0.2)
    assert [s.pose for s in b.segments] == [(0.25, 0.1, 0.0), (0.25, 0.0, 0.0), (-0.25, 0.0, pytest.approx(math.pi))]
    assert [s.length for s in b.segments] == pytest.approx([0.1, 0.1, 0.2])  # blength[2] after blength
    (f,) = r0.fiducials
    assert (f.range_min, f.range_max, f.range_max_id, f.key) == (0.0, 6.0, 3.0, 2)
    assert f.fov == pytest.approx(math.pi / 2) and f.pose == pytest.approx((0.1, 0.0, 0.0))
    assert (spec.model("beacon").fiducial_return, spec.model("beacon").fiducial_key) == (4, 2)
    assert (spec.model("wrongkey").fiducial_return, spec.model("wrongkey").fiducial_key) == (5, 0)
    assert spec.model("box").fiducial_return == 0


def test_fiducial_finder_takes_stages_defaults(tmp_path):
    spec = load_stage_world(write(tmp_path, 'position( name "r0" fiducial( ) )\n'))
    (f,) = spec.model("r0").fiducials
    d = FiducialSpec()
    assert (f.range_min, f.range_max, f.range_max_id, f.fov, f.key) == (0.0, 8.0, 5.0, math.pi, 0)
    assert (f.range_max, f.range_max_id, f.fov) == (d.range_max, d.range_max_id, d.fov)


def test_stage3_bpose_and_missing_pieces(tmp_path):
    text = 'position( name "r0" bumper( bcount 2 bpose[0] [ 0.2 0 90 ] bpose[3] [ 0 0 0 0 ] ) bumper( ) )\n'
    p = write(tmp_path, text)
    spec = load_stage_world(p)
    (b,) = spec.model("r0").bumpers  # the second has no bcount: skipped
    assert b.segments[0].pose == pytest.approx((0.2, 0.0, math.pi / 2))  # [x y a]
    assert b.segments[1].pose == (0.0, 0.0, 0.0) and b.segments[0].length == 0.0  # Stage's defaults
    text = "\n".join(spec.warnings)
    assert "bpose[1] is missing" in text and "'bpose[3]' ignored: bcount is 2" in text
    assert "segments of length 0" in text and "set blength" in text
    assert "has no segments; skipped" in text


@pytest.mark.parametrize(
    ("line", "needs"),
    [
        ("bumper( bcount 1 bpose[0] [ 0.2 0 ] )", "[x y z a]"),
        ("bumper( bcount -1 )", "a number of segments >= 1"),
        ("bumper( bcount 1 blength -0.1 )", "a length in metres >= 0"),
        ("fiducial( range_max -1 )", "a range in metres >= 0"),
        ("fiducial( range_min 5 range_max 2 )", "range_min <= range_max"),
        ("fiducial( fov 400 )", "0 < fov <= 360"),
        ("fiducial_return -1", "an integer id >= 0"),
        ('fiducial_key "a"', "an integer id >= 0"),
    ],
)
def test_bad_values_name_the_line_and_a_fix(tmp_path, line, needs):
    p = write(tmp_path, f'position\n(\n  name "r0"\n  {line}\n)\n')
    with pytest.raises(WorldFileError) as e:
        load_stage_world(p)
    assert f"{p}:4" in str(e.value) and needs in str(e.value)


def test_fiducial_keywords_where_they_are_not_simulated_are_reported(tmp_path):
    p = write(tmp_path, 'position( name "r0" fiducial( )\n  ranger( fiducial_return 3 sensor( samples 9 ) ) )\n')
    spec = load_stage_world(p)
    assert spec.warnings == [f"{p}: not simulated (ignored): 'fiducial_return' at {p}:2"]


def test_stage_bumper_and_finder_read_the_ground_truth(tmp_path):
    w = World(load_stage_world(write(tmp_path, WORLD)))
    w.step(1)
    # The box (x 0.25 .. 0.55, y +-0.15) crosses the two front segments (x = 0.26); the rear one is free.
    assert list(w.bumper("r0").pressed) == [1, 1, 0]
    seen = w.fiducial("r0")
    fx, fy = 0.1, 0.0  # the finder on r0 at the origin
    bx, by, _ = w.get_pose("beacon")
    # wrongkey has another fiducial_key; far (4.53 m) is beyond range_max_id 3: seen with id 0 (Stage).
    assert [(f.name, f.id) for f in seen] == [("beacon", 4), ("far", 0)]
    assert seen[0].range == pytest.approx(math.hypot(bx - fx, by - fy), abs=1e-6)
    assert seen[0].bearing == pytest.approx(math.atan2(by - fy, bx - fx), abs=1e-6)
