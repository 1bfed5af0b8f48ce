"""The swarm's behaviour cycle for N robots of one host: per robot vs the vectorised host step.

:class:`agents.scenarios.swarm.behaviour.SwarmPioneer` robots (an 8-sonar ring each, wall-following
with the disperse layer) on real device proxies over an in-memory fabric
(:class:`rsal.testing.FakeFabric`: no network, a command is recorded instead of put), fed random
scans and poses each cycle. The baseline, in the same run on the same data: every robot's own
``update()`` (the per-robot cycle); then :class:`agents.scenarios.swarm.vector.HostStep`, one step
for all. Figures: CPU microseconds per robot cycle (``time.thread_time``), so a machine loaded by
other work changes them little; the network's own cost per command (a Zenoh put, ~6-10 us) is not
in them.

Output: ``bench=swarm_step key=value`` lines. Usage:
``python benchmarks/bench_swarm_step.py --robots 100,300,1000 --cycles 50``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

SONAR_ANGLES = np.radians([90, 50, 30, 10, -10, -30, -50, -90])
SONAR_GEOMETRY = {"kind": "sonar", "pose": [0.0, 0.0, 0.0], "sensors": [{"pose": [0.1, 0.0, a]} for a in SONAR_ANGLES]}


def crowd(fab, n: int):
    from agents.scenarios.swarm.behaviour import SwarmPioneer
    from rsal.devices import Position2d, Sonar

    robots = []
    for i in range(n):
        pos = fab.device(Position2d, f"r{i}:position2d:0", {"max_speed": [0.5, 1.0]})
        sonar = fab.device(Sonar, f"r{i}:sonar:0", SONAR_GEOMETRY)
        r = SwarmPioneer([pos, sonar], name=f"r{i}", period=0.1, laser=False)
        r.set_wallfollow(True)
        robots.append(r)
    return robots


def run(n: int, cycles: int, warmup: int, seed: int) -> dict:
    from agents.scenarios.swarm.vector import HostStep
    from rsal.clock import clock
    from rsal.msgs import Position2dData, RangerData
    from rsal.testing import FakeFabric

    rng = np.random.default_rng(seed)
    fab = FakeFabric()
    robots = crowd(fab, n)
    step = HostStep(lambda: clock().now())
    cpu = {"per_robot": 0.0, "vector": 0.0}
    for c in range(warmup + cycles):
        for r in robots:  # the network's samples: not timed
            pose = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)), float(rng.uniform(-3, 3)))
            fab.push(r.position2d, Position2dData(0.0, pose, (0.0, 0.0, 0.0), False))
            ranges = rng.uniform(0.05, 5.0, 8)
            ranges[rng.random(8) < 0.4] = 5.0
            fab.push(r.sonars[0], RangerData(0.0, ranges, 0.0, 0.0, 0.1, 5.0))
        t0 = time.thread_time()
        for r in robots:
            r.update()
        t1 = time.thread_time()
        rest = step(robots)
        t2 = time.thread_time()
        if c >= warmup:
            if rest:
                raise RuntimeError(f"{len(rest)} robots were not taken by the vectorised step")
            cpu["per_robot"] += t1 - t0
            cpu["vector"] += t2 - t1
        fab.sent.clear()
    per = 1e6 * cpu["per_robot"] / (cycles * n)
    vec = 1e6 * cpu["vector"] / (cycles * n)
    return {
        "robots": n,
        "cycles": cycles,
        "per_robot_us": round(per, 1),
        "vector_us": round(vec, 1),
        "speedup": round(per / vec, 1) if vec else None,
        "cores_at_10hz_per_robot": round(n * 10 * per * 1e-6, 3),
        "cores_at_10hz_vector": round(n * 10 * vec * 1e-6, 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="100,300,1000", help="comma-separated robot counts")
    ap.add_argument("--cycles", type=int, default=50, help="measured cycles per count")
    ap.add_argument("--warmup", type=int, default=3, help="cycles before measuring (the first learns the geometry)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    try:
        counts = [int(x) for x in args.robots.split(",") if x.strip()]
    except ValueError:
        sys.exit(f"bench_swarm_step: --robots {args.robots!r} must be comma-separated integers, e.g. 100,1000")
    if args.cycles < 1 or args.warmup < 1 or any(n < 1 for n in counts):
        sys.exit("bench_swarm_step: --robots, --cycles and --warmup must be at least 1")
    for n in counts:
        r = run(n, args.cycles, args.warmup, args.seed)
        print("bench=swarm_step " + " ".join(f"{k}={v}" for k, v in r.items()), flush=True)


if __name__ == "__main__":
    main()
