"""``rsal map`` and ``rsal tour``: build a floor map from a recording; make a simulated recording.

``rsal map RUN.mcap -o maps/NAME`` reads one robot's scans and odometry (:mod:`.reader`), runs graph
SLAM (:mod:`.slam`: ICP scan matching, keyframes, loop closure, pose-graph optimisation), builds
an occupancy grid by log-odds ray casting (:mod:`.occupancy`) and writes ``NAME.png`` +
``NAME.yaml`` (ROS map_server format, :mod:`.mapyaml`) and ``NAME.trajectory.png`` (the trajectory
drawn on the map). ``rsal map align ...`` and ``rsal map --from-world WORLD`` are the map tools of
:mod:`rsal.mapping.toolcli`, dispatched from here. ``rsal tour`` is :mod:`.tour`. Usage:
docs/mapping.md.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import RsalError

__all__ = ["register", "main", "build_map"]


class MapError(RsalError, ValueError):
    """A bad ``rsal map`` argument; one line."""


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="rsal map",
        description="Build a 2D occupancy grid map (ROS map_server PNG + YAML) from one robot's laser scans and "
        "odometry in a recording: scan matching, loop closure, pose-graph optimisation. Also: "
        "'rsal map align BUILT.yaml PLAN.png', 'rsal map --from-world WORLD -o maps/NAME'.",
    )
    ap.add_argument("file", metavar="RUN.mcap", help="a recording of 'rsal record' or 'rsal tour'")
    ap.add_argument(
        "-o", "--output", required=True, metavar="maps/NAME", help="writes NAME.png, NAME.yaml, NAME.trajectory.png"
    )
    ap.add_argument("--robot", help="the robot whose scans to use (default: the only one with a laser)")
    ap.add_argument("--resolution", type=float, default=0.05, help="metres per pixel (default 0.05)")
    ap.add_argument(
        "--initial-pose",
        type=float,
        nargs=3,
        metavar=("X", "Y", "YAW"),
        help="the robot's pose at the first scan in the map frame (m, m, rad; default 0 0 0)",
    )
    return ap


def main(argv: list[str]) -> int:
    if argv and (argv[0] == "align" or "--from-world" in argv):
        try:
            from . import toolcli  # the map tools
        except ImportError:
            raise MapError(
                "'rsal map align' and '--from-world' need rsal.mapping.toolcli, which this "
                "installation lacks; update rsal"
            ) from None
        return toolcli.main(argv)
    args = _parser().parse_args(argv)
    if not (args.resolution > 0 and math.isfinite(args.resolution)) or args.resolution > 1.0:
        raise MapError(f"--resolution {args.resolution:g}: give metres per pixel in (0, 1], e.g. 0.05")
    if args.initial_pose is not None and not all(math.isfinite(v) for v in args.initial_pose):
        raise MapError("--initial-pose: give three finite numbers X Y YAW (m, m, rad)")
    return build_map(
        args.file, args.output, robot=args.robot, resolution=args.resolution, initial_pose=args.initial_pose
    )


def build_map(
    path: str,
    output: str,
    *,
    robot: str | None = None,
    resolution: float = 0.05,
    initial_pose=None,
    quiet: bool = False,
) -> int:
    from .mapyaml import write_map
    from .occupancy import occupancy_grid
    from .posegraph import compose
    from .reader import read_scans
    from .slam import run_slam

    t0 = time.perf_counter()
    sc = read_scans(path, robot)
    tty = sys.stderr.isatty() and not quiet

    def progress(i, n, kf, loops):
        if quiet:
            return
        w = 30
        f = int(w * i / max(n, 1))
        line = f"rsal map: [{'#' * f}{'.' * (w - f)}] {i}/{n} scans, {kf} keyframes, {loops} loop closures"
        print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)

    res = run_slam(
        sc,
        initial_pose if initial_pose is not None else (0.0, 0.0, 0.0),
        progress=progress,
        progress_every=0.5 if tty else 5.0,
    )
    if tty:
        print(file=sys.stderr)
    sensor = compose(res.poses, np.broadcast_to(sc.mount, res.poses.shape))
    occ, origin = occupancy_grid(sensor, sc.ranges[res.used], sc.angles, sc.range_min, sc.range_max, resolution)
    stem = Path(output)
    if stem.suffix in (".yaml", ".png"):
        stem = stem.with_suffix("")
    png, yml = write_map(stem, occ[::-1], resolution, (origin[0], origin[1], 0.0))
    traj = stem.with_name(stem.name + ".trajectory.png")
    _draw_trajectory(
        traj,
        occ,
        origin,
        resolution,
        res.poses,
        [res.keyframes[j] for j, _ in res.loops],
        [res.keyframes[k] for _, k in res.loops],
    )
    wall = time.perf_counter() - t0
    if not quiet:
        loops = (
            f"{len(res.loops)} loop closures ({res.loop_tries} tried)"
            if res.loops
            else f"no loop was closed ({res.loop_tries} tried): the map rests on scan matching alone"
        )
        print(
            f"rsal map: {yml} and {png} ({occ.shape[1]} x {occ.shape[0]} px at {resolution:g} m), {traj}; "
            f"{len(res.used)} of {len(sc.t)} scans used, {len(res.keyframes)} keyframes, {loops}, "
            f"final residual {res.residual * 1000:.1f} mm RMS, {wall:.1f} s"
        )
    return 0


def _draw_trajectory(path: Path, occ, origin, res, poses, loop_a, loop_b) -> None:
    """The map in grey with the trajectory in red and each loop closure as a blue line."""
    from PIL import Image, ImageDraw

    g = np.full(occ.shape, 205, np.uint8)
    g[(occ >= 0) & (occ < 0.196)] = 254
    g[occ > 0.65] = 0
    img = Image.fromarray(g[::-1], mode="L").convert("RGB")
    d = ImageDraw.Draw(img)
    h = occ.shape[0]

    def px(p):
        return ((p[0] - origin[0]) / res, h - (p[1] - origin[1]) / res)

    d.line([px(p) for p in poses], fill=(220, 0, 0), width=2)
    for a, b in zip(loop_a, loop_b, strict=True):
        d.line([px(poses[a]), px(poses[b])], fill=(0, 80, 255), width=1)
    x, y = px(poses[0])
    d.ellipse([x - 4, y - 4, x + 4, y + 4], outline=(0, 160, 0), width=2)
    img.save(path)


def _run_map(args) -> int:
    return main(args.argv)


def _run_tour(args) -> int:
    from .tour import main as tour_main

    if not (args.minutes > 0 and math.isfinite(args.minutes)):
        raise MapError(f"--minutes {args.minutes:g}: give a positive number of minutes")
    return tour_main(args)


def register(sub) -> None:
    m = sub.add_parser(
        "map",
        help="build a floor map from a recording (graph SLAM); map tools",
        add_help=False,
        description=_parser().description,
    )
    m.add_argument("argv", nargs=argparse.REMAINDER)
    m.set_defaults(func=_run_map)
    t = sub.add_parser(
        "tour",
        help="drive a simulated robot around a world and write a recording",
        description="Drive one robot of WORLD along a loop of waypoints in the simulator (as fast as it "
        "goes, odometry drifting with the world's odom_error) and write its laser, odometry and true "
        "pose as an MCAP recording, as 'rsal record' would.",
    )
    t.add_argument("world", metavar="WORLD", help="a .world or .yaml world with a floorplan")
    t.add_argument("-o", "--output", required=True, metavar="RUN.mcap")
    t.add_argument("--robot", help="the robot to drive (default: the first with a laser)")
    t.add_argument("--minutes", type=float, default=2.0, help="simulated minutes (default 2)")
    t.add_argument("--waypoints", metavar="FILE", help="'x y' per line (default: spread over the free space)")
    t.add_argument("--seed", type=int, default=1, help="random seed of the simulation (default 1)")
    t.set_defaults(func=_run_tour)
