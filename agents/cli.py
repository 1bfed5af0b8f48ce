"""``rsal agent CLASS [--robot ID] [--arg KEY=VALUE ...]``: start one agent on any host (thesis 3.5, 3.6.1).

The thesis starts each agent with its arguments: the host and port of the platform, the robot it
controls and whether that robot's laser is used (3.5). Here the host is whatever the transport
flags reach (``--connect``/``--listen``/``--mode``), ``--robot`` names the robot and
``--laser/--no-laser`` switches its laser. CLASS is any class of :mod:`agents.registry` (or
``module:Class``); ``--arg KEY=VALUE`` passes further constructor arguments (VALUE read as YAML), and
the common flags are passed where the constructor takes them. The command opens one Zenoh session, finds the robot's
devices (off the loop), starts the agent on an :class:`~agents.runtime.AgentHost` and prints a
progress line every ``--report-every`` seconds. SIGTERM, SIGINT or ``--duration`` kill the agent —
its robot stopped, its token ``agents/<id>`` withdrawn — and exit 0. An unknown class, a bad
argument or a robot whose devices do not appear within ``--startup-timeout`` give one line on
stderr and exit 1. The work is done by :func:`agents.hostproc.serve_agents`, the code of every
agent-host process.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from rsal.cliutil import positive
from rsal.transport import TransportArgs, add_transport_args

__all__ = ["register", "run_agent"]


def _index(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = -1
    if v < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a device index (an integer >= 0)")
    return v


def _fail(text: str) -> int:
    print(f"rsal agent: {text}", file=sys.stderr, flush=True)
    return 1


def _yaml_arg(text: str) -> tuple[str, object]:
    from .scenario import ScenarioError, parse_set

    try:
        ((k, v),) = parse_set([text]).items()
    except ScenarioError as e:
        raise argparse.ArgumentTypeError(str(e).replace("--set", "--arg")) from None
    return k, v


def run_agent(args: argparse.Namespace) -> int:
    from .hostproc import HostError, build_agent, serve_agents
    from .scenario import AgentEntry

    robot = args.robot or ""
    short = args.cls.rpartition(":")[2].lower()
    agent_id = args.id or (f"{short}-{robot}" if robot else short)
    common = {
        "period": args.period,
        "laser": args.laser,
        "report_every": args.report_every,
        "startup_timeout": args.startup_timeout,
        "index": args.index,
        "simulation": args.simulation,
    }
    if args.pose is not None:
        common["pose"] = list(args.pose)
    try:
        agent = build_agent(AgentEntry(short, args.cls, agent_id, robot, dict(args.arg or [])), common)
    except HostError as e:
        return _fail(str(e))

    try:
        return asyncio.run(
            serve_agents(
                [agent],
                TransportArgs.from_namespace(args),
                tag="[agent]",
                fail=_fail,
                report_every=args.report_every,
                duration=args.duration,
                name_agents=False,
                steady_gc=True,
            )
        )
    except ValueError as e:  # the session could not be opened
        return _fail(str(e))


def register(sub) -> None:
    p = sub.add_parser("agent", help="start one agent (e.g. WallfollowAgent) controlling a robot")
    p.add_argument(
        "cls",
        metavar="CLASS",
        help="agent class: a registered name (e.g. WallfollowAgent, EscapeAgent) or module:Class",
    )
    p.add_argument("--robot", help="the robot (device node) the agent controls, e.g. r0")
    p.add_argument("--id", help="agent id (default <class>-<robot>, lower case)")
    p.add_argument(
        "--arg",
        action="append",
        type=_yaml_arg,
        metavar="KEY=VALUE",
        help="a constructor argument of the class (repeatable; VALUE is YAML: 2, 1.5, true, [1, 2], r0)",
    )
    p.add_argument("--period", type=positive, default=0.1, help="control period in seconds (default 0.1)")
    p.add_argument("--index", type=_index, default=0, help="the robot's base is position2d:INDEX (default 0)")
    p.add_argument(
        "--pose",
        type=float,
        nargs=3,
        metavar=("X", "Y", "DEG"),
        help="the robot's start pose on the map (m, m, degrees), for robots without localization",
    )
    p.add_argument(
        "--simulation",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="a simulated robot: take its start pose from the simulation (default off)",
    )
    p.add_argument(
        "--laser", action=argparse.BooleanOptionalAction, default=True, help="use the robot's laser (default on)"
    )
    p.add_argument("--duration", type=positive, help="seconds to run (default: until SIGINT/SIGTERM)")
    p.add_argument("--report-every", type=positive, default=5.0, help="seconds between progress lines (default 5)")
    p.add_argument(
        "--startup-timeout", type=positive, default=30.0, help="seconds to wait for the robot's devices (default 30)"
    )
    add_transport_args(p)
    p.set_defaults(func=run_agent)
