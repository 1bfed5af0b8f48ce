"""``rsal tour`` and ``rsal map`` on a short simulated tour of maps/testroom.world, judged by the
simulator's ground truth: the trajectory, the walls of the built map, the map_server output as the
mapfile driver loads it, and each bad input's one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from rsal.cli import main as rsal_main
from rsal.mapping.evaluate import trajectory_error, wall_agreement
from rsal.mapping.mapyaml import read_map
from rsal.mapping.posegraph import between, compose
from rsal.mapping.reader import MIN_SCANS, read_scans
from rsal.mapping.slam import run_slam
from rsal.mapping.tour import run_tour
from rsal.record.format import McapWriter
from rsal.record.player import Recording

ROOT = Path(__file__).resolve().parents[2]
WORLD = ROOT / "maps" / "testroom.world"
START = (-2.0, 0.0, 0.0)  # r0's pose in the world file


@pytest.fixture(scope="module")
def tour(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("tour") / "room.mcap"
    st = run_tour(str(WORLD), str(out), minutes=1.5, seed=3)
    assert st.loops >= 1 and st.distance > 15.0  # the default waypoints make a loop of the room
    return out


@pytest.fixture(scope="module")
def truth_grid():
    from simulator.loader import load_world
    from simulator.world import World

    return World(load_world(str(WORLD))).grid


@pytest.fixture(scope="module")
def built(tour, tmp_path_factory):
    stem = tmp_path_factory.mktemp("map") / "room"
    rc = rsal_main(["map", str(tour), "-o", str(stem), "--initial-pose", *map(str, START)])
    assert rc == 0
    return stem


def test_tour_is_a_recording_of_laser_odometry_and_truth(tour):
    kinds: dict[str, set] = {}
    for s in Recording(tour).samples():
        kinds.setdefault(s.kind, set()).add(s.key)
    assert kinds["data"] == {"rsal/r0/laser/0/data", "rsal/r0/position2d/0/data"}
    assert kinds["rpc"] == {"rsal/r0/laser/0/rpc/describe", "rsal/r0/position2d/0/rpc/describe"}
    assert kinds["liveliness"] == {"rsal/r0/laser/0", "rsal/r0/position2d/0"}
    assert kinds["truth"] == {"truth/r0"}
    sc = read_scans(tour)
    assert np.allclose(sc.mount, (0.13, 0.0, 0.0))  # from the laser's describe
    assert np.allclose(sc.truth[0], START, atol=1e-3)  # standing at the start for the first scans
    # the odometry drifts: after the loop it is well off the truth (in the world frame)
    odo = compose(np.broadcast_to(compose(START, between(sc.odom[0], np.zeros(3))), sc.odom.shape), sc.odom)
    assert trajectory_error(odo, sc.truth)[1] > 0.2


def test_slam_trajectory_beats_odometry_against_ground_truth(tour):
    sc = read_scans(tour)
    res = run_slam(sc, START)
    truth = sc.truth[res.used]
    rms, worst = trajectory_error(res.poses, truth)
    odo = compose(np.broadcast_to(compose(START, between(sc.odom[0], np.zeros(3))), sc.odom.shape), sc.odom)
    odo_rms, _ = trajectory_error(odo[res.used], truth)
    assert rms < 0.05 and worst < 0.15, (rms, worst)
    assert rms < odo_rms / 5, (rms, odo_rms)
    assert res.loops, "the tour passes its start again: at least one loop closure"
    assert len(res.keyframes) > 20


def test_built_map_walls_lie_on_the_true_walls(built, truth_grid):
    m = read_map(f"{built}.yaml")
    assert m.resolution == 0.05
    precision, coverage = wall_agreement(
        m.occupancy[::-1], m.resolution, m.origin, truth_grid.occupied, truth_grid.resolution, truth_grid.origin
    )
    assert precision >= 0.95 and coverage >= 0.85, (precision, coverage)
    assert Path(f"{built}.trajectory.png").stat().st_size > 0


def test_map_yaml_loads_through_the_mapfile_path(built, truth_grid):
    from simulator.gridmap import GridMap

    meta = yaml.safe_load(Path(f"{built}.yaml").read_text())
    assert set(meta) >= {"image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate"}
    g = GridMap.from_image(
        Path(f"{built}.yaml").parent / meta["image"], meta["resolution"], tuple(meta["origin"][:2])
    )  # what the mapfile driver does with the bitmap
    iy, ix = np.nonzero(g.occupied)
    assert len(ix) > 100
    x, y = g.cell_to_world(ix, iy)
    assert np.mean(truth_grid.clearance(x, y) <= 0.125) >= 0.95
    # the box at (2.5, 0) stands in the built map where it stands in the world
    assert g.clearance(2.0, 0.0) < 0.1 and g.clearance(2.5, 0.5) < 0.1


def test_summary_names_scans_keyframes_loops_and_residual(tour, tmp_path, capsys):
    assert rsal_main(["map", str(tour), "-o", str(tmp_path / "m")]) == 0
    out = capsys.readouterr().out
    assert "scans used" in out and "keyframes" in out and "loop closures" in out and "residual" in out


def _copy(src: Path, dst: Path, keep) -> Path:
    with McapWriter(dst) as w:
        for s in Recording(src).samples():
            if keep(s):
                w.write(s.kind, s.key, s.data, s.log_time, s.publish_time)
    return dst


def _one_line_error(capsys, argv, *needles):
    assert rsal_main(["map", *argv]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


def test_bad_inputs_one_line_each(tour, tmp_path, capsys):
    out = str(tmp_path / "m")
    txt = tmp_path / "notes.mcap"
    txt.write_text("not a recording\n")
    _one_line_error(capsys, [str(txt), "-o", out], str(txt), "not an MCAP file")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    _one_line_error(capsys, [str(empty), "-o", out], str(empty), "empty")
    no_laser = _copy(tour, tmp_path / "nolaser.mcap", lambda s: "/laser/" not in s.key)
    _one_line_error(capsys, [str(no_laser), "-o", out], str(no_laser), "no laser")
    no_odo = _copy(tour, tmp_path / "noodo.mcap", lambda s: "/position2d/" not in s.key)
    _one_line_error(capsys, [str(no_odo), "-o", out], str(no_odo), "no odometry", "r0")
    _one_line_error(capsys, [str(tour), "-o", out, "--robot", "r7"], str(tour), "'r7'", "r0")
    n = {"laser": 0}

    def few(s):
        if s.key.endswith("/laser/0/data"):
            n["laser"] += 1
            return n["laser"] < MIN_SCANS
        return True

    short = _copy(tour, tmp_path / "short.mcap", few)
    _one_line_error(capsys, [str(short), "-o", out], str(short), f"only {MIN_SCANS - 1} laser scan")
    assert not Path(out + ".yaml").exists()


def test_a_tour_without_a_loop_still_builds_and_says_so(tmp_path, capsys):
    rec = tmp_path / "short.mcap"
    wp = tmp_path / "wp.txt"
    wp.write_text("# x y\n0.5 3.0\n4.0 3.0\n4.0 -3.0\n")
    st = run_tour(str(WORLD), str(rec), minutes=0.3, seed=2, waypoints=str(wp))  # out, not back
    assert st.loops == 0
    assert rsal_main(["map", str(rec), "-o", str(tmp_path / "m")]) == 0
    assert "no loop was closed" in capsys.readouterr().out
    assert (tmp_path / "m.yaml").exists() and (tmp_path / "m.png").exists()


def test_tour_bad_robot_and_waypoints(tmp_path, capsys):
    assert rsal_main(["tour", str(WORLD), "-o", str(tmp_path / "t.mcap"), "--robot", "blob0"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "blob0" in err and "r0" in err, err
    wp = tmp_path / "wp.txt"
    wp.write_text("0 0\n2.5 0.0\n")  # inside the box
    assert rsal_main(["tour", str(WORLD), "-o", str(tmp_path / "t.mcap"), "--waypoints", str(wp)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "waypoint 2" in err, err


def test_amcl_localizes_a_second_tour_on_the_built_map(built, tmp_path):
    """The built map is good enough to navigate on: AMCL (the amcl driver's filter) over a second
    tour with other odometry noise keeps its estimate within 0.15 m of the true pose."""
    from mrs_bridge.nav.grid import NavGrid
    from mrs_bridge.nav.offline import localize_scans

    second = tmp_path / "second.mcap"
    run_tour(str(WORLD), str(second), minutes=1.0, seed=5)
    sc = read_scans(second)
    m = read_map(f"{built}.yaml")
    loc = localize_scans(NavGrid(m.cells(), m.resolution, m.origin[:2]), sc, sc.truth[0])
    err = loc.after(sc.t, settle_s=3.0)
    assert err.size > 100 and float(np.max(err)) < 0.15, (float(np.mean(err)), float(np.max(err)))
    # a map shifted by 0.5 m is not: the check can fail
    bad = localize_scans(NavGrid(m.cells(), m.resolution, (m.origin[0] + 0.5, m.origin[1])), sc, sc.truth[0])
    assert float(np.max(bad.after(sc.t, settle_s=3.0))) > 0.3
