"""Map tools (rsal.mapping.tools, rsal.mapping.toolcli): a world file as a map_server map matches
the true bitmap; ``align`` recovers a known rigid transform with its residual; bad inputs are one
line each with the documented exit code."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rsal.mapping.mapyaml import read_map, write_map
from rsal.mapping.toolcli import main
from rsal.mapping.tools import Alignment, Grid, align, resample

MAPS = Path(__file__).resolve().parents[2] / "maps"


def _true_walls(png: str) -> np.ndarray:
    """The shipped bitmap's walls (0 = occupied, 255 = free), row 0 = top."""
    return np.asarray(Image.open(MAPS / png).convert("L")) < 128


def _run(capsys, argv: list[str]) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


# ------------------------------------------------------------------------------ --from-world
@pytest.mark.parametrize("world, png, origin", [("testroom.world", "testroom.png", (-5.0, -4.0)),
                                                ("floor.world", "floor.png", (-31.475, -7.8))])  # fmt: skip
def test_from_world_at_the_bitmap_resolution_is_the_bitmap(tmp_path, capsys, world, png, origin):
    code, out, err = _run(
        capsys, ["--from-world", str(MAPS / world), "-o", str(tmp_path / "m"), "--resolution", "0.05"]
    )
    assert code == 0, err
    m = read_map(tmp_path / "m.yaml")
    truth = _true_walls(png)
    assert m.occupancy.shape == truth.shape and m.resolution == 0.05
    assert m.origin == pytest.approx((*origin, 0.0))
    np.testing.assert_array_equal(m.occupied, truth)
    np.testing.assert_array_equal(m.free, ~truth)  # free everywhere inside the world's extent
    assert re.fullmatch(r"map=\S+m\.yaml width=\d+ height=\d+ resolution=0\.05 .* occupied=0\.\d{4}\n", out)
    assert "static model" in err and "wrote" in err  # progress on stderr


def test_from_world_coarser_keeps_every_wall(tmp_path, capsys):
    assert main(["--from-world", str(MAPS / "floor.world"), "-o", str(tmp_path / "c"), "--resolution", "0.1"]) == 0
    m = read_map(tmp_path / "c.yaml")
    truth = _true_walls("floor.png")  # 400 x 1200 at 0.05: each 0.1 m cell is 2 x 2 pixels
    pooled = truth.reshape(200, 2, 600, 2).any(axis=(1, 3))
    assert m.resolution == 0.1 and m.origin[:2] == pytest.approx((-31.475, -7.8))
    np.testing.assert_array_equal(m.occupied, pooled)


def test_from_world_rasterises_static_models_lasers_see(tmp_path, capsys):
    (tmp_path / "w.yaml").write_text(
        "objects:\n"
        "  - {name: crate, type: box, pose: [1.0, 2.0, 0], size: [1.0, 0.5, 0.5]}\n"
        "  - {name: b0, type: blob, pose: [4.0, 4.0, 0]}\n"  # lasers pass through blobs
    )
    assert main(["--from-world", str(tmp_path / "w.yaml"), "-o", str(tmp_path / "o"), "--resolution", "0.1"]) == 0
    m = read_map(tmp_path / "o.yaml")
    rows, cols = np.nonzero(m.occupied)
    x = m.origin[0] + (cols + 0.5) * m.resolution
    y = m.origin[1] + (m.height - rows - 0.5) * m.resolution
    assert len(x) == 50  # 10 x 5 cells of 0.1 m
    assert x.min() == pytest.approx(0.55) and x.max() == pytest.approx(1.45)
    assert y.min() == pytest.approx(1.80) and y.max() == pytest.approx(2.20)
    assert main(["--from-world", str(tmp_path / "w.yaml"), "-o", str(tmp_path / "p"), "--no-models"]) == 1
    assert "nothing to map" in capsys.readouterr().err


# ------------------------------------------------------------------------------------- align
def _plan() -> Grid:
    m = read_map(MAPS / "testroom.yaml")
    return Grid(m.occupancy.astype(float), m.resolution, m.origin[:2])


def _seen_from(plan: Grid, yaw: float, tx: float, ty: float) -> Grid:
    """The plan as a map built in another frame, ``plan = R(yaw) built + t`` (resampled, so its
    cells do not line up with the plan's)."""
    c, s = math.cos(yaw), math.sin(yaw)
    inv_t = -np.array([[c, s], [-s, c]]) @ np.array([tx, ty])
    return resample(plan, Alignment(float(inv_t[0]), float(inv_t[1]), -yaw, 0.0, 0.0, 0, 0))


@pytest.mark.parametrize("yaw_deg, tx, ty", [(10.0, 0.7, -0.4), (-123.0, -1.3, 2.1)])
def test_align_recovers_a_known_rigid_transform(yaw_deg, tx, ty):
    plan = _plan()
    built = _seen_from(plan, math.radians(yaw_deg), tx, ty)
    a = align(built, plan)
    assert abs(math.degrees(math.remainder(a.yaw - math.radians(yaw_deg), math.tau))) < 1.0
    assert math.hypot(a.x - tx, a.y - ty) < 0.05
    assert a.residual < 0.05 and a.inliers > 0.95  # nearest-cell resampling: within a cell


def test_align_cli_reports_and_writes_the_aligned_map(tmp_path, capsys):
    plan = _plan()
    built = _seen_from(plan, math.radians(25.0), 0.4, 0.9)
    write_map(tmp_path / "built", built.occupancy, built.resolution, built.origin)
    code, out, err = _run(capsys, ["align", str(tmp_path / "built.yaml"), str(MAPS / "testroom.yaml"),
                                   "-o", str(tmp_path / "aligned")])  # fmt: skip
    assert code == 0, err
    f = dict(kv.split("=") for kv in out.split())
    assert abs(float(f["yaw_deg"]) - 25.0) < 1.0 and math.hypot(float(f["x"]) - 0.4, float(f["y"]) - 0.9) < 0.05
    assert float(f["residual"]) < 0.05 and float(f["within_0.10m"]) > 0.95
    assert "coarse search" in err and "wrote the aligned map" in err
    # the written map lies on the plan: its walls within a cell of the plan's walls
    m = read_map(tmp_path / "aligned.yaml")
    assert m.origin[2] == 0.0 and m.resolution == plan.resolution
    moved = Grid(m.occupancy.astype(float), m.resolution, m.origin[:2]).wall_points()
    from scipy.spatial import cKDTree

    d, _ = cKDTree(plan.wall_points()).query(moved)
    assert len(moved) > 1000 and (d <= 0.0501).mean() > 0.95


def test_align_with_a_png_plan_placed_by_flags(tmp_path, capsys):
    plan = _plan()
    built = _seen_from(plan, math.radians(-40.0), -0.5, 0.3)
    write_map(tmp_path / "b", built.occupancy, built.resolution, built.origin)
    argv = ["align", str(tmp_path / "b.yaml"), str(MAPS / "testroom.png"), "--plan-origin", "-5", "-4"]
    code, out, err = _run(capsys, argv)
    assert code == 0, err
    f = dict(kv.split("=") for kv in out.split())
    assert abs(float(f["yaw_deg"]) + 40.0) < 1.0 and math.hypot(float(f["x"]) + 0.5, float(f["y"]) - 0.3) < 0.05


# ---------------------------------------------------------------------------------- bad input
def _bad_inputs(tmp: Path) -> list[tuple[list[str], int, str]]:
    write_map(tmp / "ok", np.zeros((4, 4)), 0.05, (0, 0))  # no walls
    (tmp / "junk.png").write_text("not an image")
    return [
        ([], 2, "expected 'align BUILT.yaml PLAN' or '--from-world WORLD -o maps/NAME'"),
        (["--from-world", str(MAPS / "testroom.world")], 2, "the following arguments are required: -o/--output"),
        (["--from-world", str(MAPS / "testroom.world"), "-o", "x", "--resolution", "fine"], 2, "invalid float value"),
        (["--from-world", str(tmp / "none.world"), "-o", str(tmp / "x")], 1, "no such world file"),
        (["--from-world", str(MAPS / "testroom.world"), "-o", str(tmp / "x"), "--resolution", "-1"], 1,
         "--resolution -1.0 must be a positive"),
        (["--from-world", str(MAPS / "testroom.world"), "-o", str(MAPS / "testroom")], 1,
         "would overwrite the world's own floorplan"),
        (["align", str(tmp / "none.yaml"), str(MAPS / "testroom.yaml")], 1, "no such map file"),
        (["align", str(MAPS / "testroom.png"), str(MAPS / "testroom.yaml")], 1, "the built map must be a map_server"),
        (["align", str(tmp / "ok.yaml"), str(MAPS / "testroom.yaml")], 1, "the built map has 0 occupied cells"),
        (["align", str(MAPS / "testroom.yaml"), str(tmp / "junk.png")], 1, "not a readable image"),
        (["align", str(MAPS / "testroom.yaml"), str(MAPS / "floor.yaml"), "--plan-origin", "0", "0"], 1,
         "a map_server YAML places itself"),
        (["align", str(MAPS / "testroom.yaml")], 2, "the following arguments are required: PLAN"),
        (["align", str(MAPS / "testroom.yaml"), str(MAPS / "floor.yaml"), "--yaw-step", "0"], 2, "--yaw-step"),
    ]  # fmt: skip


def test_bad_inputs_are_one_line_with_an_exit_code(tmp_path, capsys):
    for argv, code, words in _bad_inputs(tmp_path):
        got, out, err = _run(capsys, argv)
        assert (got, out) == (code, ""), (argv, got, err)
        assert err.count("\n") == 1 and err.startswith("rsal map") and words in err, (argv, err)
    assert not (MAPS / "testroom.png.tmp").exists()


def test_a_from_world_map_is_a_floorplan_the_simulator_loads_as_the_original(tmp_path):
    """--from-world, then a world whose floorplan is that YAML: the same walls where the original is."""
    from simulator.gridmap import GridMap
    from simulator.loader import load_world

    assert main(["--from-world", str(MAPS / "testroom.world"), "-o", str(tmp_path / "tr")]) == 0
    (tmp_path / "w.world").write_text('define floorplan model ( )\nfloorplan ( bitmap "tr.yaml" )\n')
    a = GridMap.from_floorplan(load_world(MAPS / "testroom.world").floorplan)
    b = GridMap.from_floorplan(load_world(tmp_path / "w.world").floorplan)
    assert (b.width, b.height, b.resolution) == (a.width, a.height, a.resolution)
    assert b.origin == pytest.approx(a.origin)
    np.testing.assert_array_equal(b.occupied, a.occupied)


def test_help_returns_zero_instead_of_exiting(capsys):
    assert main(["align", "--help"]) == 0
    assert "rsal map align" in capsys.readouterr().out
    assert main(["--from-world", "w.world", "--help"]) == 0
    assert "--resolution" in capsys.readouterr().out


def test_align_copes_with_a_partial_noisy_built_map():
    """A tour that saw half of the room, missed 30 % of the wall cells it passed and added 1 % clutter."""
    plan = _plan()
    built = _seen_from(plan, math.radians(-75.0), 0.3, 0.2)
    occ = built.occupancy.copy()
    rng = np.random.default_rng(1)
    occ[:, int(occ.shape[1] * 0.55) :] = -1.0  # never seen
    occ[(occ >= 0.5) & (rng.random(occ.shape) < 0.3)] = 0.0
    occ[(occ == 0.0) & (rng.random(occ.shape) < 0.01)] = 1.0
    a = align(Grid(occ, built.resolution, built.origin), plan)
    assert abs(math.degrees(math.remainder(a.yaw + math.radians(75.0), math.tau))) < 1.0
    assert math.hypot(a.x - 0.3, a.y - 0.2) < 0.05
    assert 0.8 < a.inliers < 0.95 and a.residual > 0.05  # the clutter shows in the residual


def test_align_takes_a_map_with_an_origin_yaw_and_writes_it_axis_aligned(tmp_path, capsys):
    """map_server's origin yaw turns the whole image about its lower-left corner; -o undoes it."""
    m = read_map(MAPS / "testroom.yaml")
    write_map(tmp_path / "turned", m.occupancy, m.resolution, (1.0, 2.0, 0.5))
    argv = ["align", str(tmp_path / "turned.yaml"), str(MAPS / "testroom.yaml"), "-o", str(tmp_path / "fixed")]
    code, out, err = _run(capsys, argv)
    assert code == 0, err
    f = dict(kv.split("=") for kv in out.split())
    c, s = math.cos(-0.5), math.sin(-0.5)
    want = np.array([-5.0, -4.0]) - np.array([[c, -s], [s, c]]) @ np.array([1.0, 2.0])
    assert abs(float(f["yaw_deg"]) - math.degrees(-0.5)) < 1.0
    assert math.hypot(float(f["x"]) - want[0], float(f["y"]) - want[1]) < 0.05
    fixed = read_map(tmp_path / "fixed.yaml")
    assert fixed.origin[2] == 0.0
    pts = Grid(fixed.occupancy.astype(float), fixed.resolution, fixed.origin[:2]).wall_points()
    from scipy.spatial import cKDTree

    d, _ = cKDTree(_plan().wall_points()).query(pts)
    assert (d <= 0.0501).mean() > 0.95
