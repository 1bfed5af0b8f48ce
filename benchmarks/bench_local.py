"""Local planners (VFH, ND, SND): cost of one control step, and closed-loop success rates.

**Step cost** (default). Scans of a Hokuyo URG-04LX (682 beams, 240 deg, 5.6 m) are taken by a
simulated Pioneer at random poses on the floor map with a box that is not on the map nearby; each
planner's :meth:`~mrs_bridge.nav.local.LocalPlanner.step` is timed over them (after a warm-up)
and reported as p50 / p99 microseconds, with how many robots' planners one core sustains at
10 Hz (``1e6 / (10 * mean)``). Baseline in the same run: the shared layer alone (scan memory,
goal handling, motion guard, limits) with a trivial straight-to-goal ``_plan``, so the figures
show what each algorithm adds.

**Trials** (``--trials N``). The local-only version of the project's navigation target: N random
straight 2-5 m runs on the floor map (the line keeps 0.5 m from walls) with a 0.3-0.5 m box that
is not on the map in the way, and ``--others`` (default 2) other robots driving their own runs
across it (one head-on, one crossing) with the same planner. A run succeeds when the main robot's
planner reports ``done`` within tolerance of the goal inside 60 simulated seconds and no robot
body touched anything. ``--set vfh.max_speed=0.3`` overrides a parameter (repeatable) -- the
parameter sweep behind the planners' defaults used this.

Output: one parseable line per figure, ``bench=local key=value ...``.
Usage: ``python benchmarks/bench_local.py [--quick] [--planners vfh,nd,snd] [--trials 20]``
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

from mrs_bridge.nav.local import LocalPlanner, Param  # noqa: E402
from mrs_bridge.nav.nd import ND  # noqa: E402
from mrs_bridge.nav.snd import SND  # noqa: E402
from mrs_bridge.nav.vfh import VFH  # noqa: E402

PLANNERS: dict[str, type[LocalPlanner]] = {"vfh": VFH, "nd": ND, "snd": SND}
GEOMETRY = (0.44, 0.38)  # Pioneer 2DX


class Baseline(LocalPlanner):
    """The shared layer only: head straight for the goal; memory, guard and limits as usual."""

    name = "baseline"
    PARAMS = {"max_speed": Param(0.4, 0.0, 5.0, "m/s")}

    def _configure(self, p):
        self.robot_radius = self._radius(0.25)
        self.v_max, self.w_max = p["max_speed"], math.radians(60.0)
        self.pos_tol, self.ang_tol, self.turn_min = 0.3, math.radians(10.0), 0.1
        self.accel, self.brake = None, 0.5
        self.escape_speed, self.escape_turnrate, self.escape_time = 0.0, 0.0, 0.0
        self.blocked_after, self.stuck_time, self.stuck_dist = 2.0, 10.0, 0.1
        self.stuck_angle, self.rotate_stuck_time = 0.3, 20.0

    def safety(self, speed):
        return 0.1

    def _plan(self, goal, dist, pts, speed, pose, dt):
        a = math.atan2(goal[1], goal[0])
        return self.v_max * max(0.0, math.cos(a)), 1.5 * a, True


def scans(n: int, seed: int) -> list[tuple[tuple[float, float, float], np.ndarray]]:
    """``n`` robot-frame URG scans (max-range readings removed) from random free floor poses."""
    from mrs_bridge.rigs.localsim import laser_points
    from simulator import load_world
    from simulator.presets import box
    from simulator.world import World

    world = World(load_world(ROOT / "maps" / "floor.world"), seed=seed)
    rng = np.random.default_rng(seed)
    grid = world.grid
    x0, x1, y0, y1 = grid.extent
    out = []
    world.add_model(box("bench_box", (0.0, 0.0, 0.0), size=(0.5, 0.5, 0.5)))
    while len(out) < n:
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if grid.clearance(x, y) < 0.6:
            continue
        a = rng.uniform(-math.pi, math.pi)
        world.set_pose("r1", x, y, a)
        bx, by = x + 1.5 * math.cos(a), y + 1.5 * math.sin(a)
        world.set_pose("bench_box", bx, by, 0.0)
        world.step()
        pts = laser_points(world, "r1")
        out.append(((x, y, a), pts))
    return out


def step_cost(cls: type[LocalPlanner], data, warmup: int, count: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    planner = cls(geometry=GEOMETRY)
    times = np.empty(count)
    k = 0
    total = warmup + count
    for i in range(total):
        if i % 50 == 0:  # a new goal now and then, 2-5 m ahead, so every branch gets exercised
            pose = data[k % len(data)][0]
            d, a = rng.uniform(2.0, 5.0), pose[2] + rng.uniform(-1.0, 1.0)
            planner.set_goal((pose[0] + d * math.cos(a), pose[1] + d * math.sin(a), 0.0))
        pose, pts = data[k % len(data)]
        k += 1
        t = time.perf_counter()
        planner.step(pose, (0.3, 0.0), pts, 0.1)
        dt = time.perf_counter() - t
        if i >= warmup:
            times[i - warmup] = dt
    us = times * 1e6
    mean = float(us.mean())
    return {
        "p50_us": round(float(np.percentile(us, 50)), 1),
        "p99_us": round(float(np.percentile(us, 99)), 1),
        "mean_us": round(mean, 1),
        "robots_per_core_10hz": int(1e6 / (10.0 * mean)),
        "beams": int(np.mean([len(p) for _, p in data])),
    }


def trials(cls: type[LocalPlanner], n: int, others: int, params: dict, seed: int) -> dict:
    from mrs_bridge.rigs.localsim import draw_trial, run_trial
    from simulator import load_world
    from simulator.world import World

    spec = load_world(ROOT / "maps" / "floor.world")
    ok = collided = 0
    times, fails = [], []
    t0 = time.perf_counter()
    for i in range(n):
        s = seed + i
        world = World(spec, seed=s)
        trial = draw_trial(world.grid, np.random.default_rng(s), others=others)
        res = run_trial(world, trial, lambda g: cls(params, geometry=g))
        main = res[0]
        hit = any(r.collided for r in res)
        collided += hit
        if main.reached and not hit:
            ok += 1
            times.append(main.time)
        else:
            fails.append(f"{s}:{main.status}{'+hit' if hit else ''}")
    return {
        "trials": n,
        "others": others,
        "success": ok,
        "rate": round(ok / n, 3),
        "collisions": collided,
        "mean_time_s": round(float(np.mean(times)), 1) if times else None,
        "wall_s": round(time.perf_counter() - t0, 1),
        "failed": ",".join(fails) or "-",
    }


def _overrides(items: list[str]) -> dict[str, dict]:
    out: dict[str, dict] = {name: {} for name in PLANNERS}
    for item in items:
        key, _, value = item.partition("=")
        planner, _, param = key.partition(".")
        if planner not in PLANNERS or not param or not value:
            raise SystemExit(f"bench_local: --set {item!r}: use PLANNER.PARAM=VALUE, e.g. vfh.max_speed=0.3")
        v = [float(x) for x in value.split(",")]
        out[planner][param] = v[0] if len(v) == 1 else v
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--planners", default="vfh,nd,snd", help="comma-separated: vfh, nd, snd")
    ap.add_argument("--quick", action="store_true", help="fewer steps (and 5 trials when --trials is given)")
    ap.add_argument("--warmup", type=int, default=200, help="untimed steps per planner")
    ap.add_argument("--count", type=int, default=3000, help="timed steps per planner")
    ap.add_argument("--scans", type=int, default=60, help="distinct scans to cycle through")
    ap.add_argument("--trials", type=int, default=0, help="closed-loop trials per planner (0: none)")
    ap.add_argument("--others", type=int, default=2, help="other moving robots in each trial")
    ap.add_argument("--set", action="append", default=[], metavar="PLANNER.PARAM=VALUE", help="parameter override")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    names = [x.strip() for x in args.planners.split(",") if x.strip()]
    for name in names:
        if name not in PLANNERS:
            raise SystemExit(f"bench_local: unknown planner {name!r}; use vfh, nd or snd")
    over = _overrides(args.set)
    if args.trials:
        n = 5 if args.quick else args.trials
        for name in names:
            print(f"[bench] {name}: {n} trials ...", file=sys.stderr, flush=True)
            r = trials(PLANNERS[name], n, args.others, over[name], args.seed)
            extra = "".join(f" {k}={v}" for k, v in over[name].items())
            print(f"bench=local planner={name} " + " ".join(f"{k}={v}" for k, v in r.items()) + extra, flush=True)
        return 0
    warmup, count = (50, 500) if args.quick else (args.warmup, args.count)
    data = scans(20 if args.quick else args.scans, args.seed)
    for name, cls in [("baseline", Baseline), *((n, PLANNERS[n]) for n in names)]:
        r = step_cost(cls, data, warmup, count, args.seed)
        print(f"bench=local planner={name} " + " ".join(f"{k}={v}" for k, v in r.items()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
