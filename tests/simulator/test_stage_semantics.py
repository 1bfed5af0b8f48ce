"""Stage 4 keywords with Stage's meaning, judged on the simulator's ground truth.

quit_time ends headless runs (``python -m simulator`` and ``rsal sim``), ``boundary 1`` keeps robots
on the map, ``ctrl "wander"`` robots move and keep off the walls, block outlines and ``origin`` are
the collision shape, ``resolution`` is the map's grid, and whatever is not simulated is named in one
warning with its file:line. The worlds are in ``fixtures/stage/stage4/``.
"""

from __future__ import annotations

import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from simulator.controllers import StageWander
from simulator.stageworld import load_stage_world
from simulator.world import RangerReading, World
from tests.conftest import ROOT, rsal_cmd, wait_until

WORLDS = Path(__file__).parent / "fixtures" / "stage" / "stage4"


def world_of(name: str) -> World:
    return World(load_stage_world(WORLDS / name))


def hits(world: World, name: str, x: float, y: float) -> bool:
    """Whether the point (x, y) lies inside one of ``name``'s collision polygons."""
    body = world._model(name).body
    return any(q.shape.body is body for q in world.space.point_query((x, y), 0.0, _all_filter()))


def _all_filter():
    import pymunk

    return pymunk.ShapeFilter()


def wall_contacts(world: World, name: str) -> int:
    static = world.space.static_body
    return sum(q.shape.body is static for s in world._model(name).shapes for q in world.space.shape_query(s))


# ---------------------------------------------------------------------------------- quit_time
def test_quit_time_ends_a_headless_run_at_that_simulated_time():
    out = subprocess.run(
        [sys.executable, "-m", "simulator", str(WORLDS / "quit.world"), "--fast", "--duration", "30", "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    assert "[sim] quit_time 5 s reached at t=5.0 s: stopping" in out.stdout
    assert re.search(r"summary: robots=1 sim_seconds=5\.0 ", out.stdout), out.stdout
    assert out.stderr == ""  # threads is accepted without a warning


def test_rsal_sim_stops_cleanly_at_quit_time(procs, port):
    p = procs(rsal_cmd("sim", str(WORLDS / "quit.world"), "--fast", "--listen", f"tcp/127.0.0.1:{port}"))
    wait_until(lambda: not p.alive(), 90, "rsal sim to stop at quit_time")
    out = p.output()
    assert p.p.returncode == 0, out
    assert "[sim] quit_time 5 s reached at t=5.0 s: stopped" in out
    assert re.search(r"summary: robots=1 sim_seconds=5\.0 ", out), out
    assert "Traceback" not in out


# ---------------------------------------------------------------------------------- boundary
def _drive_to_edges(world: World, seconds: float = 12.0) -> None:
    world.set_velocity("r0", 0.5, 0.0)  # east, from x = 2 towards the edge at x = 3
    world.set_velocity("r1", 0.5, 0.0)  # south, from y = -2 towards the edge at y = -3
    for _ in range(int(seconds / world.spec.interval_sim)):
        world.set_velocity("r0", 0.5, 0.0)
        world.set_velocity("r1", 0.5, 0.0)
        world.step()


def test_boundary_walls_keep_robots_on_the_map():
    w = world_of("boundary.world")
    assert w.spec.floorplan is not None and w.spec.floorplan.boundary
    _drive_to_edges(w)
    x0, y0 = w.get_pose("r0")[:2]
    x1, y1 = w.get_pose("r1")[:2]
    # Each robot pushed 6 m of travel against the edge and stays inside the 6 m x 6 m map,
    # its 0.4 m body in front of the boundary wall (one 5 cm cell).
    assert 2.5 < x0 < 3.0 - 0.05 - 0.2 + 0.01, x0
    assert -(3.0 - 0.05 - 0.2 + 0.01) < y1 < -2.5, y1
    assert abs(y0) < 0.05 and abs(x1) < 0.05


def test_without_boundary_the_same_robots_drive_off_the_map(tmp_path):
    d = tmp_path / "w"
    shutil.copytree(WORLDS, d)
    text = (d / "boundary.world").read_text().replace("boundary 1", "boundary 0")
    (d / "boundary.world").write_text(text)
    w = World(load_stage_world(d / "boundary.world"))
    _drive_to_edges(w)
    assert w.get_pose("r0")[0] > 3.5 and w.get_pose("r1")[1] < -3.5


# ---------------------------------------------------------------------------------- resolution
def _fine_map_world(tmp_path: Path, resolution: str) -> Path:
    im = Image.new("L", (200, 200), 255)  # 1 m x 1 m at 0.005 m/pixel
    im.putpixel((101, 98), 0)  # one dark pixel: x in [0.005, 0.01), y in [0.005, 0.01) (row 0 is the top)
    im.save(tmp_path / "fine.png")
    p = tmp_path / "fine.world"
    p.write_text(f'{resolution}\nmodel( bitmap "fine.png" size [ 1.0 1.0 0.5 ] pose [ 0 0 0 0 ] )\n')
    return p


@pytest.mark.parametrize(
    ("line", "cell"), [("", 0.02), ("resolution 0.02", 0.02), ("resolution 0.05", 0.05), ("resolution 0.001", 0.005)]
)
def test_resolution_is_the_grid_of_a_finer_bitmap(tmp_path, line, cell):
    w = World(load_stage_world(_fine_map_world(tmp_path, line)))
    assert w.grid is not None and w.grid.resolution == pytest.approx(cell)
    assert int(w.grid.occupied.sum()) == 1  # the dark pixel's cell, and only it
    ix, iy = w.grid.world_to_cell(0.007, 0.007)
    assert w.grid.occupied[iy, ix]


# ---------------------------------------------------------------------------------- ctrl wander
class _FakeWorld:
    """Just what the controller reads and writes."""

    def __init__(self, ranges: dict[str, np.ndarray]):
        self.model_names = list(ranges)
        self.scans = ranges
        self.time = 0.1
        self.cmd: dict[str, tuple[float, float]] = {}

    def rangers(self, name):
        return [None]

    def ranger(self, name, index=0):
        return RangerReading(np.asarray(self.scans[name], dtype=np.float32), self.time, None)

    def set_velocity(self, name, v, w):
        self.cmd[name] = (v, w)


def test_stage_wander_decides_as_stages_example_controller():
    n = 9  # front third: indices 4..5 (3 < i < 6); left: i > 4
    clear = np.full(n, 3.0)
    obst_left = clear.copy()
    obst_left[5] = 0.8  # in front, left of centre: turn right
    obst_right = clear.copy()
    obst_right[4] = 0.8  # in front, on the right half (i <= n/2): turn left
    stop = clear.copy()
    stop[0] = 0.2  # beside the robot, closer than the stop distance: stop and turn
    side = clear.copy()
    side[8] = 0.8  # beside, not in front, not closer than 0.3: keep cruising
    fw = _FakeWorld({"a": clear, "b": obst_left, "c": obst_right, "d": stop, "e": side})
    c = StageWander(fw.model_names, seed=1)
    c(fw)
    assert fw.cmd == {"a": (0.4, 0.0), "b": (0.05, -0.5), "c": (0.05, 0.5), "d": (0.0, 0.5), "e": (0.4, 0.0)}
    # An avoidance keeps its turn for 10 to 19 scans even when the way is clear again.
    fw.scans["b"] = clear
    scans = 0
    while fw.cmd["b"] != (0.4, 0.0):
        fw.time += 0.1
        c(fw)
        scans += 1
        assert scans < 30
    assert 10 <= scans <= 19  # Stage: random() % 10 + 10 scans
    # The same scan again (no new reading) changes nothing.
    fw.cmd.clear()
    c(fw)
    assert fw.cmd == {}


def test_ten_wander_robots_move_and_keep_off_the_walls():
    w = world_of("wander.world")
    names = w.robot_names
    assert len(names) == 10 and all(w.model_spec(n).ctrl == "wander" for n in names)
    prev = {n: np.array(w.get_pose(n)[:2]) for n in names}
    path = dict.fromkeys(names, 0.0)
    contacts = dict.fromkeys(names, 0)
    for _ in range(600):  # 60 s: 24 m at cruise speed in a 12 m room, so every robot must turn away
        w.step()
        for n in names:
            xy = np.array(w.get_pose(n)[:2])
            path[n] += float(np.linalg.norm(xy - prev[n]))
            prev[n] = xy
            contacts[n] += wall_contacts(w, n)
    assert min(path.values()) > 2.0, path
    assert sum(contacts.values()) == 0, contacts  # measured: no wall contact in 600 x 10 robot-steps
    for n in names:  # and all still in the room (inner walls at +-5.8 m)
        x, y = prev[n]
        assert abs(x) < 5.8 and abs(y) < 5.8


# ---------------------------------------------------------------------------------- blocks, origin
def test_block_outline_is_the_collision_shape():
    w = world_of("shapes.world")
    spec = w.model_spec("arrow")
    assert len(spec.blocks) == 2
    # Blocks span x -2..6, y 0..6; scaled to size 0.6 x 0.6 and centred: the triangle's tip is at
    # (0.3, 0), its base from (-0.15, -0.3) to (-0.15, 0.3); the tail spans x -0.3..-0.15, y +-0.1.
    assert hits(w, "arrow", 0.25, 0.0) and hits(w, "arrow", -0.1, 0.25) and hits(w, "arrow", -0.25, 0.0)
    assert not hits(w, "arrow", 0.25, 0.2)  # inside the bounding box, outside the outline
    assert not hits(w, "arrow", -0.25, 0.25)
    assert not hits(w, "arrow", 0.35, 0.0)


def _gap_world(tmp_path: Path, robot: str) -> World:
    im = Image.new("L", (200, 200), 255)  # 4 m x 4 m at 0.02 m/pixel, centred on the origin
    for row in range(200):
        y = 2.0 - (row + 0.5) * 0.02
        if abs(y) > 0.25:  # a wall at x in [-0.06, 0.06) with a 0.5 m gap round y = 0
            for col in range(97, 103):
                im.putpixel((col, row), 0)
    im.save(tmp_path / "gap.png")
    p = tmp_path / "gap.world"
    shutil.copy(WORLDS / "robots.inc", tmp_path / "robots.inc")
    p.write_text(
        'include "robots.inc"\ninterval_sim 50\n'
        'model( bitmap "gap.png" size [ 4.0 4.0 0.5 ] pose [ 0 0 0 0 ] )\n'
        f"{robot}\n"
    )
    w = World(load_stage_world(p))
    for _ in range(200):  # 10 s at 0.3 m/s: 3 m of travel towards and through the gap
        w.set_velocity("r0", 0.3, 0.0)
        w.step()
    return w


def test_an_outline_wider_than_a_gap_cannot_pass_it_but_its_tip_enters(tmp_path):
    w = _gap_world(tmp_path, 'arrowbot( name "r0" pose [ -1.0 0 0 0 ] )')
    x = w.get_pose("r0")[0]
    # The 0.6 m wide arrow stops where its slanted sides meet the gap's edges (x = +0.045 in
    # theory): past where its 0.6 m bounding box would stop (-0.36), short of passing.
    assert -0.06 < x < 0.12, x


def test_a_robot_narrower_than_the_gap_passes_it(tmp_path):
    w = _gap_world(tmp_path, 'position( name "r0" pose [ -1.0 0 0 0 ] size [ 0.44 0.38 0.2 ] )')
    assert w.get_pose("r0")[0] > 1.0


def test_origin_offsets_the_shape_from_the_pose():
    w = world_of("shapes.world")
    assert w.model_spec("offset").origin == (0.5, 0.0, 0.0)
    assert w.get_pose("offset")[:2] == pytest.approx((0.0, 3.0))
    assert hits(w, "offset", 0.5, 3.0) and hits(w, "offset", 0.68, 3.0)
    assert not hits(w, "offset", 0.0, 3.0)  # the pose itself is outside the shape
    w.set_pose("offset", 0.0, 3.0, math.pi / 2)  # the shape swings round the pose
    assert hits(w, "offset", 0.0, 3.5) and not hits(w, "offset", 0.5, 3.0)


# ---------------------------------------------------------------------------------- warnings
def test_what_is_not_simulated_is_named_in_one_warning_with_lines():
    p = WORLDS / "unsupported.world"
    spec = load_stage_world(p)
    assert spec.warnings == [
        f"{p}:8: controller 'followme' of 'r0' is not built in (known: wander); the robot gets no controller",
        f"{p}: not simulated (ignored): 'wheelbase' at {p}:6, 'localization_origin' at {p}:7, "
        f"model type 'camera' at {p}:9, 'velocity' at {p}:11",
    ]
    assert spec.model("r0").ctrl is None


@pytest.mark.parametrize("name", ["quit.world", "wander.world", "boundary.world", "shapes.world"])
def test_supported_worlds_load_without_warnings(name):
    assert load_stage_world(WORLDS / name).warnings == []
