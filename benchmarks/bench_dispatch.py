"""Fleet dispatcher: 1,000 tasks over 50 robots -- assignment latency, re-bid after a kill, no task
lost or done twice.

A ``DispatcherAgent`` runs in its own process (``rsal agent DispatcherAgent``); this process hosts
``--robots`` stand-in robot agents (:class:`agents.dispatch.agent.FleetWorker` with no simulator:
a robot "drives" by waiting the straight-line travel time divided by ``--compress``, and its
position jumps to where the task ends) and a submitter that sends ``--tasks`` ``go_to`` tasks to
random points of a 50 m x 50 m floor at ``--rate`` tasks per second. Once every task is
submitted, the robot holding the most unfinished tasks is killed (its agent stops, its liveliness
token goes).

Figures (``bench=dispatch key=value`` lines):

- ``latency_after_window`` p50/p99/max (ms): a robot's receipt of the award minus the moment the
  bidding window closed (the call's ``reply_by``, or the last called robot's bid when every robot
  answered earlier); ``submit_to_award`` p50/p99 (ms) the whole way, window included. The first
  ``--warmup`` tasks are left out.
- ``rebid``: the killed robot's unfinished tasks, the time from the kill to each one's award to
  another robot (p50/max, ms), and whether every one of them was then performed by another robot.
- ``lost`` / ``done_twice``: ground truth from the stand-ins' own records of what they performed
  (not from any message): every task performed exactly once, none never.

Baseline in the same run: ``submit_to_award`` minus ``window`` shows what the dispatcher adds to
the bidding window itself. Usage: ``python benchmarks/bench_dispatch.py --robots 50 --tasks 1000``.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from agents.dispatch.agent import FleetWorker  # noqa: E402
from agents.dispatch.tasks import DispatchMsg, Task, TaskRequest, TaskStatus, task_places  # noqa: E402
from agents.runtime import Agent, AgentHost  # noqa: E402
from benchmarks.loopback import free_port, session  # noqa: E402


class StandIn(FleetWorker, Agent):
    """A robot with no body: travel is waiting ``distance / speed / compress`` seconds."""

    def __init__(self, agent_id: str, x: float, y: float, compress: float, log: dict):
        Agent.__init__(self, agent_id, period=0.2, robot=agent_id.upper())
        self.init_worker(speed=0.5, threshold=0.2, target=0.9, status_every=1.0, agent_id=agent_id)
        self.pos = (x, y)
        self.compress = compress
        self.log = log  # shared: awards received, bids sent, calls seen

    async def created(self) -> None:
        self.start_worker()

    def _on_dispatch(self, msg, m: DispatchMsg) -> None:
        if m.op == "call":
            self.log["reply_by"][(m.task_id, m.round)] = m.reply_by
        elif m.op == "award" and m.to == self.id:
            self.log["awards"].append((m.task_id, m.round, self.id, time.time()))
        super()._on_dispatch(msg, m)

    def _fleet(self, body) -> None:
        if body.op == "bid":
            key = (body.task_id, body.round)
            self.log["last_bid"][key] = max(self.log["last_bid"].get(key, 0.0), time.time())
        super()._fleet(body)

    def where(self):
        return self.pos

    async def killed(self) -> None:
        self.stop_worker()

    async def step(self) -> None:
        self.report_status()

    async def perform(self, task: Task) -> str:
        end = task_places(task)[-1]
        await asyncio.sleep(math.dist(self.pos, end) / self.speed / self.compress)
        self.pos = end
        self.log["performed"].setdefault(task.id, []).append(self.id)
        return ""


class Submitter(Agent):
    def __init__(self) -> None:
        super().__init__("bench-submitter")
        self.states: dict[str, list[tuple[str, str, float]]] = {}

    async def created(self) -> None:
        self.subscribe(TaskStatus.SERVICE, self._on)

    def _on(self, msg) -> None:
        b = msg.body
        self.states.setdefault(b.get("task_id", "?"), []).append((b.get("state"), b.get("robot", ""), time.time()))


def _pct(v, q) -> float:
    return float(np.percentile(v, q)) if len(v) else float("nan")


async def bench(args, ep: str) -> dict:
    log = {"reply_by": {}, "awards": [], "last_bid": {}, "performed": {}}
    rng = np.random.default_rng(args.seed)
    async with AgentHost(session(listen=ep), own_session=True) as host:
        sub = await host.start(Submitter())
        robots = []
        for i, (x, y) in enumerate(rng.uniform(0, 50, (args.robots, 2))):
            robots.append(await host.start(StandIn(f"b{i:03d}", float(x), float(y), args.compress, log)))
        deadline = time.monotonic() + 60
        while not any(h.cls == "DispatcherAgent" for h in await host.who_is_there(0.5)):
            if time.monotonic() > deadline:
                raise SystemExit("bench_dispatch: the DispatcherAgent did not start within 60 s")
        await asyncio.sleep(2.5)  # every robot has sent a status (every 1 s)
        submitted: dict[str, float] = {}
        goals = rng.uniform(0, 50, (args.tasks, 2))
        t0 = time.perf_counter()
        for i, (x, y) in enumerate(goals):
            tid = f"k{i:04d}"
            sub.publish(
                TaskRequest.SERVICE,
                TaskRequest("submit", {"id": tid, "kind": "go_to", "args": {"x": float(x), "y": float(y)}}),
            )
            submitted[tid] = time.time()
            await asyncio.sleep(max(0.0, t0 + (i + 1) / args.rate - time.perf_counter()))
        # kill the robot holding the most unfinished tasks
        victim = max(robots, key=lambda r: (len(r.queue) + (r.active is not None), r.id))
        held = [t.id for t in victim.queue] + ([victim.active.id] if victim.active else [])
        t_kill = time.time()
        await host.kill(victim)
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline:
            final = sum(
                1
                for t in submitted
                if any(s in ("done", "failed", "cancelled", "refused") for s, _, _ in sub.states.get(t, []))
            )
            if final == len(submitted):
                break
            await asyncio.sleep(0.2)
        await asyncio.sleep(1.0)  # a late double performance would show now
    awards = sorted(log["awards"], key=lambda a: a[3])
    first_award: dict[str, float] = {}
    after_window, to_award = [], []
    for tid, rnd, _who, t in awards:
        if tid in first_award:
            continue
        first_award[tid] = t
        if int(tid[1:]) < args.warmup:
            continue
        close = log["reply_by"].get((tid, rnd), t)
        last = log["last_bid"].get((tid, rnd))
        if last is not None:
            close = min(close, last)
        after_window.append((t - close) * 1e3)
        to_award.append((t - submitted[tid]) * 1e3)
    rebid = []
    rebid_ok = True
    for tid in held:
        later = [a for a in awards if a[0] == tid and a[3] > t_kill and a[2] != victim.id]
        by_other = [r for r in log["performed"].get(tid, []) if r != victim.id]
        if tid in log["performed"] and victim.id in log["performed"][tid]:
            continue  # finished before the kill
        if later:
            rebid.append((later[0][3] - t_kill) * 1e3)
        rebid_ok = rebid_ok and bool(later) and len(by_other) == 1
    performed = log["performed"]
    lost = [t for t in submitted if t not in performed]
    twice = [t for t, who in performed.items() if len(who) > 1]
    return {
        "after_window": after_window,
        "to_award": to_award,
        "rebid": rebid,
        "rebid_ok": rebid_ok,
        "held": len(held),
        "lost": len(lost),
        "twice": len(twice),
        "victim": victim.id,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=50)
    ap.add_argument("--tasks", type=int, default=1000)
    ap.add_argument("--rate", type=float, default=10.0, help="tasks submitted per second (default 10)")
    ap.add_argument("--window", type=float, default=2.0, help="bidding window, s (default 2, Open-RMF's)")
    ap.add_argument("--compress", type=float, default=20.0, help="stand-ins drive this many times faster than 0.5 m/s")
    ap.add_argument("--warmup", type=int, default=20, help="first tasks left out of the latency figures")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for every task to end")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    disp = subprocess.Popen(
        [
            sys.executable, "-m", "rsal.cli", "agent", "DispatcherAgent", "--id", "dispatcher", "--connect", ep,
            "--arg", f"window={args.window}", "--arg", "max_rounds=50", "--arg", "retry=1.0",
        ],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        r = asyncio.run(bench(args, ep))
    finally:
        disp.terminate()
        try:
            disp.wait(10)
        except subprocess.TimeoutExpired:
            disp.kill()
    aw, ta, rb = r["after_window"], r["to_award"], r["rebid"]
    print(
        f"bench=dispatch robots={args.robots} tasks={args.tasks} window_s={args.window:g} rate={args.rate:g} "
        f"latency_after_window_ms_p50={_pct(aw, 50):.1f} p99={_pct(aw, 99):.1f} "
        f"max={max(aw, default=float('nan')):.1f} "
        f"submit_to_award_ms_p50={_pct(ta, 50):.1f} p99={_pct(ta, 99):.1f}"
    )
    print(
        f"bench=dispatch rebid victim={r['victim']} held={r['held']} rebid={len(rb)} "
        f"rebid_ms_p50={_pct(rb, 50):.1f} max={max(rb, default=float('nan')):.1f} done_by_another={r['rebid_ok']}"
    )
    print(f"bench=dispatch lost={r['lost']} done_twice={r['twice']}")
    return 0 if r["lost"] == 0 and r["twice"] == 0 and r["rebid_ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
