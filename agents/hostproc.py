"""An agent-host process: one Zenoh session, one :class:`~agents.runtime.AgentHost`, many agents
(thesis 3.5 and 3.6.1: the agents of an application started on a platform with their arguments).

``python -m agents.hostproc SCENARIO --app NAME --host GROUP [--set KEY=VALUE ...] --connect EP``
is what ``rsal run`` starts for each host group of a scenario: the host reads the same scenario
file with the same overrides through :func:`agents.scenario.load_scenario` (no schema of its own)
and runs the agents of application ``NAME`` whose host group is ``GROUP``
(:meth:`agents.scenario.Application.groups`). ``rsal agent CLASS`` runs the same code for one
agent, built from an :class:`~agents.scenario.AgentEntry` of its flags.

Each agent is built as ``resolve(cls)(id, robot=robot, **kwargs)`` with the global ``arguments``
its constructor accepts and its own ``args`` (:func:`agents.scenario.constructor_kwargs`). Agents
that drive a robot (an async ``find_robot(fabric)``, like :class:`agents.classes.RobotAgent`) look
for their devices concurrently, off the loop, so one slow robot does not hold up the others; then
each is started on the host. An agent whose ``robot_built_by_host`` is true (a swarm agent: its
host's hub builds every robot through one device node or the simulator's crowd device) skips that
search. Progress lines are ``[host NAME] ...`` on stdout, every
``--report-every`` seconds. SIGTERM or SIGINT stops every agent (robots stopped, tokens
``agents/<id>`` withdrawn) and exits 0. An agent that cannot be built or started gives one line on
stderr and exit 1 after the others are stopped, unless ``--tolerate-failures``; an agent whose
body failed makes the exit code 1 too. When every agent has ended on its own the process exits
(0, or 1 if one failed).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import signal
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from rsal.cliutil import CROWD, brief, positive
from rsal.errors import RsalError
from rsal.transport import TransportArgs, add_transport_args

from .scenario import AgentEntry, Scenario, ScenarioError, constructor_kwargs, load_scenario, parse_set

__all__ = ["HostError", "build_agent", "host_agents", "main", "serve_agents"]


class HostError(RsalError, ValueError):
    """A host group or an agent that cannot be built; the message is one line."""


def host_agents(scenario: Scenario, app: str, host: str) -> list[AgentEntry]:
    """The agents of application ``app`` that run in host group ``host``, in file order; raises
    :class:`HostError` naming what the scenario has instead."""
    application = scenario.applications.get(app)
    if application is None:
        known = ", ".join(scenario.applications)
        raise HostError(f"{scenario.source}: no application {app!r}; use one of {known}")
    groups = application.groups()
    if host not in groups:
        raise HostError(
            f"{scenario.source}: application {app!r} has no host group {host!r}; its groups: {', '.join(groups)}"
        )
    return groups[host]


def build_agent(entry: AgentEntry, arguments: dict[str, Any] | None = None):
    """``resolve(cls)(id, robot=..., **kwargs)``; an unknown class or a bad argument raises
    :class:`HostError` naming the agent."""
    from .registry import AgentClassError, resolve

    try:
        cls = resolve(entry.cls)
    except AgentClassError as e:
        raise HostError(str(e)) from None
    kwargs = constructor_kwargs(cls, entry.robot, arguments or {}, entry.args)
    try:
        return cls(entry.id, **kwargs)
    except (TypeError, ValueError) as e:
        raise HostError(f"agent {entry.id} ({cls.__name__}): {e}") from None


def _starting_line(agent) -> str:
    robot = f" for robot {agent.robot}" if agent.robot else ""
    opts = [f"laser {'on' if agent.laser else 'off'}"] if hasattr(agent, "laser") else []
    opts.append(f"period {agent.period:g} s")
    return f"starting {type(agent).__name__} {agent.id}{robot} ({', '.join(opts)})"


def _starting_lines(agents: list) -> list[str]:
    """A line per agent; for a crowd (more than :data:`rsal.cliutil.CROWD`), a line per run of
    agents of one class and options: ``starting 500 SwarmAgent swarm0..swarm499 for robots
    r0..r499 (laser off, period 0.1 s)``."""
    if len(agents) <= CROWD:
        return [_starting_line(a) for a in agents]
    groups: list[tuple[tuple, list]] = []
    for a in agents:
        kind = (type(a).__name__, _starting_line(a).rsplit(" (", 1)[-1], bool(a.robot))
        if groups and groups[-1][0] == kind:
            groups[-1][1].append(a)
        else:
            groups.append((kind, [a]))
    lines = []
    for (cls, opts, _), run in groups:
        robots = [a.robot for a in run if a.robot]
        on = f" for robots {brief(robots)}" if robots else ""
        lines.append(f"starting {len(run)} {cls} {brief(a.id for a in run)}{on} ({opts}")
    return lines


def _status(agent) -> str:
    status = getattr(agent, "status", None)
    return status() if callable(status) else agent.state


def _error_text(e: BaseException) -> str:
    from rsal.errnet import describe

    return describe(e)


async def serve_agents(
    agents: list,
    targs: TransportArgs,
    *,
    tag: str,
    fail: Callable[[str], None],
    report_every: float = 5.0,
    duration: float | None = None,
    tolerate_failures: bool = False,
    name_agents: bool = True,
    steady_gc: bool = False,
    each: bool = False,
) -> int:
    """Run ``agents`` on one host until SIGTERM/SIGINT, ``duration`` or their own end; returns the
    exit code. ``tag`` prefixes progress lines (``[agent]``, ``[host NAME]``); ``fail(line)`` reports
    an error line; ``name_agents`` puts the agent id in front of its errors. ``steady_gc`` (a process
    of its own: the agent-host processes) tunes the garbage collector and freezes what start-up left
    alive (:mod:`rsal.gcpause`), and the progress lines give the collector's longest pause. A crowd
    (more than :data:`rsal.cliutil.CROWD` agents) is started, running and stopped in a line each for
    all, with the statuses of the first few; ``each`` prints a line per agent anyway."""
    from rsal import gcpause
    from rsal.client import Fabric
    from rsal.clock import ENV as clock_env
    from rsal.clock import clock, sim_time_from_env
    from rsal.transport import open_session

    from .runtime import AgentHost

    loop = asyncio.get_running_loop()
    loop.set_default_executor(ThreadPoolExecutor(max_workers=max(8, len(agents) + 4)))
    stop = asyncio.Event()
    got: list[str] = []

    def on_signal(sig: signal.Signals) -> None:
        got.append(sig.name)
        stop.set()

    for s in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(s, on_signal, s)

    def error(agent, e: BaseException) -> None:
        fail(f"agent {agent.id}: {_error_text(e)}" if name_agents else _error_text(e))

    for line in _starting_lines(agents):
        print(f"{tag} {line}", flush=True)
    session = await asyncio.to_thread(open_session, targs)
    sim_clock = sim_time_from_env(session)  # RSAL_SIM_TIME: follow the simulation's clock
    if sim_clock is not None:
        print(f"{tag} on the simulation's clock ({clock_env}={os.environ[clock_env]})", flush=True)
        if not await asyncio.to_thread(sim_clock.wait_started, 60.0):
            fail(f"no time from the simulation within 60 s (is the simulator running? {clock_env} names its node)")
            session.close()
            return 1
    clk = clock()
    gc_watch = gcpause.GcWatch() if steady_gc else None
    if steady_gc:
        gcpause.tune()
    async with AgentHost(session, own_session=True) as host:
        fabrics: dict[str, Fabric] = {}

        async def start_one(agent) -> None:
            # an agent whose robot its host builds (a swarm's hub: one device node, or the crowd
            # device) is not searched for robot by robot first
            searches = hasattr(agent, "find_robot") and not getattr(agent, "robot_built_by_host", False)
            if searches and getattr(agent, "pioneer", True) is None:
                fabrics[agent.id] = Fabric(session, own_session=False)
                await agent.find_robot(fabrics[agent.id])
            await host.start(agent)

        starts = {a.id: asyncio.ensure_future(start_one(a)) for a in agents}
        stopping = asyncio.ensure_future(stop.wait())
        pending = set(starts.values())
        failed: list = []
        while pending and not stopping.done():
            _, pending = await asyncio.wait(pending | {stopping}, return_when=asyncio.FIRST_COMPLETED)
            pending.discard(stopping)
            failed = [a for a in agents if starts[a.id].done() and starts[a.id].exception() is not None]
            if failed and not tolerate_failures:
                break
        if pending:  # a signal or a failure while devices were being looked for: give the searches up
            for a in agents:
                if not starts[a.id].done() and hasattr(a, "abort"):
                    a.abort()
            await asyncio.wait(pending)
            for a in agents:
                if starts[a.id] in pending and starts[a.id].exception() is not None:  # retrieved: no error
                    why = got[0] if stopping.done() else "another agent failed"
                    print(f"{tag} {a.id}: {why} before it was started; stopped", flush=True)
                    if a.id in fabrics:
                        fabrics[a.id].close()
        if stopping.done() and not failed:
            await host.stop()
            print(f"{tag} stopped ({got[0] if got else 'signal'})", flush=True)
            return 0
        for a in failed:
            error(a, starts[a.id].exception())
            if a.id in fabrics:
                fabrics[a.id].close()
        failed = [a for a in agents if starts[a.id].exception() is not None]
        running = [a for a in agents if a not in failed]
        if failed and (not tolerate_failures or not running):
            stopping.cancel()
            await host.stop()
            return 1
        if len(running) <= CROWD or each:
            for a in running:
                robot = f" on robot {a.robot}" if a.robot else ""
                print(f"{tag} {a.id} running: {type(a).__name__}{robot}, token agents/{a.id}", flush=True)
        else:
            ids = brief(a.id for a in running)
            print(f"{tag} {len(running)} agents running: {ids}, tokens agents/<id>", flush=True)
        if steady_gc:  # start-up's objects out of every later collection's way
            frozen = await asyncio.to_thread(gcpause.freeze_startup)
            print(f"{tag} {len(running)} agent(s) started; {frozen} objects frozen out of the gc's way", flush=True)
        killed = {a.id: asyncio.ensure_future(host.wait_killed(a)) for a in running}
        t0 = clk.now()
        reason = ""
        ended: set[str] = set()
        while not reason:
            left = duration - (clk.now() - t0) if duration else math.inf
            await asyncio.wait(
                {stopping, *(k for aid, k in killed.items() if aid not in ended)},
                timeout=min(report_every, max(0.0, clk.wall(left))),
                return_when=asyncio.FIRST_COMPLETED,
            )
            for a in running:
                if killed[a.id].done() and a.id not in ended:
                    ended.add(a.id)
                    why = f"failed: {type(a.error).__name__}: {a.error}" if a.error is not None else "ended"
                    print(f"{tag} {a.id} {why}", flush=True)
            if stopping.done():
                reason = got[0] if got else "signal"
            elif len(ended) == len(running):
                reason = "killed" if len(running) == 1 else "all agents ended"
            elif duration and clk.now() - t0 >= duration:
                reason = f"duration {duration:g} s"
            elif left > 0 or not duration:
                if len(running) <= 4:
                    for a in running:
                        if a.id not in ended:
                            print(f"{tag} {a.id} t={clk.now() - t0:6.1f} s  {_status(a)}", flush=True)
                else:
                    n = len(running) - len(ended)
                    gcs = ""
                    if gc_watch is not None:
                        count, longest, total = gc_watch.take()
                        gcs = f", {count} gc pause(s), longest {1000 * longest:.0f} ms, {1000 * total:.0f} ms in all"
                    print(f"{tag} t={clk.now() - t0:6.1f} s  {n}/{len(running)} agents running{gcs}", flush=True)
        stopping.cancel()
        await asyncio.gather(*(host.kill(a) for a in running))
        for k in killed.values():
            k.cancel()
        errors = [a for a in running if a.error is not None]
        for a in errors:
            fail(f"agent {a.id} failed: {type(a.error).__name__}: {a.error}")
        ok = [a for a in running if a.error is None]
        shown = ok if len(ok) <= CROWD or each else ok[:3]
        for a in shown:
            print(f"{tag} {a.id} stopped ({reason}): {_status(a)}", flush=True)
        if len(shown) < len(ok):
            more = brief(a.id for a in ok[len(shown) :])
            n = len(ok) - len(shown)
            print(f"{tag} {n} more agents stopped ({reason}): {more} (-v: each one's status)", flush=True)
    return 1 if errors else 0  # failed starts returned 1 above unless tolerated


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m agents.hostproc", description="Run the agents of one host group of a scenario application."
    )
    ap.add_argument("scenario", metavar="SCENARIO", help="the scenario file (YAML or TOML) rsal run was given")
    ap.add_argument("--app", required=True, help="the application")
    ap.add_argument("--host", required=True, help="the host group whose agents run here")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="a global argument override, as rsal run's")
    ap.add_argument("--name", help="host name for progress lines (default: the host group)")
    ap.add_argument("--report-every", type=positive, default=5.0, help="seconds between progress lines (default 5)")
    ap.add_argument(
        "--tolerate-failures", action="store_true", help="run the agents that could start when others cannot"
    )
    ap.add_argument(
        "--remote",
        action="store_true",
        help="the scenario is a host daemon's copy: the files it names are on the runner's machine, not checked",
    )
    ap.add_argument("-v", "--verbose", action="count", default=0, help="debug log output")
    add_transport_args(ap)
    args = ap.parse_args(argv)
    from rsal.cli import setup_logging

    setup_logging(args.verbose)
    name = args.name or args.host
    prog = f"host {name}"

    def fail(line: str) -> None:
        print(f"{prog}: {line}", file=sys.stderr, flush=True)

    try:
        sc = load_scenario(args.scenario, parse_set(args.set or []), check_files=not args.remote)
        entries = host_agents(sc, args.app, args.host)
    except (ScenarioError, HostError) as e:
        fail(str(e))
        return 1
    here = str(sc.source.parent.resolve())  # module:Class names next to the scenario, as rsal run
    if here not in sys.path:
        sys.path.insert(0, here)
    agents = []
    for a in entries:
        try:
            agents.append(build_agent(a, sc.arguments))
        except HostError as e:
            fail(str(e))
            if not args.tolerate_failures:
                return 1
    if not agents:
        return 1
    try:
        return asyncio.run(
            serve_agents(
                agents,
                TransportArgs.from_namespace(args),
                tag=f"[host {name}]",
                fail=fail,
                report_every=args.report_every,
                tolerate_failures=args.tolerate_failures,
                steady_gc=True,
                each=args.verbose > 0,
            )
        )
    except ValueError as e:  # the session could not be opened
        fail(str(e))
        return 1


if __name__ == "__main__":
    from rsal.errnet import run_guarded

    sys.exit(run_guarded("hostproc", main))
