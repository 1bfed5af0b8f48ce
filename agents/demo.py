"""``rsal demo``: the embedded default, end to end on loopback and headless: all three layers.

- the multi-robot system: the simulator with its device server (``rsal sim``, a separate process)
  on the floor map, three Pioneers with lasers and sonars;
- RSAL: each robot is found through a DeviceNode (thesis 3.6.2.1) and driven by the subsumption
  behaviour of :class:`rsal.robot.Pioneer` (avoid, escape, wall-follow; 3.6.2.4);
- the agents: one :class:`agents.classes.WallfollowAgent` per robot on an in-process agent host,
  each broadcasting its robot's position on the ``send_position`` service (3.6.1), and a listener
  agent that receives those broadcasts, as a team agent would.

It prints progress (true distance per robot, positions broadcast), a line on how to watch the run
live (``rsal watch``) and steer robots (``rsal control``), and a summary. The verdict comes from the
simulator's ground truth (``sim:simulation:0`` ``get_pose``), not from what the robots believe:
exit 0 when every robot truly travelled at least ``--min-distance`` metres and its agent's
broadcasts arrived, 1 otherwise, 130 on Ctrl-C (everything stopped cleanly either way).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import signal
import sys
import time
from collections import Counter
from pathlib import Path

from rsal.cliutil import positive
from rsal.errors import RsalError
from rsal.procs import Child
from rsal.transport import DEFAULT_ENDPOINT, TransportArgs, port_free

__all__ = ["register", "run_demo"]

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_WORLD = ROOT / "maps" / "floor.world"
MOVED = 0.05  # m of true displacement that counts as "moving"


class _Failure(RsalError):
    """The demo cannot go on: one line for the user."""


def run_demo(args: argparse.Namespace) -> int:
    endpoint = args.endpoint
    if not port_free(endpoint):
        print(
            f"rsal demo: {endpoint} is in use (another rsal server?); stop it or pass --endpoint tcp/127.0.0.1:PORT",
            file=sys.stderr,
        )
        return 1
    world = Path(args.world)
    if not world.exists():
        print(f"rsal demo: world {str(world)!r} not found", file=sys.stderr)
        return 1
    t_start = time.monotonic()
    cmd = [sys.executable, "-m", "rsal.cli", "sim", str(world), "--listen", endpoint, "--speedup", str(args.speedup)]
    print(f"[demo] starting the simulator: {world.name} at {args.speedup:g}x real time on {endpoint}", flush=True)
    # its output is read (so its pipe never fills), the last lines kept for error messages, and its
    # progress and error lines shown as they come
    sim = Child("sim", cmd, kind="sim", on_line=_relay, keep=15)
    stopping: list[int] = []
    old = {s: signal.signal(s, lambda n, f: stopping.append(n)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return asyncio.run(_demo(args, sim, stopping, t_start))
    except _Failure as e:
        print(f"rsal demo: {e}", file=sys.stderr, flush=True)
        return 130 if stopping else 1
    finally:
        sim.stop(_SIM_STOP)
        for s, h in old.items():
            signal.signal(s, h)


async def _demo(args: argparse.Namespace, sim: Child, stopping: list[int], t_start: float) -> int:
    from rsal.client import Fabric
    from rsal.msgs import RpcError
    from rsal.transport import open_session

    from .classes import WallfollowAgent
    from .runtime import Agent, AgentHost
    from .services import SendPosition

    class Listener(Agent):
        """Receives every ``send_position`` broadcast, as a team agent would (thesis 3.6.1)."""

        def __init__(self) -> None:
            super().__init__("demo-listener", period=1.0)
            self.heard: Counter[str] = Counter()

        async def created(self) -> None:
            self.subscribe(SendPosition.SERVICE, lambda m: self.heard.update([m.body.robot]))

    session = await asyncio.to_thread(open_session, TransportArgs(connect=[args.endpoint]))
    async with AgentHost(session, own_session=True) as host:
        fab = Fabric(session, own_session=False)
        node = fab.node("*:simulation:0")
        deadline = time.monotonic() + args.startup_timeout
        while not node.is_alive("sim:simulation:0"):  # the simulator compiles its kernels on a first run
            if sim.poll() is not None:
                raise _Failure("the simulator stopped during start-up; its output:\n" + _drain(sim))
            if stopping:
                raise _Failure("stopped")
            if time.monotonic() > deadline:
                raise _Failure(
                    f"the simulator did not come up within {args.startup_timeout:g} s; its output:\n" + _drain(sim)
                )
            await asyncio.sleep(0.05)
        sim_dev = node.device("sim:simulation:0")
        names = (await asyncio.to_thread(sim_dev.models))["robots"]  # errors: one line by rsal's error net
        start = {n: await asyncio.to_thread(sim_dev.get_pose, n) for n in names}
        listener = await host.start(Listener())
        agents = []
        for i, name in enumerate(names):
            a = WallfollowAgent(f"wallfollow-{name}", robot=name, simulation=True, startup_timeout=30.0)
            a.side = "left" if i % 2 == 0 else "right"
            agents.append(a)

        async def start_agent(a: WallfollowAgent) -> None:
            await a.find_robot(Fabric(session, own_session=False))
            await host.start(a)

        try:
            await asyncio.gather(*(start_agent(a) for a in agents))
        except (TimeoutError, RpcError, OSError) as e:
            raise _Failure(f"could not start the agents: {e}") from None
        print(
            f"[demo] {len(agents)} agents drive {', '.join(names)} through RSAL (wall-following) and broadcast "
            "their positions on svc/send_position",
            flush=True,
        )
        print(
            "[demo] while it runs: 'rsal watch' shows it live in Rerun; 'rsal control' opens the control center "
            "(scenarios, goals, stop) on http://127.0.0.1:8470",
            flush=True,
        )

        travelled = dict.fromkeys(names, 0.0)
        last = dict(start)
        first_move: float | None = None
        t0 = time.monotonic()
        next_report = t0 + args.report_every
        t_sim = 0.0
        while time.monotonic() - t0 < args.duration and not stopping:
            if sim.poll() is not None:
                raise _Failure("the simulator stopped unexpectedly:\n" + _drain(sim))
            await asyncio.sleep(0.5)
            for n in names:  # ground truth, sampled
                try:
                    p = await asyncio.to_thread(sim_dev.get_pose, n)
                except RpcError:
                    continue
                travelled[n] += math.hypot(p.x - last[n].x, p.y - last[n].y)
                last[n] = p
                if first_move is None and math.hypot(p.x - start[n].x, p.y - start[n].y) > MOVED:
                    first_move = time.monotonic() - t_start
                    print(f"[demo] first robot moving {first_move:.1f} s after the demo started", flush=True)
            st = sim_dev.latest
            t_sim = st.t if st else t_sim
            if time.monotonic() >= next_report:
                next_report += args.report_every
                parts = [f"{n} {travelled[n]:5.1f} m ({listener.heard[n]} positions)" for n in names]
                print(f"[demo] t={t_sim:6.1f} s  " + "  ".join(parts), flush=True)
        wall = time.monotonic() - t0
        states = {
            a.robot: (a.pioneer.state if a.pioneer else "?", a.pioneer.behaviour.escapes if a.pioneer else 0)
            for a in agents
        }
        sent = {a.robot: a.sent for a in agents}
        for a in agents:
            await host.kill(a)
        ok_dist = all(travelled[n] >= args.min_distance for n in names)
        ok_heard = all(listener.heard[n] > 0 for n in names)
        print("[demo] summary (distances from the simulator's ground truth):", flush=True)
        for n in names:
            state, escapes = states[n]
            print(
                f"[demo]   {n}: travelled {travelled[n]:.1f} m, {escapes} escape(s), final behaviour {state}, "
                f"{sent[n]} position(s) broadcast, {listener.heard[n]} received",
                flush=True,
            )
        verdict = "ok"
        if not ok_dist:
            verdict = f"FAILED (a robot did not move {args.min_distance:g} m)"
        elif not ok_heard:
            verdict = "FAILED (an agent's broadcasts did not arrive)"
        print(
            f"[demo]   robots={len(names)} agents={len(agents) + 1} sim_seconds={t_sim:.1f} wall_seconds={wall:.1f} "
            f"first_move_s={first_move if first_move is not None else float('nan'):.1f} result={verdict}",
            flush=True,
        )
        print(
            "[demo] next: 'rsal run deploy/scenarios/hunt_prey.yaml --app virtual' (Hunt and Prey), "
            "'rsal control' (the control center), docs/scenarios.md",
            flush=True,
        )
        if stopping:
            return 130
        return 0 if ok_dist and ok_heard else 1


_RELAYED = ("[sim] compiling", "[sim] kernels", "rsal sim:")  # its progress and error lines, shown as they come
_SIM_STOP = ((signal.SIGTERM, 10.0),)  # the simulator stops on SIGTERM; SIGKILL after 10 s


def _relay(line: str) -> None:
    if line.startswith(_RELAYED):
        print(line, flush=True)


def _drain(sim: Child) -> str:
    """Stop the simulator and return its last lines."""
    sim.stop(_SIM_STOP)
    return "\n".join(sim.lines)


def register(sub) -> None:
    p = sub.add_parser(
        "demo", help="run the embedded default: simulator, robots driven by wall-following agents, headless"
    )
    p.add_argument("--world", default=str(DEFAULT_WORLD), help="world file (default maps/floor.world)")
    p.add_argument("--duration", type=positive, default=30.0, help="wall seconds to run (default 30)")
    p.add_argument("--speedup", type=positive, default=2.0, help="simulation speed-up (default 2)")
    p.add_argument("--endpoint", default=DEFAULT_ENDPOINT, help=f"loopback endpoint (default {DEFAULT_ENDPOINT})")
    p.add_argument("--report-every", type=positive, default=5.0, help="seconds between progress lines")
    p.add_argument("--min-distance", type=float, default=2.0, help="metres each robot must travel (default 2)")
    p.add_argument("--startup-timeout", type=positive, default=120.0, help=argparse.SUPPRESS)
    p.set_defaults(func=run_demo)
