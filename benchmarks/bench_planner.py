"""Global planner speed: Wavefront plans on the floor map and the 128 m swarm arena.

For each map (``floor``: 1200 x 400 cells at 0.05 m; ``arena``: 1280 x 1280 cells at 0.1 m) the
configuration space is built once (timed), then ``--pairs`` random start/goal pairs (fixed seed)
in the largest connected region of allowed cells are planned ``--repeat`` times each from a
fresh wave (a new goal) after ``--warmup`` plans, with the thesis's Pioneer settings
(robot_radius 0.25 m, safety_dist 0.3 m, max_radius 1 m, dist_penalty 1). Reported: p50 and max
planning time over the pairs (each pair's best of its repeats), path lengths, the cells the
search settled, and the time to replan to the same goal from a start up to 3 m off the path
(the executive's replanning case: the kept wave is continued).

Baseline in the same run: the full wavefront over the whole map from the same goals, as Player's
driver computes it (:meth:`mrs_bridge.nav.wavefront.Wavefront.potential`: the same compiled
Dijkstra without the early stop at the start), reported as ``full_p50_ms`` and the ratio.

Output: one parseable line per map, ``bench=planner key=value ...``, then a table.
Usage: ``python benchmarks/bench_planner.py [--maps floor,arena] [--pairs 20] [--quick]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

MAPS = {
    "floor": ("floor.png", 0.05, (-31.475, -7.8)),
    "arena": ("arena.png", 0.1, (-64.0, -64.0)),
}


def run_map(name: str, pairs: int, repeat: int, warmup: int, full: int, seed: int) -> dict:
    from scipy import ndimage

    from mrs_bridge.nav.grid import NavGrid
    from mrs_bridge.nav.wavefront import Wavefront
    from simulator.gridmap import GridMap

    image, res, origin = MAPS[name]
    gm = GridMap.from_image(ROOT / "maps" / image, res, origin)
    grid = NavGrid.from_occupancy(gm.occupied, res, origin)
    t = time.perf_counter()
    wf = Wavefront(grid, robot_radius=0.25, safety_dist=0.3, max_radius=1.0, dist_penalty=1.0)
    build_s = time.perf_counter() - t

    labels, _ = ndimage.label(wf.allowed)
    biggest = np.bincount(labels.ravel())[1:].argmax() + 1
    iy, ix = np.nonzero(labels == biggest)
    rng = np.random.default_rng(seed)
    k = rng.integers(len(ix), size=(pairs + warmup, 2))
    x, y = grid.cell_to_world(ix, iy)
    pts = [((x[a], y[a]), (x[b], y[b])) for a, b in k]

    for s, g in pts[:warmup]:
        wf.plan(s, g)
    times, replans, lengths, settled, straight = [], [], [], [], []
    for s, g in pts[warmup:]:
        best = float("inf")
        for _ in range(repeat):
            wf.reset()  # a new goal: a fresh wave
            t = time.perf_counter()
            plan = wf.plan(s, g)
            best = min(best, time.perf_counter() - t)
        times.append(best)
        lengths.append(plan.length)
        settled.append(wf.last_expanded)
        straight.append(float(np.hypot(g[0] - s[0], g[1] - s[1])))
        # The robot strays up to 3 m off its path and replans to the same goal.
        for _ in range(100):
            p = plan.path[rng.integers(len(plan.path))] + rng.uniform(-3.0, 3.0, 2)
            cx, cy = grid.world_to_cell(p[0], p[1])
            if grid.in_bounds_cell(cx, cy) and labels[cy, cx] == biggest:
                t = time.perf_counter()
                wf.plan(p, g)
                replans.append(time.perf_counter() - t)
                break
    full_t = []
    for s, g in pts[warmup : warmup + full]:
        wf.reset()
        wf.plan(s, g)
        t = time.perf_counter()
        wf.potential()
        full_t.append(time.perf_counter() - t)
    tm = np.array(times) * 1000
    rp = np.array(replans) * 1000
    p50 = float(np.median(tm))
    full_p50 = float(np.median(full_t)) * 1000 if full_t else float("nan")
    return {
        "map": name,
        "cells": grid.width * grid.height,
        "build_ms": round(build_s * 1000, 1),
        "pairs": pairs,
        "plan_p50_ms": round(p50, 2),
        "plan_max_ms": round(float(tm.max()), 2),
        "plan_mean_ms": round(float(tm.mean()), 2),
        "replan_p50_ms": round(float(np.median(rp)), 2),
        "replan_max_ms": round(float(rp.max()), 2),
        "length_p50_m": round(float(np.median(lengths)), 1),
        "length_max_m": round(float(np.max(lengths)), 1),
        "detour_max": round(float(np.max(np.array(lengths) / np.maximum(straight, 1e-9))), 2),
        "settled_p50": int(np.median(settled)),
        "settled_max": int(np.max(settled)),
        "full_p50_ms": round(full_p50, 1),
        "full_over_plan": round(full_p50 / p50, 1) if full_t else float("nan"),
        "plans_per_s_1core": round(1000.0 / float(tm.mean()), 0),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", default="floor,arena", help="comma-separated: floor, arena")
    ap.add_argument("--pairs", type=int, default=20, help="random start/goal pairs per map")
    ap.add_argument("--repeat", type=int, default=3, help="plans per pair (the best is kept)")
    ap.add_argument("--warmup", type=int, default=3, help="untimed plans first (JIT load, caches)")
    ap.add_argument("--full", type=int, default=5, help="pairs whose full-map wavefront is timed as baseline")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="5 pairs, 1 repeat, 2 baseline wavefronts")
    args = ap.parse_args()
    if args.quick:
        args.pairs, args.repeat, args.full = 5, 1, 2
    names = [m.strip() for m in args.maps.split(",") if m.strip()]
    for m in names:
        if m not in MAPS:
            print(f"unknown map {m!r}; choose from {', '.join(MAPS)}", file=sys.stderr)
            return 1
    rows = []
    for m in names:
        print(f"[bench] {m}: {args.pairs} pairs x {args.repeat} ...", file=sys.stderr, flush=True)
        r = run_map(m, args.pairs, args.repeat, args.warmup, min(args.full, args.pairs), args.seed)
        rows.append(r)
        print("bench=planner " + " ".join(f"{k}={v}" for k, v in r.items()), flush=True)
    cols = [
        ("map", "map"),
        ("cells", "cells"),
        ("build ms", "build_ms"),
        ("p50 ms", "plan_p50_ms"),
        ("max ms", "plan_max_ms"),
        ("replan p50", "replan_p50_ms"),
        ("replan max", "replan_max_ms"),
        ("len p50 m", "length_p50_m"),
        ("settled p50", "settled_p50"),
        ("full wave ms", "full_p50_ms"),
        ("full/plan", "full_over_plan"),
    ]
    widths = [max(len(h), *(len(str(r[k])) for r in rows)) for h, k in cols]
    print()
    print("  ".join(h.rjust(w) for (h, _), w in zip(cols, widths, strict=True)))
    for r in rows:
        print("  ".join(str(r[k]).rjust(w) for (_, k), w in zip(cols, widths, strict=True)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
