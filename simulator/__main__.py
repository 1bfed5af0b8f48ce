"""``python -m simulator WORLD``: run a world headless and report how fast it ran.

Loads a Stage ``.world`` or YAML world, runs it for ``--duration`` simulated seconds, or until
the world's ``quit_time`` when that comes first (Stage's headless stop; paced at
``--speedup`` times real time, or as fast as possible with ``--fast``), optionally lets every robot
wander, prints a progress line every second and a summary: robots, simulated seconds, wall
seconds, real-time factor. User errors (a bad world file, bad flags) print one line and exit 1.
"""

from __future__ import annotations

import argparse
import math
import sys

__all__ = ["main"]


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive number")
    return v


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m simulator", description="Run a world headless and report its speed.")
    ap.add_argument("world", help="a Stage .world file or a YAML world (.yaml)")
    ap.add_argument(
        "--duration",
        type=_positive,
        default=None,
        help="simulated seconds to run (default: the world's quit_time, else 30); quit_time still stops the run",
    )
    pace = ap.add_mutually_exclusive_group()
    pace.add_argument("--speedup", type=_positive, default=None, help="times real time (default: the world's)")
    pace.add_argument("--fast", action="store_true", help="run as fast as possible")
    ap.add_argument("--seed", type=int, default=None, help="random seed (default: the world's)")
    ap.add_argument("--wander", action="store_true", help="let every robot wander with its laser")
    ap.add_argument("--quiet", action="store_true", help="no progress lines, only the summary")
    args = ap.parse_args(argv)

    from .clock import run
    from .controllers import wander
    from .errors import SimulatorError
    from .loader import load_world
    from .world import World

    try:
        spec = load_world(args.world, seed=args.seed)
        for w in spec.warnings:
            print(f"[sim] warning: {w}", file=sys.stderr)
        world = World(spec, seed=args.seed)
    except SimulatorError as e:
        print(f"python -m simulator: {e}", file=sys.stderr)
        return 1
    speedup = math.inf if args.fast else (args.speedup or spec.speedup)
    duration = args.duration if args.duration is not None else (spec.quit_time or 30.0)
    quits = spec.quit_time > 0 and spec.quit_time <= duration
    if quits:
        duration = spec.quit_time
    n = len(world.robot_names)
    pace = "as fast as possible" if math.isinf(speedup) else f"at {speedup:g}x real time"
    print(
        f"[sim] {args.world}: {n} robots, {len(world.model_names) - n} objects, "
        f"step {spec.interval_sim * 1000:g} ms, running {duration:g} s {pace}",
        flush=True,
    )

    def progress(st):
        if not args.quiet:
            print(
                f"[sim] t={st.sim_seconds:7.1f} s  wall={st.wall_seconds:6.1f} s  rtf={st.realtime_factor:6.2f}x",
                flush=True,
            )

    try:
        stats = run(world, duration, speedup=speedup, on_step=wander if args.wander else None, progress=progress)
    except KeyboardInterrupt:
        print("[sim] interrupted", file=sys.stderr)
        return 130
    if quits:
        print(f"[sim] quit_time {spec.quit_time:g} s reached at t={world.time:.1f} s: stopping", flush=True)
    print(
        f"[sim] summary: robots={n} sim_seconds={stats.sim_seconds:.1f} "
        f"wall_seconds={stats.wall_seconds:.2f} realtime_factor={stats.realtime_factor:.2f}",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
