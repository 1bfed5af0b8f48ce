"""``rsal agent CLASS --robot ID``: start one agent on any host (thesis 3.5 and 3.6.1).

The thesis starts each agent with its arguments: the host and port of the platform, the robot it
controls and whether that robot's laser is used (3.5). Here the host is whatever the transport
flags reach (``--connect``/``--listen``/``--mode``), ``--robot`` names the robot and
``--laser/--no-laser`` switches its laser. The command opens one Zenoh session, finds the robot's
devices (off the loop), starts the agent on an :class:`~agents.runtime.AgentHost` and prints a
progress line every ``--report-every`` seconds. SIGTERM, SIGINT or ``--duration`` kill the agent —
its robot stopped, its token ``agents/<id>`` withdrawn — and exit 0. An unknown class, a bad
argument or a robot whose devices do not appear within ``--startup-timeout`` give one line on
stderr and exit 1.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import signal
import sys

from rsal.transport import TransportArgs, add_transport_args

__all__ = ["register", "run_agent"]


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive number")
    return v


def _fail(text: str) -> int:
    print(f"rsal agent: {text}", file=sys.stderr, flush=True)
    return 1


def run_agent(args: argparse.Namespace) -> int:
    from rsal.robot import RobotError

    from .classes import AGENT_CLASSES

    cls = AGENT_CLASSES.get(args.cls)
    if cls is None:
        return _fail(f"unknown agent class {args.cls!r}; classes: {', '.join(sorted(AGENT_CLASSES))}")
    agent_id = args.id or f"{args.cls.lower()}-{args.robot}"
    try:
        agent = cls(
            agent_id,
            robot=args.robot,
            period=args.period,
            laser=args.laser,
            report_every=args.report_every,
            startup_timeout=args.startup_timeout,
        )
    except ValueError as e:
        return _fail(str(e))
    try:
        return asyncio.run(_serve(args, agent))
    except (TimeoutError, RobotError) as e:
        return _fail(str(e))


async def _serve(args: argparse.Namespace, agent) -> int:
    from rsal.client import Fabric
    from rsal.transport import open_session

    from .runtime import AgentHost

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    got: list[str] = []

    def on_signal(sig: signal.Signals) -> None:
        got.append(sig.name)
        stop.set()

    for s in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(s, on_signal, s)
    targs = TransportArgs.from_namespace(args)
    print(
        f"[agent] starting {type(agent).__name__} {agent.id} for robot {agent.robot} "
        f"(laser {'on' if agent.laser else 'off'}, period {agent.period:g} s)",
        flush=True,
    )
    session = await asyncio.to_thread(open_session, targs)
    async with AgentHost(session, own_session=True) as host:
        fabric = Fabric(session, own_session=False)
        finding = asyncio.ensure_future(agent.find_robot(fabric))
        stopping = asyncio.ensure_future(stop.wait())
        await asyncio.wait({finding, stopping}, return_when=asyncio.FIRST_COMPLETED)
        if not finding.done():  # a signal while the devices were being looked for
            agent.abort()
            await asyncio.wait({finding})
            finding.exception()  # retrieved: the aborted search is no error
            fabric.close()
            print(f"[agent] {agent.id}: {got[0]} before the robot was found; stopped", flush=True)
            return 0
        if finding.exception() is not None:
            stopping.cancel()
            fabric.close()
            raise finding.exception()
        await host.start(agent)
        print(f"[agent] {agent.id} running: robot {agent.robot} wall-following, token agents/{agent.id}", flush=True)
        killed = asyncio.ensure_future(host.wait_killed(agent))
        t0 = loop.time()
        reason = ""
        while not reason:
            left = args.duration - (loop.time() - t0) if args.duration else math.inf
            timeout = min(args.report_every, max(0.0, left))
            await asyncio.wait({killed, stopping}, timeout=timeout)
            if stopping.done():
                reason = got[0] if got else "signal"
            elif killed.done():
                reason = "killed"
            elif args.duration and loop.time() - t0 >= args.duration:
                reason = f"duration {args.duration:g} s"
            else:
                print(f"[agent] {agent.id} t={loop.time() - t0:6.1f} s  {agent.status()}", flush=True)
        stopping.cancel()
        await host.kill(agent)
        killed.cancel()
        if agent.error is not None:
            return _fail(f"agent {agent.id} failed: {type(agent.error).__name__}: {agent.error}")
        print(f"[agent] {agent.id} stopped ({reason}): {agent.status()}", flush=True)
    return 0


def register(sub) -> None:
    p = sub.add_parser("agent", help="start one agent (e.g. WallfollowAgent) controlling a robot")
    p.add_argument("cls", metavar="CLASS", help="agent class: WallfollowAgent or EscapeAgent")
    p.add_argument("--robot", required=True, help="the robot (device node) the agent controls, e.g. r0")
    p.add_argument("--id", help="agent id (default <class>-<robot>, lower case)")
    p.add_argument("--period", type=_positive, default=0.1, help="control period in seconds (default 0.1)")
    p.add_argument(
        "--laser", action=argparse.BooleanOptionalAction, default=True, help="use the robot's laser (default on)"
    )
    p.add_argument("--duration", type=_positive, help="seconds to run (default: until SIGINT/SIGTERM)")
    p.add_argument("--report-every", type=_positive, default=5.0, help="seconds between progress lines (default 5)")
    p.add_argument(
        "--startup-timeout", type=_positive, default=30.0, help="seconds to wait for the robot's devices (default 30)"
    )
    add_transport_args(p)
    p.set_defaults(func=run_agent)
