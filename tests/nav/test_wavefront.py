"""Wavefront planner and executive on the project's floor and arena maps.

Path optimality is checked against an exact grid shortest path computed here with
``scipy.sparse.csgraph.dijkstra`` over the plain 8-connected graph of allowed cells (which may
cut corners, so it is a lower bound on the planner's corner-safe paths); safety against the
map's own distance field; straight segments by dense sampling.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse import csgraph

from mrs_bridge.nav.grid import NavGrid
from mrs_bridge.nav.wavefront import Executive, PlanError, Wavefront
from simulator.gridmap import GridMap
from tests.conftest import MAPS

FLOOR = ("floor.png", 0.05, (-31.475, -7.8))
ARENA = ("arena.png", 0.1, (-64.0, -64.0))
R_MIN = 0.5  # default robot_radius + safety_dist
SERVER_ROOM = (-1.3, 7.0)  # the floor's server room N5 has no door (maps/README.md)
LAB = (-14.0, 7.0)  # in the laboratory, 1.5 m from its furniture


def load(spec) -> NavGrid:
    name, res, origin = spec
    gm = GridMap.from_image(MAPS / name, res, origin)
    return NavGrid.from_occupancy(gm.occupied, res, origin)


@pytest.fixture(scope="module")
def floor() -> NavGrid:
    return load(FLOOR)


@pytest.fixture(scope="module")
def arena() -> NavGrid:
    return load(ARENA)


@pytest.fixture(scope="module")
def floor_wf(floor) -> Wavefront:
    wf = Wavefront(floor)
    wf.plan((-28.0, 1.75), (-20.0, 1.75))  # compile / load the kernels before anything is timed
    return wf


def grid_graph(allowed: np.ndarray, res: float, weight=None, corner_cut: bool = True) -> sparse.csr_matrix:
    """Undirected 8-connected graph of allowed cells; an edge costs its length in metres, times the
    mean of its cells' ``weight`` if given. Without ``corner_cut``, a diagonal edge needs both
    cells beside it allowed."""
    h, w = allowed.shape
    idx = np.arange(h * w).reshape(h, w)
    rows, cols, wts = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        ya, yb = slice(0, h - dy), slice(dy, h)
        xa, xb = slice(max(0, -dx), w - max(0, dx)), slice(max(0, dx), w - max(0, -dx))
        m = allowed[ya, xa] & allowed[yb, xb]
        if dx and dy and not corner_cut:
            m &= allowed[ya, xb] & allowed[yb, xa]
        length = res * math.hypot(dx, dy)
        rows.append(idx[ya, xa][m])
        cols.append(idx[yb, xb][m])
        cost = np.full(int(m.sum()), length)
        if weight is not None:
            cost *= 0.5 * (weight[ya, xa][m] + weight[yb, xb][m])
        wts.append(cost)
    r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(wts)
    return sparse.csr_matrix((v, (r, c)), shape=(h * w, h * w))


def polyline_length(p: np.ndarray) -> float:
    return float(np.hypot(*np.diff(p, axis=0).T).sum())


def polyline_cost(wf: Wavefront, plan) -> float:
    """The cell path's cost under the documented model (length times mean cell weight)."""
    grid = wf.grid
    ix, iy = grid.world_to_cell(plan.path[:, 0], plan.path[:, 1])
    w = 1.0 + wf.dist_penalty * np.maximum(0.0, wf.max_radius - grid.distance[iy, ix].astype(float))
    step = np.hypot(np.diff(ix), np.diff(iy)) * grid.resolution
    return float(np.sum(step * 0.5 * (w[:-1] + w[1:])))


def assert_segments_allowed(grid: NavGrid, pts: np.ndarray, r_min: float, skip_first: bool = False):
    """Sample every segment every 1/16 cell; each sample's cell must have clearance >= r_min."""
    for k in range(1 if skip_first else 0, len(pts) - 1):
        a, b = pts[k], pts[k + 1]
        n = max(2, int(math.ceil(np.hypot(*(b - a)) / grid.resolution * 16)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        s = a + t * (b - a)
        ix, iy = grid.world_to_cell(s[:, 0], s[:, 1])
        assert grid.in_bounds_cell(ix, iy).all()
        clear = grid.distance[iy, ix]
        assert clear.min() >= r_min, f"segment {k} {a} -> {b} passes {clear.min():.3f} m from a wall"


def assert_path_shape(grid: NavGrid, plan, start, goal, r_min: float):
    assert np.allclose(plan.waypoints[0], start[:2]) and np.allclose(plan.waypoints[-1], goal[:2])
    assert math.isclose(plan.length, polyline_length(plan.waypoints), rel_tol=1e-12)
    ix, iy = grid.world_to_cell(plan.path[:, 0], plan.path[:, 1])
    steps = np.abs(np.diff(np.column_stack([ix, iy]), axis=0))
    assert steps.max() == 1, "path cells must be 8-neighbours"
    assert grid.distance[iy, ix].min() >= r_min, "a path cell is too close to a wall"


# ------------------------------------------------------------------------------------ optimality
def test_floor_paths_match_exact_grid_shortest_paths(floor):
    wf = Wavefront(floor, dist_penalty=0.0)  # pure length, comparable to the graph shortest path
    allowed = floor.distance >= R_MIN
    assert np.array_equal(wf.allowed, allowed)
    graph = grid_graph(allowed, floor.resolution)
    rng = np.random.default_rng(20110607)
    cand = np.flatnonzero(allowed.ravel())
    ratios, wp_ratios = [], []
    while len(ratios) < 20:
        s = int(rng.choice(cand))
        dist = csgraph.dijkstra(graph, directed=False, indices=s)
        reach = np.flatnonzero(np.isfinite(dist) & (dist > 5.0))
        if reach.size == 0:
            continue
        g = int(rng.choice(reach))
        exact = float(dist[g])
        sy, sx = divmod(s, floor.width)
        gy, gx = divmod(g, floor.width)
        # random points inside the start and goal cells
        start = np.array(floor.cell_to_world(sx, sy)) + rng.uniform(-0.49, 0.49, 2) * floor.resolution
        goal = np.array(floor.cell_to_world(gx, gy)) + rng.uniform(-0.49, 0.49, 2) * floor.resolution
        plan = wf.plan(start, goal)
        assert_path_shape(floor, plan, start, goal, R_MIN)
        assert_segments_allowed(floor, plan.waypoints, R_MIN)
        grid_len = polyline_length(plan.path)
        assert exact - 1e-9 <= grid_len <= 1.05 * exact, (start, goal, grid_len, exact)
        # the exact start and goal points may lie up to half a cell diagonal from their centres
        assert plan.length <= 1.05 * exact + floor.resolution * math.sqrt(2), (start, goal, plan.length, exact)
        ratios.append(grid_len / exact)
        wp_ratios.append(plan.length / exact)
    print(f"\npath/exact max {max(ratios):.4f}; waypoints/exact min {min(wp_ratios):.4f} max {max(wp_ratios):.4f}")


def test_potential_is_the_wavefront_the_path_descends(floor_wf, floor):
    start, goal = (-27.0, 2.2), LAB  # corridor to laboratory, through a door
    plan = floor_wf.plan(start, goal)
    pot = floor_wf.potential()
    assert pot.shape == (floor.height, floor.width)
    ix, iy = floor.world_to_cell(plan.path[:, 0], plan.path[:, 1])
    along = pot[iy, ix]
    assert along[-1] == 0.0 and np.all(np.diff(along) < 0), "the path must descend the potential"
    assert np.all(np.isinf(pot[~floor_wf.allowed])), "forbidden cells have no potential"
    # the documented cost model, computed independently: Dijkstra over the corner-safe 8-connected
    # graph with edges costing length * mean(1 + dist_penalty * max(0, max_radius - clearance))
    weight = 1.0 + floor_wf.dist_penalty * np.maximum(0.0, floor_wf.max_radius - floor.distance.astype(float))
    graph = grid_graph(floor.distance >= R_MIN, floor.resolution, weight, corner_cut=False)
    gx, gy = floor.world_to_cell(*goal)
    ref = csgraph.dijkstra(graph, directed=False, indices=int(gy) * floor.width + int(gx)).reshape(pot.shape)
    assert np.array_equal(np.isfinite(ref), np.isfinite(pot))
    fin = np.isfinite(ref)
    assert np.allclose(pot[fin], ref[fin], rtol=1e-6)  # float32 weights in the planner


def test_replans_to_the_same_goal_continue_the_wave(floor):
    wf = Wavefront(floor)
    goal = (8.0, 8.0)  # office N7
    wf.plan((-27.0, 1.75), goal)
    first = wf.last_expanded
    others = [LAB, (-17.4, -4.0), (11.0, -4.0)]  # rooms off the first path
    for start in others:
        fresh = Wavefront(floor).plan(start, goal)
        again = wf.plan(start, goal)
        assert polyline_cost(wf, again) == pytest.approx(polyline_cost(wf, fresh), rel=1e-9)
    wf.plan((-27.0, 1.75), goal)  # settled already: nothing to do
    assert first > 0 and wf.last_expanded == 0
    pot = wf.potential()
    wf.plan((10.0, -4.0), goal)
    assert wf.last_expanded == 0 and wf.potential() is pot
    wf.reset()
    assert np.all(np.isinf(wf.potential()))
    wf.plan((-27.0, 1.75), goal)
    assert wf.last_expanded == first


def test_clones_share_the_configuration_space(floor, floor_wf):
    a = floor_wf.clone()
    b = floor_wf.clone()
    assert np.shares_memory(a.allowed, floor_wf.allowed) and not a.allowed.flags.writeable
    start = (-27.0, 1.75)
    pa = a.plan(start, LAB)
    b.plan(start, (20.0, 1.75))
    assert b.last_expanded > 0
    again = a.plan(start, LAB)  # b's search left a's kept wave alone
    assert a.last_expanded == 0 and np.array_equal(again.path, pa.path)
    assert polyline_cost(a, pa) == pytest.approx(polyline_cost(a, Wavefront(floor).plan(start, LAB)), rel=1e-12)


def test_dist_penalty_keeps_paths_in_the_middle(floor):
    start, goal = (-27.0, 1.3), (20.0, 2.2)  # along the 2.5 m corridor, off its centre line
    clear = []
    for pen in (0.0, 1.0, 5.0):
        plan = Wavefront(floor, dist_penalty=pen).plan(start, goal)
        ix, iy = floor.world_to_cell(plan.path[:, 0], plan.path[:, 1])
        clear.append(float(np.mean(floor.distance[iy, ix])))
    assert clear[0] < clear[1] <= clear[2]
    assert clear[2] > 1.1  # the corridor's middle is 1.25 m from its walls


# ------------------------------------------------------------------------------------ safety
@pytest.mark.parametrize("robot_radius, safety_dist", [(0.25, 0.25), (0.25, 0.3)])
def test_arena_paths_keep_clearance(arena, robot_radius, safety_dist):
    r_min = robot_radius + safety_dist
    wf = Wavefront(arena, robot_radius=robot_radius, safety_dist=safety_dist)
    rng = np.random.default_rng(7)
    iy, ix = np.nonzero(arena.distance >= r_min + 0.3)
    for _ in range(10):
        a, b = rng.integers(len(ix), size=2)
        start, goal = arena.cell_to_world(ix[a], iy[a]), arena.cell_to_world(ix[b], iy[b])
        plan = wf.plan(start, goal)
        assert_path_shape(arena, plan, start, goal, r_min)
        assert_segments_allowed(arena, plan.waypoints, r_min)


def test_unknown_cells_are_obstacles():
    cells = np.full((40, 80), -1, dtype=np.int8)
    cells[:, 39:41] = 0  # an unknown strip across the map...
    grid = NavGrid(cells, 0.1, (0.0, 0.0))
    wf = Wavefront(grid, robot_radius=0.2, safety_dist=0.1)
    with pytest.raises(PlanError) as e:
        wf.plan((1.0, 2.0), (7.0, 2.0))
    assert e.value.code == "unreachable"
    cells[15:25, 39:41] = -1  # ...with a 1 m gap in it
    grid = NavGrid(cells, 0.1, (0.0, 0.0))
    wf = Wavefront(grid, robot_radius=0.2, safety_dist=0.1)
    plan = wf.plan((1.0, 0.5), (7.0, 0.5))
    ix, iy = grid.world_to_cell(plan.path[:, 0], plan.path[:, 1])
    assert np.all(wf.clearance[iy, ix] >= 0.3)
    assert np.any((ix >= 39) & (ix <= 40)) and np.all(iy[(ix >= 39) & (ix <= 40)] >= 17)
    with pytest.raises(PlanError) as e:
        wf.plan((1.0, 0.5), (4.0, 0.5))  # inside the unknown strip
    assert e.value.code == "in_obstacle" and "unknown" in str(e.value)


# ------------------------------------------------------------------------------------ errors
def wall_point(grid: NavGrid) -> tuple[float, float]:
    iy, ix = np.nonzero(grid.occupied[100:300, 100:1100])
    return grid.cell_to_world(ix[len(ix) // 2] + 100, iy[len(iy) // 2] + 100)


def near_wall_point(grid: NavGrid, lo: float, hi: float) -> tuple[float, float]:
    iy, ix = np.nonzero(grid.free & (grid.distance > lo) & (grid.distance < hi))
    k = len(ix) // 3
    return grid.cell_to_world(ix[k], iy[k])


def test_invalid_goals_fail_fast_with_clear_errors(floor_wf, floor):
    start = (-27.0, 1.75)
    cases = [
        (floor_wf, (100.0, 1.0), "outside_map", "outside the map"),
        (floor_wf, wall_point(floor), "in_obstacle", "inside an obstacle"),
        (floor_wf, near_wall_point(floor, 0.1, 0.4), "in_obstacle", "safety_dist"),
        (floor_wf, SERVER_ROOM, "unreachable", "no path"),
    ]
    for wf, goal, code, words in cases:
        t = time.perf_counter()
        with pytest.raises(PlanError) as e:
            wf.plan(start, goal)
        dt = time.perf_counter() - t
        assert e.value.code == code
        msg = str(e.value)
        assert "\n" not in msg and words in msg and f"({goal[0]:.2f}, {goal[1]:.2f})" in msg
        assert dt < 0.1, f"{code} took {dt:.3f} s"
    # and the other way round: a start inside the closed room
    with pytest.raises(PlanError) as e:
        floor_wf.plan(SERVER_ROOM, start)
    assert e.value.code == "unreachable"


def test_invalid_starts(floor_wf, floor):
    goal = (-20.0, 1.75)
    for start, code in [((-40.0, 1.0), "outside_map"), (wall_point(floor), "in_obstacle")]:
        with pytest.raises(PlanError) as e:
            floor_wf.plan(start, goal)
        assert e.value.code == code and "start" in str(e.value)
    with pytest.raises(ValueError):
        floor_wf.plan((math.nan, 0.0), goal)


def test_start_touching_a_wall_snaps_to_allowed_space(floor_wf, floor):
    # a robot of radius 0.25 with its centre 0.3 m from a wall is inside the 0.5 m forbidden band
    start = near_wall_point(floor, 0.28, 0.32)
    assert not floor_wf.allowed[tuple(reversed(floor.world_to_cell(*start)))]
    plan = floor_wf.plan(start, goal=(-20.0, 1.75))
    assert np.allclose(plan.waypoints[0], start)
    assert np.hypot(*(plan.path[0] - start)) <= floor_wf.snap_radius
    assert_path_shape(floor, plan, start, (-20.0, 1.75), R_MIN)
    assert_segments_allowed(floor, plan.waypoints, R_MIN, skip_first=True)
    assert_segments_allowed(floor, plan.waypoints[:2], 1e-6)  # the way out crosses no occupied cell
    with pytest.raises(PlanError) as e:
        Wavefront(floor, snap_radius=0.05).plan(start, (-20.0, 1.75))
    assert e.value.code == "in_obstacle" and "start" in str(e.value) and "snap" not in str(e.value)


def test_parameters_are_checked(floor):
    with pytest.raises(ValueError, match="safety_dist"):
        Wavefront(floor, safety_dist=-0.1)
    with pytest.raises(ValueError, match="dist_penalty"):
        Wavefront(floor, dist_penalty=math.nan)
    with pytest.raises(ValueError, match="distance_epsilon"):
        Executive(Wavefront(floor), distance_epsilon=-1.0)


# ------------------------------------------------------------------------------------ executive
def drive(ex: Executive, pose, t: float, limit: int = 200):
    """Teleport the robot onto each target it is handed; return the targets and the final status."""
    seen = []
    for _ in range(limit):
        target, status = ex.update(pose, t)
        if target is None:
            return seen, status, pose
        if not seen or not np.array_equal(seen[-1], target):
            seen.append(target)
        pose = tuple(target)
        t += 0.1
    raise AssertionError("the executive never finished")


def test_executive_hands_waypoints_in_order(floor_wf):
    ex = Executive(floor_wf, distance_epsilon=0.4, angle_epsilon=math.radians(10))
    assert ex.update((-27.0, 1.75, 0.0), 0.0) == (None, "idle")
    goal = (*LAB, 1.0)
    plan = ex.set_goal((-27.0, 1.75, 0.0), goal, now=0.0)
    assert ex.status == "driving" and ex.waypoint_index == 1 and len(plan.waypoints) >= 3
    seen, status, pose = drive(ex, (-27.0, 1.75, 0.0), 0.0)
    assert status == "done" and ex.replans == 0
    wp = plan.waypoints
    assert np.allclose([s[:2] for s in seen], wp[1:])
    for k, s in enumerate(seen[:-1], start=1):  # intermediate yaw points along the path
        assert s[2] == pytest.approx(math.atan2(wp[k + 1, 1] - wp[k, 1], wp[k + 1, 0] - wp[k, 0]))
    assert seen[-1][2] == pytest.approx(1.0)
    assert ex.update(pose, 30.0) == (None, "done")


def test_executive_done_needs_both_epsilons(floor_wf):
    ex = Executive(floor_wf, distance_epsilon=0.4, angle_epsilon=math.radians(10))
    goal = (-24.0, 1.75, math.pi / 2)
    ex.set_goal((-27.0, 1.75, 0.0), goal, now=0.0)
    assert len(ex.plan.waypoints) == 2  # straight down the corridor
    near = [
        ((-24.0, 1.75, 0.0), "driving"),  # there, facing the wrong way
        ((-24.5, 1.75, math.pi / 2), "driving"),  # facing right, too far
        ((-24.3, 1.75, math.pi / 2 + math.radians(15)), "driving"),
        ((-24.3, 1.75, math.pi / 2 + math.radians(8)), "done"),
    ]
    for pose, want in near:
        target, status = ex.update(pose, 0.5)
        assert status == want, pose
        if want == "driving":
            assert np.allclose(target, goal)


def test_executive_replans_off_path_after_min_time(floor_wf):
    ex = Executive(floor_wf, replan_dist_thresh=2.0, replan_min_time=2.0)
    first = ex.set_goal((-27.0, 1.75, 0.0), (20.0, 1.75, 0.0), now=0.0)
    lab = (*LAB, 0.0)  # 5.25 m off the corridor path
    _, status = ex.update(lab, 1.0)
    assert status == "driving" and ex.plan is first, "replanned before replan_min_time"
    _, status = ex.update((-25.0, 3.0, 0.0), 2.5)  # still within replan_dist_thresh
    assert ex.plan is first
    target, status = ex.update(lab, 2.5)
    assert status == "driving" and ex.plan is not first and ex.replans == 1
    assert np.allclose(ex.plan.waypoints[0], lab[:2]) and ex.waypoint_index >= 1
    second = ex.plan
    ex.update((-5.0, 7.5, 0.0), 3.0)  # off the new path, but too soon
    assert ex.plan is second
    ex.update((-5.0, 7.5, 0.0), 4.6)
    assert ex.plan is not second and ex.replans == 2
    ex2 = Executive(floor_wf, replan_min_time=-1)  # Player's -1: never replan
    plan = ex2.set_goal((-27.0, 1.75, 0.0), (20.0, 1.75, 0.0), now=0.0)
    ex2.update(lab, 100.0)
    assert ex2.plan is plan


def test_executive_aborts_when_the_map_is_blocked(floor_wf, floor):
    ex = Executive(floor_wf)
    ex.set_goal((-27.0, 1.75, 0.0), (20.0, 1.75, 0.0), now=0.0)
    occ = floor.occupied.copy()
    occ[:, 600:606] = True  # a wall across the whole building
    ex.planner = Wavefront(NavGrid.from_occupancy(occ, floor.resolution, floor.origin))
    target, status = ex.update((-27.0, 6.0, 0.0), 3.0)  # strayed off the path: replan fails
    assert (target, status) == (None, "aborted")
    assert ex.error is not None and ex.error.code == "unreachable"
    assert ex.update((-27.0, 1.75, 0.0), 10.0) == (None, "aborted")
    ex.planner = floor_wf  # the way is open again
    assert ex.resume((-27.0, 1.75, 0.0), 11.0) == "driving" and ex.error is None


def test_executive_stop_resume_and_bad_goal(floor_wf):
    ex = Executive(floor_wf)
    ex.set_goal((-27.0, 1.75, 0.0), (20.0, 1.75, 0.0), now=0.0)
    ex.stop()
    assert ex.update((-27.0, 1.75, 0.0), 0.5) == (None, "idle")
    assert ex.resume((-20.0, 1.75, 0.0), 1.0) == "driving"
    assert np.allclose(ex.plan.waypoints[0], (-20.0, 1.75))
    target, status = ex.update((-20.0, 1.75, 0.0), 1.1)
    assert status == "driving" and np.allclose(target[:2], (20.0, 1.75))
    plan = ex.plan
    with pytest.raises(PlanError):
        ex.set_goal((-20.0, 1.75, 0.0), (100.0, 0.0, 0.0), now=2.0)
    assert ex.status == "driving" and ex.plan is plan
