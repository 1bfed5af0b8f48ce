"""Tracking robots between their position broadcasts: last-message hold vs the Kalman tracker.

Ground truth: ``--robots`` Pioneers wander in the 128 m swarm arena of
:mod:`benchmarks.bench_simulator` (the simulator's reactive laser controller, 0.5 m/s, turning
away from walls and each other) for ``--sim-seconds`` simulated seconds, stepped at 10 Hz. Each
robot broadcasts its true pose at ``--rate`` Hz (random phase per robot), and each message arrives
after a delay drawn uniformly from ``--delay`` (min,max seconds: the fabric's latency plus the
agent's loop). With ``--motion curvy`` each robot instead drives 0.4 m/s on a turn rate drawn
anew from [-0.8, 0.8] rad/s every 1-4 s (a hard case for a constant-velocity model: it always turns).
At every step an observer estimates every robot's pose now in two ways:

* **hold** (the baseline, what agents did before): the last message received;
* **kalman**: :class:`rsal.tracking.PoseTracker` fed each message at its reception time (what an
  agent knows), predicting to now.

Reported over all robots and steps after a warm-up: mean and 95th-percentile position error (m),
mean yaw error (deg), and the ratio hold / kalman in the same run; plus the tracker's cost per
``update`` and per ``predict`` (microseconds).

Output: one parseable line per figure, ``bench=tracking key=value ...``.
Usage: ``python benchmarks/bench_tracking.py [--motion wander|curvy] [--robots 20] [--sim-seconds 120]
[--rate 2] [--delay 0.02,0.15]``
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_simulator import build_world  # noqa: E402

from rsal.tracking import PoseTracker  # noqa: E402


def run(
    robots: int, sim_seconds: float, rate: float, delay: tuple[float, float], warmup: float, seed: int, motion: str
) -> dict:
    from simulator.controllers import wander

    rng = np.random.default_rng(seed)
    world = build_world(robots, seed)
    names = world.robot_names
    dt = world.spec.interval_sim
    period = 1.0 / rate
    next_send = rng.uniform(0.0, period, robots)
    inbox: list[tuple[float, int, tuple[float, float, float]]] = []  # (arrival, robot, pose)
    held: list[tuple[float, float, float] | None] = [None] * robots
    trackers = [PoseTracker() for _ in range(robots)]
    err_hold, err_kf, yaw_hold, yaw_kf = [], [], [], []
    t_update = t_predict = 0.0
    n_update = n_predict = 0
    next_turn = np.zeros(robots)
    t = 0.0
    while t < sim_seconds:
        if motion == "wander":
            wander(world)
        else:
            for i in np.nonzero(next_turn <= t)[0]:
                world.set_velocity(names[i], 0.4, float(rng.uniform(-0.8, 0.8)))
                next_turn[i] = t + rng.uniform(1.0, 4.0)
        world.step()
        t += dt
        truth = world.poses[:, :3].copy()
        for i in np.nonzero(next_send <= t)[0]:
            arrival = t + rng.uniform(*delay)
            inbox.append((arrival, int(i), tuple(float(v) for v in truth[i])))
            next_send[i] += period
        inbox.sort()
        while inbox and inbox[0][0] <= t:
            arrival, i, pose = inbox.pop(0)
            held[i] = pose
            c = time.perf_counter()
            trackers[i].update(*pose, arrival)
            t_update += time.perf_counter() - c
            n_update += 1
        if t < warmup:
            continue
        for i in range(robots):
            if held[i] is None:
                continue
            c = time.perf_counter()
            p = trackers[i].predict(t)
            t_predict += time.perf_counter() - c
            n_predict += 1
            x, y, yaw = truth[i]
            err_hold.append(math.hypot(held[i][0] - x, held[i][1] - y))
            err_kf.append(math.hypot(p.x - x, p.y - y))
            yaw_hold.append(abs(math.remainder(held[i][2] - yaw, math.tau)))
            yaw_kf.append(abs(math.remainder(p.yaw - yaw, math.tau)))
    eh, ek = np.array(err_hold), np.array(err_kf)
    speed = float(np.mean([abs(world.velocity(n)[0]) for n in names]))  # m/s at the end of the run
    return {
        "robots": robots,
        "samples": len(eh),
        "end_speed": round(speed, 3),
        "hold_mean_m": round(float(eh.mean()), 4),
        "hold_p95_m": round(float(np.percentile(eh, 95)), 4),
        "kalman_mean_m": round(float(ek.mean()), 4),
        "kalman_p95_m": round(float(np.percentile(ek, 95)), 4),
        "mean_ratio": round(float(eh.mean() / ek.mean()), 2),
        "p95_ratio": round(float(np.percentile(eh, 95) / np.percentile(ek, 95)), 2),
        "hold_yaw_mean_deg": round(math.degrees(float(np.mean(yaw_hold))), 2),
        "kalman_yaw_mean_deg": round(math.degrees(float(np.mean(yaw_kf))), 2),
        "update_us": round(1e6 * t_update / max(n_update, 1), 1),
        "predict_us": round(1e6 * t_predict / max(n_predict, 1), 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=20)
    ap.add_argument("--sim-seconds", type=float, default=120.0)
    ap.add_argument("--warmup", type=float, default=5.0, help="simulated seconds before errors count")
    ap.add_argument("--rate", type=float, default=2.0, help="broadcasts per simulated second per robot")
    ap.add_argument("--delay", default="0.02,0.15", help="min,max delivery delay in seconds")
    ap.add_argument("--motion", choices=("wander", "curvy"), default="wander")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    try:
        lo, hi = (float(v) for v in args.delay.split(","))
        if not 0 <= lo <= hi:
            raise ValueError
    except ValueError:
        print(f"bench_tracking: --delay {args.delay!r} must be MIN,MAX seconds with 0 <= MIN <= MAX", file=sys.stderr)
        return 1
    r = run(args.robots, args.sim_seconds, args.rate, (lo, hi), args.warmup, args.seed, args.motion)
    head = f"bench=tracking motion={args.motion} rate_hz={args.rate:g} delay={lo:g}-{hi:g} "
    print(head + " ".join(f"{k}={v}" for k, v in r.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
