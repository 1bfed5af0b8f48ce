"""The thesis's swarm at its start density, at a cost two cores afford: a block of the 100-robot crowd.

The 100-robot run (``rsal run deploy/scenarios/swarm.yaml --app thesis``) is slow on this machine;
its failures (contacts, localization) come from the density of its start, 1.2 m apart, where most
sonar echoes are other robots. This benchmark keeps that density: the thesis world
(``maps/swarm_thesis.world``) with a ``--rows`` x ``--cols`` block at its corner (r0.., nearest the
hall's walls) carrying the full stack (``rsal sim --nav vfh --nav-robots ...``: AMCL on the sonar
ring, VFH, Wavefront) and a :class:`~agents.scenarios.swarm.thesis.ThesisSwarmAgent` each; the
other robots stand, and their positions are broadcast for them twice a second as their agents
would (they stand still: where they stand). Judged by
:class:`~agents.scenarios.swarm.thesis.ThesisSwarmMonitor` on ground truth (contacts in every
physics step, AMCL pose against the true pose every 0.5 s).

``--baseline`` first runs the same block with the agents' ``set_obstacles`` declarations off (AMCL
scores every echo against the map, as before), then with them; each run prints one
``bench=thesis_dense`` line. Every contact is printed as it happens (the robot, its behaviour's
layer, its speed, its sectors). Usage::

    python benchmarks/bench_thesis_dense.py [--rows 5] [--cols 6] [--seconds 40] [--speedup 1] [--baseline]
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from agents.runtime import Agent, AgentHost  # noqa: E402
from agents.scenarios.swarm.thesis import ThesisSwarmAgent, ThesisSwarmMonitor  # noqa: E402
from agents.services import SendPosition  # noqa: E402
from rsal.client import Fabric  # noqa: E402
from rsal.clock import use_sim_time  # noqa: E402
from rsal.transport import TransportArgs  # noqa: E402
from tests.conftest import free_port  # noqa: E402


class StandingBroadcasts(Agent):
    """The standing robots' broadcasts at 2 Hz: their poses, which do not change."""

    def __init__(self, agent_id: str, poses: dict):
        super().__init__(agent_id, period=0.5)
        self.poses = poses

    async def step(self) -> None:
        for name, (x, y, yaw) in self.poses.items():
            self.publish(SendPosition.SERVICE, SendPosition(name, x, y, yaw, "map"))


class Quiet(ThesisSwarmAgent):
    """The baseline: no neighbours declared to the localize device."""

    def declare_neighbours(self) -> None:
        pass


def _cpu_s(pid: int) -> float:
    """CPU seconds (user + system) the process has used so far, from /proc (Linux)."""
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


async def _judge(ep: str, robots: list[str], seconds: float, declare: bool, simdev, sim_pid: int) -> dict:
    async with AgentHost.connect(TransportArgs(connect=[ep])) as host:
        clk = await asyncio.to_thread(use_sim_time, host.session, "sim")
        await asyncio.to_thread(clk.wait_started, 60)
        allp = await asyncio.to_thread(simdev.rpc, "get_poses")
        standing = {n: tuple(p) for n, p in zip(allp["names"], allp["poses"], strict=True) if n not in robots}
        await host.start(StandingBroadcasts("standing", standing))
        cls = ThesisSwarmAgent if declare else Quiet
        agents = [cls(f"swarm{n}", robot=n, startup_timeout=300) for n in robots]
        await asyncio.gather(*(host.start(a) for a in agents))
        mon = ThesisSwarmMonitor("monitor", robots=robots, duration=seconds, startup_timeout=300, max_p99_ms=1000)
        await host.start(mon)
        seen: dict = {}
        wall0, sim0, cpu0 = time.perf_counter(), clk.now(), _cpu_s(sim_pid)
        while mon.verdict is None:
            await asyncio.sleep(0.1)
            c = await asyncio.to_thread(simdev.rpc, "contacts")
            for k, v in c["robots"].items():
                if seen.get(k) != v:
                    seen[k] = v
                    a = next((a for a in agents if a.robot == k), None)
                    p = a.pioneer if a is not None else None
                    tp = await asyncio.to_thread(simdev.get_pose, k)
                    if p is None:
                        print(f"contact t={clk.now():.1f} {k} {v} standing at ({tp.x:.2f}, {tp.y:.2f})", flush=True)
                        continue
                    s = p.sectors()
                    vel = p.position2d.latest.vel if p.position2d.latest else None
                    print(
                        f"contact t={clk.now():.1f} {k} {v} layer={p.behaviour.state} vel={vel} "
                        f"front={s.min_between(-30, 30):.2f} left={s.min_between(30, 100):.2f} "
                        f"right={s.min_between(-100, -30):.2f} rear={s.min_between(150, 210):.2f} "
                        f"at ({tp.x:.2f}, {tp.y:.2f}, {math.degrees(tp.yaw):.0f} deg)",
                        flush=True,
                    )
        sim_s = clk.now() - sim0
        rtf = sim_s / (time.perf_counter() - wall0)
        cpu = (_cpu_s(sim_pid) - cpu0) / max(sim_s, 1e-9)
        e = np.array(mon.loc_errors)
        share, p95, worst = mon.localization()
        first = e[: max(1, int(20 / mon.sample_every))]
        return {
            "contacts": mon.contact_counts(),
            "share": share,
            "first20": float(np.mean(first <= mon.max_loc_error)),
            "p95": p95,
            "worst": worst,
            "rtf": rtf,
            "cpu": cpu,
            "verdict": mon.verdict.text,
        }


def run(rows: int, cols: int, seconds: float, speedup: str, declare: bool) -> dict:
    robots = [f"r{r * 10 + c}" for r in range(rows) for c in range(cols)]
    ep = f"tcp/127.0.0.1:{free_port()}"
    world = str(ROOT / "maps" / "swarm_thesis.world")
    cmd = [sys.executable, "-m", "rsal.cli", "sim", world, "--listen", ep, "--nav", "vfh"]
    cmd += ["--nav-robots", ",".join(robots), "--speedup", speedup]
    sim = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        with Fabric.connect(TransportArgs(connect=[ep])) as fab:
            node = fab.node("*:planner:0")
            node.wait_for("*:planner:0", len(robots), 300)
            r = asyncio.run(_judge(ep, robots, seconds, declare, fab.device("sim:simulation:0"), sim.pid))
            node.close()
            return r
    finally:
        os.killpg(sim.pid, signal.SIGTERM)
        sim.wait(10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=5, help="rows of the crowd with full stacks (default 5)")
    ap.add_argument("--cols", type=int, default=6, help="columns of the crowd with full stacks (default 6)")
    ap.add_argument("--seconds", type=float, default=40.0, help="simulated seconds judged (default 40)")
    ap.add_argument("--speedup", default="1", help="the simulator's speed-up (default 1)")
    ap.add_argument("--baseline", action="store_true", help="first run without the set_obstacles declarations")
    a = ap.parse_args()
    if not (1 <= a.rows <= 10 and 1 <= a.cols <= 10):
        ap.error(f"--rows {a.rows} and --cols {a.cols} must be 1..10 (the thesis crowd is 10 x 10)")
    for declare in (False, True) if a.baseline else (True,):
        r = run(a.rows, a.cols, a.seconds, a.speedup, declare)
        rr, rw = r["contacts"]
        print(
            f"bench=thesis_dense robots={a.rows * a.cols} seconds={a.seconds:g} declare={'on' if declare else 'off'} "
            f"contacts_robot={rr} contacts_wall={rw} within_0.5m={r['share']:.3f} first_20s={r['first20']:.3f} "
            f"p95_m={r['p95']:.2f} worst_m={r['worst']:.2f} rtf={r['rtf']:.2f} cpu_s_per_sim_s={r['cpu']:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
