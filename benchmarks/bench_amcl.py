"""AMCL update cost per robot: the URG-04LX laser on the floor map, 500 and 5000 particles.

A Pioneer with the URG-04LX (682 beams, 5.6 m) wanders ``--seconds`` of simulated time on
``maps/floor.world``; its odometry poses and scans are recorded once and then fed to
:class:`mrs_bridge.nav.amcl.Amcl` (tracking from the true start pose) with the particle count held
at each ``--particles`` value (``pf_min_samples = pf_max_samples``), in two modes:

* ``every_scan`` (worst case): ``update_thresh = 0``, so every 10 Hz scan runs the motion model,
  the sensor update (30 beams) and, every second scan, resampling;
* ``typical``: Player's ``update_thresh`` (0.2 m, 30 deg); most scans find no update due.

Per scan it times ``odometry() + sensor()`` (``filter``) and what the ``amcl`` driver adds after an
update (``estimate()``, ``hypotheses()``); p50 and p99 are over the scans that ran an update, and
``robots_per_core`` is how many robots with 10 Hz scans one core sustains at the mean cost per scan
(filter plus driver work). Baseline in the same run: the numpy reference of the likelihood-field
kernel (:func:`~mrs_bridge.nav.amcl.likelihood_field_numpy`) against the compiled one on the same
particles and beams.

Output: one parseable line per figure (``bench=amcl key=value ...``), then a table.
Usage: ``python benchmarks/bench_amcl.py [--particles 500,5000] [--seconds 60] [--quick]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np

from mrs_bridge.nav.amcl import Amcl, AmclParams, likelihood_field_jit, likelihood_field_numpy
from mrs_bridge.nav.grid import NavGrid
from simulator import load_world
from simulator.controllers import wander
from simulator.world import World

ROOT = Path(__file__).resolve().parent.parent

SCAN_HZ = 10.0


def record(seconds: float, seed: int):
    """Wander the floor with r1 (URG-04LX); return the grid, start pose, beam geometry, and the
    odometry pose and scan of every step."""
    world = World(load_world(ROOT / "maps" / "floor.world"), seed=seed)
    for name in ("r0", "r2"):
        world.remove_model(name)
    g = world.grid
    grid = NavGrid.from_occupancy(g.occupied, g.resolution, g.origin)
    spec = world.rangers("r1")[1]
    s = spec.sensors[0]
    px, py, pa = spec.pose
    bearings = pa + s.pose[2] - s.fov / 2 + np.arange(s.samples) * s.fov / (s.samples - 1)
    origins = np.tile([px + s.pose[0], py + s.pose[1]], (s.samples, 1))
    start = world.get_pose("r1")
    steps = []
    for _ in range(int(round(seconds / world.spec.interval_sim))):
        wander(world)
        world.step()
        steps.append((world.odometry("r1"), np.array(world.ranger("r1", 1).ranges)))
    return grid, start, (bearings, origins, s.range_min, s.range_max), steps


def run(grid, start, beams, steps, n: int, every_scan: bool, seed: int, warmup: int) -> dict:
    params = AmclParams(
        pf_min_samples=n,
        pf_max_samples=n,
        init_pose=start,
        init_pose_var=(0.01, 0.01, 0.003),
        update_thresh=(0.0, 0.0) if every_scan else AmclParams().update_thresh,
        seed=seed,
    )
    amcl = Amcl(grid, params)
    b, o, rmin, rmax = beams
    filt, driver, all_scans = [], [], []
    for i, (odom, ranges) in enumerate(steps):
        t0 = time.perf_counter()
        amcl.odometry(odom)
        updated = amcl.sensor(ranges, b, o, rmin, rmax)
        t1 = time.perf_counter()
        if updated:  # what the amcl driver does after each update
            amcl.estimate()
            amcl.hypotheses()
        t2 = time.perf_counter()
        if i < warmup:
            continue
        all_scans.append(t2 - t0)
        if updated:
            filt.append(t1 - t0)
            driver.append(t2 - t1)
    f, d, a = (np.array(x) * 1e3 for x in (filt, driver, all_scans))
    mean_scan = float(a.mean())
    return {
        "particles": n,
        "mode": "every_scan" if every_scan else "typical",
        "updates_per_s": round(len(f) / (len(a) / SCAN_HZ), 2),
        "filter_p50_ms": round(float(np.percentile(f, 50)), 3),
        "filter_p99_ms": round(float(np.percentile(f, 99)), 3),
        "driver_p50_ms": round(float(np.percentile(d, 50)), 3),
        "driver_p99_ms": round(float(np.percentile(d, 99)), 3),
        "mean_ms_per_scan": round(mean_scan, 3),
        "robots_per_core": int(1000.0 / (SCAN_HZ * mean_scan)),
    }


def kernel_baseline(grid, start, beams, steps, n: int, reps: int, seed: int) -> dict:
    """Compiled vs numpy likelihood-field kernel, 30 beams of a recorded scan, ``n`` particles."""
    rng = np.random.default_rng(seed)
    b, o, _, rmax = beams
    z = steps[len(steps) // 2][1].astype(float)
    ok = np.flatnonzero(z < rmax - 1e-3)
    idx = ok[np.linspace(0, ok.size - 1, 30).round().astype(int)]
    lx, ly = o[idx, 0] + z[idx] * np.cos(b[idx]), o[idx, 1] + z[idx] * np.sin(b[idx])
    q = np.asarray(start) + rng.normal(0, [0.2, 0.2, 0.05], (n, 3))
    amcl = Amcl(grid, AmclParams(pf_min_samples=10, pf_max_samples=10, seed=seed))
    table = amcl._field(rmax).reshape(-1)
    args = (q[:, 0].copy(), q[:, 1].copy(), q[:, 2].copy(), lx, ly, 1, table, *grid.origin, 1 / grid.resolution)
    args = (*args, grid.width, grid.height)
    out = {}
    for name, fn in (("jit", likelihood_field_jit), ("numpy", likelihood_field_numpy)):
        fn(*args)
        t = time.perf_counter()
        for _ in range(reps):
            fn(*args)
        out[name] = (time.perf_counter() - t) / reps * 1e3
    return {
        "particles": n,
        "kernel_jit_ms": round(out["jit"], 3),
        "kernel_numpy_ms": round(out["numpy"], 3),
        "speedup_vs_numpy": round(out["numpy"] / out["jit"], 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", default="500,5000", help="comma-separated particle counts")
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds of recorded driving")
    ap.add_argument("--warmup", type=int, default=20, help="scans not timed at the start of each run")
    ap.add_argument("--reps", type=int, default=50, help="repetitions of the kernel baseline")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="15 s of driving, 10 kernel repetitions")
    args = ap.parse_args()
    if args.quick:
        args.seconds, args.reps = min(args.seconds, 15.0), min(args.reps, 10)
    numba.set_num_threads(1)  # one core: the figure is robots per core
    counts = [int(x) for x in args.particles.split(",") if x.strip()]
    print(f"[bench] recording {args.seconds:g} s of driving ...", file=sys.stderr, flush=True)
    grid, start, beams, steps = record(args.seconds, args.seed)
    rows = []
    for n in counts:
        base = kernel_baseline(grid, start, beams, steps, n, args.reps, args.seed)
        print("bench=amcl " + " ".join(f"{k}={v}" for k, v in base.items()), flush=True)
        for every_scan in (True, False):
            r = run(grid, start, beams, steps, n, every_scan, args.seed, args.warmup)
            print("bench=amcl " + " ".join(f"{k}={v}" for k, v in r.items()), flush=True)
            rows.append(r)
    print()
    head = (
        "particles",
        "mode",
        "updates/s",
        "filter p50",
        "filter p99",
        "driver p50",
        "driver p99",
        "ms/scan",
        "robots",
    )
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for r in rows:
        vals = [r[k] for k in ("particles", "mode", "updates_per_s", "filter_p50_ms", "filter_p99_ms")]
        vals += [r[k] for k in ("driver_p50_ms", "driver_p99_ms", "mean_ms_per_scan", "robots_per_core")]
        print("| " + " | ".join(str(v) for v in vals) + " |")
    print("\n(ms; filter = odometry() + sensor() incl. resampling; driver = estimate() + hypotheses() after an update;")
    print(f" robots = robots with {SCAN_HZ:g} Hz scans one core sustains at the mean cost per scan)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
