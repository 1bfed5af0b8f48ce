"""Simulator throughput: N Pioneers with an URG-04LX laser at 10 Hz in the 128 m swarm arena.

For each N (default 10, 100, 300, 1000) a child process builds the arena world with N robots on
random free poses, lets each wander with the reactive laser controller of
:mod:`simulator.controllers`, runs ``--sim-seconds`` of
simulated time as fast as possible, and reports simulated seconds per wall second (the real-time
factor), laser scans per wall second, and its peak resident memory. Each N runs in its own
process so peak memory is its own.

Baseline in the same run: the pure-numpy reference ray caster
(:func:`simulator.raycast.cast_fans_numpy`) casts one tick of the same lasers, and the compiled
caster's time for that tick is reported as a ratio against it. The C++ Stage figures on this
machine kind (measured: 100 robots 2.7x, 300 0.9x, 1000 0.21x real time) are printed beside ours
as ``vs_stage``.

Energy (:mod:`simulator.energy`): every robot carries the Pioneer battery and the arena has 20
chargers. Baseline in the same run: the same world and seed stepped again with the energy model
switched off (no battery drains, no charger docks, the batteries' step a no-op), reported as
``energy_ratio`` = speed with energy / without (1.0: no cost; the median over pairs of one-second
slices, the two worlds stepped alternately for ``--sim-seconds`` each, so load spikes on a shared
machine fall on both alike), beside the totals ``rtf_energy_on`` and ``rtf_energy_off``; and the
energy model's own step alone, ``energy_us_per_step`` (all robots and chargers), against the whole
step, ``energy_share``.

Output: one parseable line per figure, ``bench=simulator key=value ...``.
Usage: ``python benchmarks/bench_simulator.py [--robots 10,100,300,1000] [--sim-seconds 60]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STAGE_RTF = {100: 2.7, 300: 0.9, 1000: 0.21}  # C++ Stage, same robots/lasers/arena, this machine kind


def build_world(n: int, seed: int):
    import numpy as np

    from simulator.presets import urg04lx
    from simulator.spec import ChargerSpec, FloorplanSpec, ModelSpec, WorldSpec
    from simulator.world import World

    fp = FloorplanSpec(bitmap=ROOT / "maps" / "arena.png", resolution=0.1, origin=(-64.0, -64.0))
    probe = World(WorldSpec(floorplan=fp), seed=seed)
    grid = probe.grid
    rng = np.random.default_rng(seed)
    poses: list[tuple[float, float, float]] = []
    pts = np.empty((0, 2))
    while len(poses) < n:
        cand = rng.uniform(-62, 62, size=(4 * n, 2))
        ok = grid.clearance(cand[:, 0], cand[:, 1]) > 0.6
        for x, y in cand[ok]:
            if pts.size and np.min(np.hypot(pts[:, 0] - x, pts[:, 1] - y)) < 0.8:
                continue
            poses.append((float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
            pts = np.vstack([pts, [x, y]])
            if len(poses) == n:
                break
    models = [
        ModelSpec(
            name=f"r{i}",
            position=True,
            pose=p,
            size=(0.44, 0.38, 0.22),
            mass=23.0,
            rangers=[urg04lx()],
        )
        for i, p in enumerate(poses)
    ]
    chargers = [ChargerSpec(f"dock{i}", poses[i % n]) for i in range(20)] if n else []
    return World(WorldSpec(floorplan=fp, models=models, chargers=chargers, interval_sim=0.1, seed=seed), seed=seed)


def energy_off(world) -> None:
    """The baseline: no robot has a battery model and the batteries' step does nothing."""
    world.batteries.has[:] = False
    world.batteries.step = lambda prev, pose, dt: None


def child(n: int, sim_seconds: float, seed: int) -> dict:
    import numpy as np

    from simulator.clock import run
    from simulator.controllers import wander
    from simulator.raycast import cast_fans, cast_fans_numpy

    t_build = time.perf_counter()
    world = build_world(n, seed)
    build_s = time.perf_counter() - t_build
    world.step()  # compile/warm up
    wander(world)
    # One tick of the same lasers through the numpy reference and the compiled caster.
    f = world.sensors["ranger"].fans
    pose = world.poses[f["robot"]]
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    fans = {
        "x": pose[:, 0] + c * f["lx"] - s * f["ly"],
        "y": pose[:, 1] + s * f["lx"] + c * f["ly"],
        "th0": pose[:, 2] + f["lth"],
        "dth": f["dth"],
        "n": f["n"],
        "rmax": f["rmax"],
        "owner": f["uids"][f["robot"]],
    }
    circles = world.circles()
    k = max(1, 2000 // max(n, 1))
    t = time.perf_counter()
    for _ in range(k):
        cast_fans(world.grid, fans, circles)
    jit_tick = (time.perf_counter() - t) / k
    sub = min(n, 20)  # the numpy caster is memory hungry: time 20 robots and scale linearly
    fsub = {key: v[:sub] for key, v in fans.items()}
    t = time.perf_counter()
    cast_fans_numpy(world.grid, fsub, circles)
    numpy_tick = (time.perf_counter() - t) * n / sub

    # The energy model's step alone, on this step's poses.
    b, prev, pose = world.batteries, world.poses.copy(), world.bodies.robot_poses()
    k = 200
    t = time.perf_counter()
    for _ in range(k):
        b.step(prev, pose, 0.1)
        _ = b.empty
    energy_step = (time.perf_counter() - t) / k

    scans0 = world.steps
    stats = run(world, sim_seconds, on_step=wander)
    scans = (world.steps - scans0) * n
    # With and without energy: two worlds of the same seed stepped in alternating one-second
    # slices (whichever goes first alternates too), so the machine's load falls on both alike.
    w_on, w_off = build_world(n, seed), build_world(n, seed)
    energy_off(w_off)
    wall = {True: 0.0, False: 0.0}
    sims = {True: 0.0, False: 0.0}
    ratios = []  # per slice pair: wall time without energy / with
    for w in (w_on, w_off):
        w.step()
        wander(w)
    for i in range(max(1, int(sim_seconds))):
        pair = {}
        for on in (True, False) if i % 2 else (False, True):
            st = run(w_on if on else w_off, 1.0, on_step=wander)
            wall[on] += st.wall_seconds
            sims[on] += st.sim_seconds
            pair[on] = st.wall_seconds
        ratios.append(pair[False] / pair[True])
    rtf_on, rtf_off = sims[True] / wall[True], sims[False] / wall[False]
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {
        "robots": n,
        "sim_s": round(stats.sim_seconds, 2),
        "wall_s": round(stats.wall_seconds, 3),
        "rtf": round(stats.realtime_factor, 3),
        "scans_per_s": round(scans / stats.wall_seconds, 1),
        "peak_mb": round(peak_kb / 1024, 1),
        "build_s": round(build_s, 2),
        "caster_tick_ms": round(jit_tick * 1000, 3),
        "numpy_tick_ms": round(numpy_tick * 1000, 1),
        "caster_speedup_vs_numpy": round(numpy_tick / jit_tick, 1),
        "rtf_energy_on": round(rtf_on, 3),
        "rtf_energy_off": round(rtf_off, 3),
        "energy_ratio": round(float(np.median(ratios)), 3),
        "energy_us_per_step": round(energy_step * 1e6, 1),
        "energy_share": round(energy_step / (stats.wall_seconds / max(1, world.steps - scans0)), 4),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="10,100,300,1000", help="comma-separated robot counts")
    ap.add_argument("--sim-seconds", type=float, default=60.0, help="simulated seconds per run")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child, args.sim_seconds, args.seed)))
        return 0
    counts = [int(x) for x in args.robots.split(",") if x.strip()]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for n in counts:
        print(f"[bench] {n} robots, {args.sim_seconds:g} sim s ...", file=sys.stderr, flush=True)
        out = subprocess.run(
            [
                sys.executable,
                __file__,
                "--child",
                str(n),
                "--sim-seconds",
                str(args.sim_seconds),
                "--seed",
                str(args.seed),
            ],
            capture_output=True,
            text=True,
            env=env,
        )
        if out.returncode != 0:
            print(f"bench=simulator robots={n} error={out.stderr.strip().splitlines()[-1:]}")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        stage = STAGE_RTF.get(n)
        vs = f" vs_stage={r['rtf'] / stage:.1f}x" if stage else ""
        print(
            "bench=simulator "
            + " ".join(f"{k}={v}" for k, v in r.items())
            + f" target_rtf={'10' if n == 100 else '1' if n == 1000 else '-'}"
            + vs,
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
