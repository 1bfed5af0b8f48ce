"""Surveillance patrol over simulated hours: 6 robots, 2 chargers, the dispatcher's charging on and off.

The thesis's surveillance robots (5.4) patrol "around the clock" and head "to a recharging point
when necessary". This benchmark runs the fleet dispatcher's logic (:class:`agents.dispatch.Dispatcher`,
the same code the ``DispatcherAgent`` runs) and its robots' cost model
(:func:`agents.dispatch.plan_bid`) in one process against the simulator (:mod:`simulator`, stepped
as fast as it goes, its battery model and chargers included), with no network in between, so hours
of simulated time take a minute: each robot follows its task's points with a proportional
controller on its true pose, a patrol manager keeps one ``patrol`` task per route open (as
:class:`agents.dispatch.patrol.PatrolAgent` does), and bids are answered at once.

World (generated): an open 30 m x 20 m hall, ``--robots`` Pioneer 2DX bodies with small batteries
(``--capacity`` Wh; 20 W electronics, 20 J/m, 4 J/rad: about 45 min of driving), ``--chargers``
150 W charging stations, 4 square patrol routes of 6 m x 6 m.

Figures (``bench=patrol key=value``, ground truth from the simulator), for the run with charging
(threshold 20 %, target 90 %) and the baseline without, in the same invocation with the same seed:
robots that ran flat and their flat minutes, coverage (per route point, the longest time between
two visits of a robot within 0.7 m; the share of points revisited at least every ``--every``
minutes), idle minutes per robot (no task, not charging), laps completed and the wall time.

Usage: ``python benchmarks/bench_patrol.py --hours 4``.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from agents.dispatch import ChargePolicy, Charger, Dispatcher, DispatchMsg, FleetMsg, Task, TaskState  # noqa: E402
from agents.dispatch.bidder import Energy, plan_bid  # noqa: E402
from agents.dispatch.patrol import revisit_gaps  # noqa: E402
from agents.dispatch.tasks import parse_task, task_places  # noqa: E402
from simulator.loader import load_world  # noqa: E402
from simulator.world import World  # noqa: E402

ROUTES = [
    [[2.0, 2.0], [8.0, 2.0], [8.0, 8.0], [2.0, 8.0]],
    [[22.0, 2.0], [28.0, 2.0], [28.0, 8.0], [22.0, 8.0]],
    [[22.0, 12.0], [28.0, 12.0], [28.0, 18.0], [22.0, 18.0]],
    [[2.0, 12.0], [8.0, 12.0], [8.0, 18.0], [2.0, 18.0]],
]
SPEED = 0.4  # m/s cruise
WATTS, PER_M, PER_RAD, RATE = 20.0, 20.0, 4.0, 150.0


def world_yaml(n: int, chargers: int, capacity_wh: float, seed: int) -> str:
    rng = np.random.default_rng(seed)
    lines = [f"world: {{interval_sim: 0.1, speedup: max, seed: {seed}}}", "robots:"]
    for i in range(n):
        x, y = 12.0 + (i % 3) * 3.0, 8.0 + (i // 3) * 4.0
        charge = float(rng.uniform(0.5, 1.0))
        lines.append(
            f"  - {{name: r{i}, pose: [{x}, {y}, 0], sonar: false, odom_noise: [0, 0, 0], "
            f"battery: {{capacity: {capacity_wh}, charge: {charge:.3f}, per_metre: {PER_M}, "
            f"per_radian: {PER_RAD}, watts: {WATTS}, max_charge: {RATE}}}}}"
        )
    lines.append("chargers:")
    for j in range(chargers):
        lines.append(f"  - {{name: dock{j}, pose: [{13.0 + 4.0 * j}, 1.0, 0], rate: {RATE}, distance: 0.4}}")
    return "\n".join(lines) + "\n"


class Bot:
    """A robot's executor: its queue, the point it drives to, and charging on a charger."""

    def __init__(self, name: str):
        self.name = self.agent = name
        self.queue: list[Task] = []
        self.active: Task | None = None
        self.points: list[tuple[float, float]] = []
        self.idle = 0.0
        self.flat = 0.0
        self.ever_flat = False


def run(args, charging: bool) -> dict:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "patrol.yaml"
        path.write_text(world_yaml(args.robots, args.chargers, args.capacity, args.seed))
        world = World(load_world(str(path)))
    dt = world.spec.interval_sim if hasattr(world.spec, "interval_sim") else 0.1
    cap_j = args.capacity * 3600.0
    energy = Energy(per_metre=PER_M / cap_j, per_second=WATTS / cap_j, charge_rate=RATE / cap_j)
    bots = {f"r{i}": Bot(f"r{i}") for i in range(args.robots)}
    outbox: list = []
    chargers = [Charger(f"dock{j}", 13.0 + 4.0 * j, 1.0) for j in range(args.chargers)]
    policy = ChargePolicy(threshold=0.2, target=0.9, finishing="nothing", enabled=charging)
    d = Dispatcher(now=lambda: world.time, send=outbox.append, window=2.0, retry=5.0, max_rounds=10**6,
                   policy=policy, chargers=chargers, name="bench")  # fmt: skip
    open_route: dict[int, str] = {}
    laps = [0] * len(ROUTES)

    def pose(name):
        x, y, yaw = world.get_pose(name)
        return x, y, yaw

    def status(b: Bot):
        x, y, _ = pose(b.name)
        bat = world.battery(b.name)
        d.on_fleet(b.agent, FleetMsg("status", robot=b.name, x=x, y=y, battery=bat.fraction, charging=bat.charging))

    def deliver():
        while outbox:
            m = outbox.pop(0)
            if not isinstance(m, DispatchMsg):
                if m.state in ("done", "failed", "cancelled") and m.task_id in open_route.values():
                    r = next(i for i, t in open_route.items() if t == m.task_id)
                    del open_route[r]
                    laps[r] += m.state == "done"
                continue
            if m.op == "call":
                task = parse_task(m.task)
                for b in bots.values():
                    if b.agent in m.exclude:
                        continue
                    x, y, _ = pose(b.name)
                    here, busy = (x, y), 0.0
                    if b.active is not None and b.points:
                        here, busy = b.points[-1], math.dist((x, y), b.points[-1]) / SPEED
                    bid = plan_bid(here, b.queue, task, speed=SPEED, battery=world.battery(b.name).fraction,
                                   energy=energy, busy_until=busy)  # fmt: skip
                    if bid is None:
                        d.on_fleet(b.agent, FleetMsg("refuse", task_id=m.task_id, round=m.round))
                    else:
                        i = bid.index + (1 if b.active is not None else 0)
                        d.on_fleet(b.agent, FleetMsg("bid", task_id=m.task_id, round=m.round, cost=bid.cost, index=i))
            elif m.op == "award":
                b = bots[m.to]
                task = parse_task(m.task)
                if task.kind == "charge":
                    b.queue.insert(0, task)
                else:
                    i = m.index - (1 if b.active is not None else 0)
                    b.queue.insert(max(0, min(i, len(b.queue))), task)
            elif m.op == "revoke":
                b = bots[m.to]
                b.queue = [t for t in b.queue if t.id != m.task_id]

    for b in bots.values():
        status(b)
    steps = int(round(args.hours * 3600 / dt))
    every = int(round(1.0 / dt))
    times, track = [], []
    t0 = time.perf_counter()
    for k in range(steps):
        for i in range(len(ROUTES)):
            if i not in open_route:
                rec = d.submit({"kind": "patrol", "args": {"route": ROUTES[i]}}, "patrol")
                open_route[i] = rec.task.id
        d.tick()
        deliver()
        for b in bots.values():
            bat = world.battery(b.name)
            if bat.empty:
                b.flat += dt
                b.ever_flat = True
            if b.active is None:
                if not b.queue:
                    b.idle += dt
                    world.set_velocity(b.name, 0.0, 0.0)
                    continue
                b.active = b.queue.pop(0)
                pts = task_places(b.active)
                b.points = list(pts) + ([pts[0]] if b.active.kind == "patrol" else [])  # close the loop
                d.on_fleet(b.agent, FleetMsg("progress", task_id=b.active.id, state="active"))
            x, y, yaw = pose(b.name)
            if b.points:
                tx, ty = b.points[0]
                dist = math.hypot(tx - x, ty - y)
                if dist < 0.25 and (b.active.kind != "charge" or bat.fraction >= float(b.active.args["target"])):
                    b.points.pop(0)
                    world.set_velocity(b.name, 0.0, 0.0)
                    continue
                if dist < 0.25:  # on the dock: hold the place while charging (pushed off: drive back)
                    world.set_velocity(b.name, 0.0, 0.0)
                    continue
                err = math.atan2(ty - y, tx - x) - yaw
                err = math.atan2(math.sin(err), math.cos(err))
                v = SPEED * max(0.0, math.cos(err)) ** 4 * min(1.0, dist)
                world.set_velocity(b.name, v, max(-1.0, min(1.0, 2.0 * err)))
                continue
            world.set_velocity(b.name, 0.0, 0.0)
            if b.active.kind == "charge" and bat.fraction < float(b.active.args.get("target", 0.9)):
                continue  # charging on the dock
            tid = b.active.id
            b.active = None
            status(b)
            d.on_fleet(b.agent, FleetMsg("progress", task_id=tid, state="done"))
        deliver()
        world.step()
        if k % every == 0:
            for b in bots.values():
                status(b)
            times.append(world.time)
            track.append([pose(n)[:2] for n in bots])
    wall = time.perf_counter() - t0
    pts = np.array([p for r in ROUTES for p in r])
    gaps = revisit_gaps(np.array(times), np.array(track), pts, radius=0.7)
    hours = args.hours
    return {
        "flat_robots": sum(b.ever_flat for b in bots.values()),
        "flat_min": sum(b.flat for b in bots.values()) / 60.0,
        "gap_max_min": float(gaps.max()) / 60.0,
        "gap_p50_min": float(np.median(gaps)) / 60.0,
        "covered": float(np.mean(gaps <= args.every * 60.0)),
        "idle_min": [round(b.idle / 60.0, 1) for b in bots.values()],
        "laps": sum(laps),
        "charges": sum(1 for r in d.tasks.values() if r.task.kind == "charge" and r.state is TaskState.DONE),
        "wall_s": wall,
        "rtf": hours * 3600 / wall,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=4.0, help="simulated hours (default 4)")
    ap.add_argument("--robots", type=int, default=6)
    ap.add_argument("--chargers", type=int, default=2)
    ap.add_argument("--capacity", type=float, default=20.0, help="battery capacity, Wh (default 20)")
    ap.add_argument("--every", type=float, default=10.0, help="coverage: minutes between visits (default 10)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--baseline", action=argparse.BooleanOptionalAction, default=True, help="also run charging off")
    args = ap.parse_args(argv)
    for charging in (True, False) if args.baseline else (True,):
        r = run(args, charging)
        print(
            f"bench=patrol charging={'on' if charging else 'off'} robots={args.robots} chargers={args.chargers} "
            f"hours={args.hours:g} flat_robots={r['flat_robots']} flat_min={r['flat_min']:.1f} "
            f"gap_max_min={r['gap_max_min']:.1f} gap_p50_min={r['gap_p50_min']:.1f} "
            f"covered_every_{args.every:g}min={r['covered']:.2f} laps={r['laps']} charges={r['charges']} "
            f"idle_min={','.join(map(str, r['idle_min']))} wall_s={r['wall_s']:.1f} rtf={r['rtf']:.0f}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
