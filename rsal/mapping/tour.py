"""``rsal tour``: a simulated tour of a world, written as a recording (test and benchmark data).

Loads a world with the simulator's :class:`simulator.World` (no fabric, no real time: the world is
stepped as fast as it goes), keeps one robot (the others are removed so that the recorded scans
see only the floorplan), and drives it along a loop of waypoints with a pure-pursuit controller on
its *true* pose (this only generates data; a map builder never sees the true pose). The odometry
drifts with the world's ``odom_error`` exactly as under ``rsal sim``.

The file is what ``rsal record`` writes of that robot's ``laser:0`` and ``position2d:0`` under
``rsal sim`` (:mod:`rsal.record.format`: the devices' joins, ``describe`` replies and msgpack
``data`` samples; receive times = a start time + simulated time), plus the robot's true pose on the
``truth/<robot>`` channel (kind ``truth``, docs/recording.md), which players ignore.

Default waypoints: free cells with at least 0.6 m clearance reachable from the start, spread by
farthest-point sampling within the distance the tour can cover, ordered as a loop that starts and
ends at the start. Paths between waypoints: Dijkstra (``scipy.sparse.csgraph``) on a 0.1 m grid
that prefers clearance. The simulator is imported lazily: ``rsal`` itself depends on it only here,
for this data generator.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RsalError
from ..interfaces.position2d import Position2dData
from ..interfaces.ranger import RangerData
from ..msgs import Describe, ok_reply
from ..record.format import McapWriter, liveliness_message, truth_key

__all__ = ["TourError", "TourStats", "run_tour", "plan_waypoints"]

CELL = 0.1  # m: the planning grid
MIN_CLEARANCE = 0.4  # m: cells closer to a wall are not driven through
WAYPOINT_CLEARANCE = 0.6  # m
V_MAX = 0.4  # m/s
W_MAX = 0.8  # rad/s
LOOKAHEAD = 0.5  # m
STILL = 0.5  # s standing at the start before driving off


class TourError(RsalError, ValueError):
    """A tour that cannot be made (no such robot, no floorplan, a waypoint in a wall); one line."""


@dataclass
class TourStats:
    sim_seconds: float = 0.0
    scans: int = 0
    distance: float = 0.0  # m driven (true)
    waypoints: int = 0
    loops: int = 0
    wall: float = 0.0


class _Planner:
    """Shortest paths on a coarse grid of the world's free space, preferring clearance."""

    def __init__(self, grid):
        from scipy import ndimage, sparse

        k = max(1, int(round(CELL / grid.resolution)))
        h, w = grid.occupied.shape
        hk, wk = h // k, w // k
        occ = grid.occupied[: hk * k, : wk * k].reshape(hk, k, wk, k).any(axis=(1, 3))
        self.res = grid.resolution * k
        self.origin = grid.origin
        self.clear = ndimage.distance_transform_edt(~occ) * self.res
        ok = self.clear >= MIN_CLEARANCE
        self.ok = ok
        self.shape = ok.shape
        idx = np.arange(ok.size).reshape(ok.shape)
        cost_cell = 1.0 + 2.0 / np.maximum(self.clear, 0.05)  # prefer the middle of corridors
        rows, cols, vals = [], [], []
        H, W = ok.shape
        for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
            ys, yd = slice(0, H - dy), slice(dy, H)
            xs, xd = slice(max(0, -dx), W - max(0, dx)), slice(max(0, dx), W + min(0, dx))
            m = ok[ys, xs] & ok[yd, xd]
            ia, ib = idx[ys, xs][m], idx[yd, xd][m]
            c = 0.5 * (cost_cell.ravel()[ia] + cost_cell.ravel()[ib]) * math.hypot(dx, dy)
            rows += [ia, ib]
            cols += [ib, ia]
            vals += [c, c]
        n = ok.size
        self.graph = sparse.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
        )

    def cell(self, x: float, y: float) -> int:
        ix = int((x - self.origin[0]) / self.res)
        iy = int((y - self.origin[1]) / self.res)
        if not (0 <= ix < self.shape[1] and 0 <= iy < self.shape[0]):
            return -1
        if not self.ok[iy, ix]:  # snap to the nearest drivable cell within 0.5 m
            ys, xs = np.nonzero(self.ok[max(0, iy - 5) : iy + 6, max(0, ix - 5) : ix + 6])
            if len(xs) == 0:
                return -1
            j = int(np.argmin((ys + max(0, iy - 5) - iy) ** 2 + (xs + max(0, ix - 5) - ix) ** 2))
            iy, ix = int(ys[j]) + max(0, iy - 5), int(xs[j]) + max(0, ix - 5)
        return iy * self.shape[1] + ix

    def xy(self, cells) -> np.ndarray:
        cells = np.asarray(cells)
        iy, ix = np.divmod(cells, self.shape[1])
        return np.stack([self.origin[0] + (ix + 0.5) * self.res, self.origin[1] + (iy + 0.5) * self.res], axis=-1)

    def distances(self, src: int) -> tuple[np.ndarray, np.ndarray]:
        from scipy.sparse.csgraph import dijkstra

        return dijkstra(self.graph, indices=src, return_predecessors=True)

    def path(self, a: int, b: int) -> np.ndarray:
        _, pred = self.distances(a)
        if not np.isfinite(_[b]):
            return np.empty((0, 2))
        out = [b]
        while out[-1] != a:
            out.append(pred[out[-1]])
        return self.xy(out[::-1])


def plan_waypoints(planner: _Planner, start: tuple[float, float], budget: float, n: int = 6) -> np.ndarray:
    """``n`` waypoints spread over the free space reachable from ``start`` within ``budget`` metres
    of driving (a loop start -> waypoints -> start), ordered greedily by path length."""
    s = planner.cell(*start)
    dist, _ = planner.distances(s)
    clear = planner.clear.ravel()
    allxy = planner.xy(np.arange(len(clear)))
    near = np.linalg.norm(allxy - np.asarray(start), axis=1) <= budget / 5  # out and back, with detours
    cand = np.nonzero(np.isfinite(dist) & (clear >= WAYPOINT_CLEARANCE) & near)[0]
    if len(cand) == 0:
        return np.empty((0, 2))
    pts = planner.xy(cand)
    chosen = [int(np.argmax(dist[cand]))]
    d = np.linalg.norm(pts - pts[chosen[0]], axis=1)
    d = np.minimum(d, np.linalg.norm(pts - planner.xy(s), axis=1))
    while len(chosen) < n:
        j = int(np.argmax(d))
        if d[j] < 1.0:
            break
        chosen.append(j)
        d = np.minimum(d, np.linalg.norm(pts - pts[j], axis=1))
    wps = pts[chosen]
    order, cur, left = [], np.asarray(start, float), list(range(len(wps)))  # nearest neighbour
    while left:
        j = min(left, key=lambda i: np.linalg.norm(wps[i] - cur))
        order.append(j)
        cur = wps[j]
        left.remove(j)
    return wps[order]


def _load_waypoints(path: str) -> np.ndarray:
    try:
        rows = [ln.split("#")[0].replace(",", " ").split() for ln in Path(path).read_text().splitlines()]
    except OSError as e:
        raise TourError(f"--waypoints {path}: cannot be read ({e.strerror}); give a file of 'x y' lines") from None
    pts = []
    for i, r in enumerate(rows, 1):
        if not r:
            continue
        try:
            pts.append((float(r[0]), float(r[1])))
        except (ValueError, IndexError):
            raise TourError(f"{path}:{i}: {' '.join(r)!r} is not 'x y' in metres") from None
    if not pts:
        raise TourError(f"--waypoints {path}: no waypoints; write one 'x y' (metres) per line")
    return np.asarray(pts)


def _describe(node: str, iface: str, rate: float, geometry: dict, ops: list[str], cmd: str, data: str) -> bytes:
    d = Describe(
        node=node,
        interface=iface,
        index=0,
        driver="sim",
        rate=rate,
        geometry=geometry,
        ops=["describe", *ops],
        cmd=cmd,
        data=data,
    )
    return ok_reply(**d.to_dict())


def run_tour(
    world_path: str,
    out: str,
    *,
    robot: str | None = None,
    minutes: float = 2.0,
    waypoints: str | None = None,
    seed: int = 1,
    progress=None,
) -> TourStats:
    """Drive the tour and write ``out``; returns its figures. ``progress(stats)`` about once a second."""
    from simulator.errors import SimulatorError
    from simulator.loader import load_world
    from simulator.world import World

    t_wall = time.perf_counter()
    try:
        world = World(load_world(world_path, seed=seed), seed=seed)
    except (SimulatorError, OSError) as e:
        raise TourError(f"{world_path}: {e}") from None
    if world.grid is None:
        raise TourError(f"{world_path}: the world has no floorplan; a tour needs walls to see")
    names = world.robot_names
    lasers = [n for n in names if any(r.kind != "sonar" for r in world.rangers(n))]
    if robot is None:
        if not lasers:
            raise TourError(f"{world_path}: no robot with a laser; add one (e.g. fancypioneer2dx)")
        robot = lasers[0]
    elif robot not in lasers:
        what = "has no laser" if robot in names else "is not a robot of this world"
        raise TourError(f"--robot {robot}: {what}; robots with a laser: {', '.join(lasers) or 'none'}")
    for m in list(world.model_names):
        if m != robot:
            world.remove_model(m)
    spec = world.model_spec(robot)
    lidx = next(i for i, r in enumerate(world.rangers(robot)) if r.kind != "sonar")
    rspec = world.rangers(robot)[lidx]
    sen = rspec.sensors[0]
    step = sen.fov / (sen.samples - 1) if sen.samples > 1 else 0.0

    planner = _Planner(world.grid)
    x0, y0, _ = world.get_pose(robot)
    budget = V_MAX * 0.7 * minutes * 60.0
    if waypoints:
        wps = _load_waypoints(waypoints)
        for i, (wx, wy) in enumerate(wps, 1):
            if planner.cell(wx, wy) < 0:
                raise TourError(f"{waypoints}: waypoint {i} ({wx:g}, {wy:g}) is in a wall or off the map")
    else:
        wps = plan_waypoints(planner, (x0, y0), budget)
        if len(wps) == 0:
            raise TourError(f"{world_path}: no free space around {robot}'s start to tour; give --waypoints FILE")
    while True:
        loop = [(x0, y0), *map(tuple, wps), (x0, y0)]
        path_parts = []
        for a, b in zip(loop[:-1], loop[1:], strict=True):
            p = planner.path(planner.cell(*a), planner.cell(*b))
            if len(p) == 0:
                raise TourError(f"waypoint ({b[0]:g}, {b[1]:g}) cannot be reached from ({a[0]:g}, {a[1]:g}); move it")
            path_parts.append(p)
        length = sum(float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) for p in path_parts)
        if waypoints or length <= budget or len(wps) <= 2:
            break
        wps = wps[:-1]  # the loop would not close in time: one waypoint fewer
    path = np.concatenate(path_parts)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    path = path[keep]

    st = TourStats(waypoints=len(wps))
    dt = world.spec.interval_sim
    t0_ns = 1_700_000_000 * 10**9
    pos_geo = {
        "size": list(spec.size[:2]),
        "max_speed": list(spec.max_speed),
        "max_accel": list(spec.max_accel),
        "frame": "odom",
        "model": robot,
    }
    las_geo = {
        "kind": rspec.kind,
        "pose": list(rspec.pose),
        "sensors": [
            {
                "pose": list(s.pose),
                "fov": s.fov,
                "samples": s.samples,
                "range_min": s.range_min,
                "range_max": s.range_max,
            }
            for s in rspec.sensors
        ],
    }
    pkey, lkey = f"rsal/{robot}/position2d/0", f"rsal/{robot}/laser/0"
    end_t = minutes * 60.0
    idx = 0  # the path point being pursued
    last_scan = None
    prev_true = np.array(world.get_pose(robot)[:2])
    next_report = time.monotonic() + 1.0
    with McapWriter(out, templates=f"{robot}:*:*", started_ns=t0_ns) as w:
        for key, iface, rate, geo, ops, cmd, data in (
            (
                pkey,
                "position2d",
                1.0 / dt,
                pos_geo,
                ["set_odom", "motor_power", "stop", "estop", "estop_release"],
                "VelocityCmd",
                "Position2dData",
            ),
            (lkey, "laser", 1.0 / rspec.interval, las_geo, ["get"], "", "RangerData"),
        ):
            w.write("liveliness", key, liveliness_message(True), t0_ns, t0_ns)
            w.write("rpc", key + "/rpc/describe", _describe(robot, iface, rate, geo, ops, cmd, data), t0_ns, t0_ns)
        while world.time < end_t:
            x, y, a = world.get_pose(robot)
            # pure pursuit: the first path point at least LOOKAHEAD ahead of the nearest one
            near = idx + int(np.argmin(np.linalg.norm(path[idx : idx + 10] - (x, y), axis=1)))
            idx = near
            j = idx
            while j + 1 < len(path) and math.hypot(path[j, 0] - x, path[j, 1] - y) < LOOKAHEAD:
                j += 1
            tx, ty = path[j]
            err = math.atan2(ty - y, tx - x) - a
            err = math.atan2(math.sin(err), math.cos(err))
            v = V_MAX * max(0.0, math.cos(err)) ** 4
            om = max(-W_MAX, min(W_MAX, 1.5 * err))
            if idx > len(path) // 2 and j == len(path) - 1 and math.hypot(tx - x, ty - y) < 0.15:  # again
                st.loops += 1
                idx = 0
            if world.time < STILL:  # the first scans at the start pose (where --initial-pose puts them)
                v = om = 0.0
            world.set_velocity(robot, v, om)
            world.step()
            t = world.time
            tn = t0_ns + int(round(t * 1e9))
            pose = world.get_pose(robot)
            st.distance += float(np.linalg.norm(np.array(pose[:2]) - prev_true))
            prev_true = np.array(pose[:2])
            odo = world.odometry(robot)
            vel = world.velocity(robot)
            w.write(
                "data",
                pkey + "/data",
                Position2dData(t, odo, (vel[0], 0.0, vel[1]), world.stalled(robot)).to_msgpack(),
                tn,
            )
            w.write("truth", truth_key(robot), _truth(t, pose), tn, tn)
            r = world.ranger(robot, lidx)
            if r is not None and r.time != last_scan:
                last_scan = r.time
                msg = RangerData(r.time, r.ranges, -sen.fov / 2 + sen.pose[2], step, sen.range_min, sen.range_max)
                w.write("data", lkey + "/data", msg.to_msgpack(), tn)
                st.scans += 1
            st.sim_seconds = t
            if progress is not None and time.monotonic() >= next_report:
                next_report = time.monotonic() + 1.0
                st.wall = time.perf_counter() - t_wall
                progress(st)
        tn = t0_ns + int(round(world.time * 1e9))
        for key in (pkey, lkey):
            w.write("liveliness", key, liveliness_message(False), tn, tn)
    st.wall = time.perf_counter() - t_wall
    return st


def _truth(t: float, pose) -> bytes:
    import ormsgpack

    return ormsgpack.packb({"t": t, "pose": [float(pose[0]), float(pose[1]), float(pose[2])]})


def main(args) -> int:
    """``rsal tour`` (registered by :mod:`rsal.mapping.cli`)."""
    tty = sys.stderr.isatty()

    def progress(st: TourStats) -> None:
        line = f"rsal tour: {st.sim_seconds:6.1f} s simulated, {st.scans} scans, {st.distance:.1f} m, {st.loops} loops"
        print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)

    st = run_tour(
        args.world,
        args.output,
        robot=args.robot,
        minutes=args.minutes,
        waypoints=args.waypoints,
        seed=args.seed,
        progress=progress,
    )
    if tty:
        print(file=sys.stderr)
    print(
        f"rsal tour: wrote {args.output}: {st.sim_seconds:.0f} s simulated, {st.scans} scans, "
        f"{st.distance:.1f} m driven, {st.waypoints} waypoints, {st.loops} loop(s) closed back at the start, "
        f"{st.wall:.1f} s wall"
    )
    return 0
