"""The map tools' command line: ``rsal map --from-world`` and ``rsal map align`` (docs/mapping.md).

``rsal map`` hands these argument lists to :func:`main` unchanged::

    --from-world WORLD -o maps/NAME [--resolution R] [--no-models]
    align BUILT.yaml PLAN.(png|yaml) [-o OUT] [--plan-resolution R] [--plan-origin X Y]
          [--yaw-step DEG]

``--from-world`` writes ``NAME.png`` + ``NAME.yaml`` (ROS map_server format) from the world's
floorplan and static models (:func:`rsal.mapping.tools.from_world`). ``align`` prints the rigid
transform that lays the built map onto the plan, ``plan = R(yaw) built + (x, y)``, and its residual
(:func:`rsal.mapping.tools.align`); with ``-o`` it also writes the built map moved into the plan's
frame (axis-aligned, whatever origin yaw the inputs had). A bare PNG plan is placed by
``--plan-resolution`` (default: the built map's) and ``--plan-origin`` (default 0 0); dark pixels
(below half brightness) are its walls.

Progress goes to stderr, results to stdout (one ``key=value`` line). Exit codes: 0 done, 1 a bad
input (one line on stderr naming the file and a fix), 2 a bad command line (one line).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from .mapyaml import MapFileError, is_map_yaml, read_map, write_map
from .tools import Grid, align, from_world, resample, world_spec

__all__ = ["main"]

PROG = "rsal map"


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, not argparse's usage block; main() returns the 2
        print(f"{self.prog}: {message}; see '{self.prog} --help'", file=sys.stderr)
        raise SystemExit(2)


def _parsers() -> tuple[_Parser, _Parser]:
    fw = _Parser(prog=f"{PROG} --from-world", description="Write a world file's static geometry as a map.")
    fw.add_argument("--from-world", dest="world", required=True, metavar="WORLD", help="a .world or YAML world")
    fw.add_argument("-o", "--output", required=True, metavar="maps/NAME", help="writes NAME.png and NAME.yaml")
    fw.add_argument("--resolution", type=float, metavar="R", help="m per cell (default: the floorplan's)")
    fw.add_argument("--no-models", action="store_true", help="only the floorplan, not the static models")
    al = _Parser(prog=f"{PROG} align", description="Align a built map to a floor plan (rigid transform).")
    al.add_argument("built", metavar="BUILT.yaml", help="the built map (map_server YAML)")
    al.add_argument("plan", metavar="PLAN", help="the floor plan: map_server YAML or a PNG")
    al.add_argument("-o", "--output", metavar="OUT", help="also write the aligned built map as OUT.png/.yaml")
    al.add_argument("--plan-resolution", type=float, metavar="R", help="m per pixel of a PNG plan")
    al.add_argument("--plan-origin", type=float, nargs=2, metavar=("X", "Y"), help="lower-left of a PNG plan, m")
    al.add_argument("--yaw-step", type=float, default=2.0, metavar="DEG", help="coarse heading step (default 2)")
    return fw, al


def main(argv: list[str] | None = None) -> int:
    """Run one map tool; returns the exit code (module docstring)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    fw, al = _parsers()
    try:
        if argv[:1] == ["align"]:
            return _align(al, al.parse_args(argv[1:]))
        if any(a == "--from-world" or a.startswith("--from-world=") for a in argv):
            return _from_world(fw.parse_args(argv))
        _Parser(prog=PROG).error("expected 'align BUILT.yaml PLAN' or '--from-world WORLD -o maps/NAME'")
    except SystemExit as e:  # --help (0) or a bad command line (2): returned, not raised
        return e.code if isinstance(e.code, int) else 2
    except (MapFileError, OSError) as e:
        print(f"{PROG}: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # the simulator's WorldFileError (it imports nothing of ours)
        from simulator.errors import SimulatorError

        if isinstance(e, SimulatorError):
            print(f"{PROG}: {e}", file=sys.stderr)
            return 1
        raise


def _say(text: str) -> None:
    print(f"{PROG}: {text}", file=sys.stderr, flush=True)


def _from_world(a: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    spec = world_spec(a.world)
    out = Path(a.output)
    out = out.with_suffix("") if out.suffix.lower() in (".yaml", ".yml", ".png") else out
    fp = spec.floorplan
    mine = {Path(p).resolve() for p in (fp.bitmap, fp.mapfile) if p is not None} if fp is not None else set()
    if {out.with_suffix(".png").resolve(), out.with_suffix(".yaml").resolve()} & mine:
        raise MapFileError(f"-o {a.output}: would overwrite the world's own floorplan; choose another name")
    grid, spec = from_world(spec, a.resolution, models=not a.no_models, progress=_say)
    png, yml = write_map(out, grid.occupancy, grid.resolution, (*grid.origin, 0.0))
    h, w = grid.occupancy.shape
    occ = float(grid.occupied.mean())
    _say(f"wrote {png} and {yml} in {time.perf_counter() - t0:.2f} s")
    print(
        f"map={yml} width={w} height={h} resolution={grid.resolution:g} "
        f"origin_x={grid.origin[0]:g} origin_y={grid.origin[1]:g} occupied={occ:.4f}"
    )
    return 0


def _load(path: str, resolution: float | None, origin, what: str) -> Grid:
    if is_map_yaml(path):
        if resolution is not None or origin is not None:
            raise MapFileError(f"{path}: a map_server YAML places itself; drop --plan-resolution/--plan-origin")
        m = read_map(path)
        return Grid(m.occupancy.astype(np.float64), m.resolution, (m.origin[0], m.origin[1]), m.origin[2])
    from PIL import Image, UnidentifiedImageError

    if not Path(path).is_file():
        raise MapFileError(f"{path}: no such {what}; check the path (a map_server .yaml or a .png)")
    try:
        with Image.open(path) as im:
            grey = np.asarray(im.convert("L"), dtype=np.float64)
    except (UnidentifiedImageError, OSError, ValueError) as e:
        raise MapFileError(f"{path}: not a readable image ({e}); give a PNG or a map_server .yaml") from None
    res = 0.05 if resolution is None else resolution
    if not (math.isfinite(res) and res > 0):
        raise MapFileError(f"--plan-resolution {res!r} must be positive metres per pixel")
    o = (0.0, 0.0) if origin is None else (float(origin[0]), float(origin[1]))
    return Grid(np.where(grey < 127.5, 1.0, 0.0), float(res), o)


def _align(parser: _Parser, a: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    if not is_map_yaml(a.built):
        raise MapFileError(f"{a.built}: the built map must be a map_server .yaml (as 'rsal map' writes)")
    if not (math.isfinite(a.yaw_step) and 0.1 <= a.yaw_step <= 30):
        parser.error(f"--yaw-step {a.yaw_step} must be between 0.1 and 30 degrees")
    built = _load(a.built, None, None, "built map")
    res = a.plan_resolution
    if res is None and not is_map_yaml(a.plan):
        res = built.resolution  # a bare PNG: as fine as the built map unless told
    plan = _load(a.plan, res, a.plan_origin, "plan")
    r = align(built, plan, yaw_step=math.radians(a.yaw_step), progress=_say)
    _say(f"aligned in {time.perf_counter() - t0:.2f} s")
    if a.output:
        moved = resample(built, r, snap_to=plan if plan.resolution == built.resolution else None)
        png, yml = write_map(a.output, moved.occupancy, moved.resolution, (*moved.origin, 0.0))
        _say(f"wrote the aligned map {png} and {yml}")
    print(
        f"x={r.x:.4f} y={r.y:.4f} yaw_deg={math.degrees(r.yaw):.3f} residual={r.residual:.4f} "
        f"within_0.10m={r.inliers:.4f} walls={r.points}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
