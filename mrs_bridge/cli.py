"""``rsal serve CONFIG`` and ``rsal sim WORLD``: run a device server; ``rsal warmup``: compile the
servers' kernels ahead of time (registered as ``rsal`` sub-commands through the ``rsal.commands``
entry points).

``rsal serve`` runs the drivers of a TOML configuration (see :mod:`mrs_bridge.config`).
``rsal sim`` is the shorthand of DESIGN "Processes": one server with the simulator in-process,
a ``simulation`` driver on node ``sim`` (``sim:simulation:0`` and the robots as arrays,
``sim:crowd:0``), the floorplan as ``sim:map:0`` and one ``sim`` driver per
robot model, whose devices live on the node named after the model (``r0:position2d:0``...); which
devices a robot has comes from its world model (:func:`mrs_bridge.drivers.sim.robot_devices`).
``--node NAME`` puts the simulation and map devices on another node, so that two simulators (e.g.
a virtual world and the stand-in for reality of a mixed-reality run, thesis 4.3) share one fabric.
The navigation stacks of ``--nav`` may run in other processes, as Player ran a planner server that
required ``6665:position2d:0`` (appendix A.3, ``planner_6666.cfg``): ``--nav-servers N`` leaves them
out of the simulator's server, and ``rsal sim WORLD --nav .. --nav-part I/N`` is a server with no
simulator that runs the stacks of every N-th robot from the I-th (robots ``I, I+N, ...`` of the
world's order), requiring each robot's devices and the map over the fabric; ``rsal run`` starts
them for a scenario's ``nav_servers`` (docs/scenarios.md). Two cores then share the load.
Both stop cleanly on SIGTERM or Ctrl-C: motors stopped, tokens withdrawn, session closed.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import time

from rsal.cliutil import brief, positive
from rsal.transport import TransportArgs, add_transport_args, open_session

from .config import ConfigError, DriverConfig, ServerConfig, load_config
from .server import DeviceServer, ServerError

__all__ = ["register_serve", "register_sim", "register_warmup", "sim_config", "run_server"]

log = logging.getLogger("mrs_bridge")


def run_server(cfg: ServerConfig, args: argparse.Namespace, *, shared: dict | None = None) -> int:
    """Open the session, start the drivers, serve until a signal, then shut down cleanly."""
    import mrs_bridge.drivers  # noqa: F401  (registers the built-in drivers)
    from rsal import gcpause

    prog = f"rsal {getattr(args, 'command', None) or 'serve'}"  # "rsal serve: ..." / "rsal sim: ..."
    stop_requested: list[int] = []
    server: DeviceServer | None = None
    started = False

    def on_signal(signum, frame):
        stop_requested.append(signum)
        if server is not None:
            server.stop()

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        session = open_session(TransportArgs.from_namespace(args), server=True)
    except ValueError as e:
        print(f"{prog}: {e}", file=sys.stderr)
        return 1
    server = DeviceServer(cfg, session, require_timeout=args.require_timeout, shared=shared)
    if stop_requested:
        server.stop()
    try:
        server.start()
        started = True
        # a long-running server: what start-up built (world, drivers, devices) is moved out of the
        # cyclic collector's reach, whose full collections had paused a 1000-robot simulator 200 ms
        gcpause.tune()
        gcpause.freeze_startup()
        n = len(server.devices)
        print(f"[serve] {cfg.source or 'server'}: {len(cfg.drivers)} driver(s), {n} device(s) up", flush=True)
        server.run()
        return 0
    except ConfigError as e:
        print(f"{prog}: {e}", file=sys.stderr)
        return 1
    except ServerError as e:
        print(f"{prog}: {e}", file=sys.stderr)
        return 1
    finally:
        server.close()
        try:
            session.close()
        except Exception:
            pass
        for sig, h in old.items():
            signal.signal(sig, h)
        if started:
            log.info("server stopped")


def _serve(args: argparse.Namespace) -> int:
    try:
        cfg = load_config(args.config_file, default_node=args.node)
    except ConfigError as e:
        print(f"rsal serve: {e}", file=sys.stderr)
        return 1
    return run_server(cfg, args)


TRUTH_INDEX = 3  # rsal sim --truth: <robot>:position2d:3, the ground-truth pose


def sim_config(
    world,
    *,
    map_device: bool = True,
    source: str = "",
    nav: str | None = None,
    nav_robots: list[str] | None = None,
    node: str = "sim",
    truth: bool = False,
    nav_part: tuple[int, int] | None = None,
    nav_elsewhere: bool = False,
) -> ServerConfig:
    """The server configuration of ``rsal sim`` for a loaded :class:`simulator.world.World`.

    With ``nav`` (``"vfh"``, ``"nd"`` or ``"snd"``) every robot with a laser (or those named in
    ``nav_robots``; ``["*"]``: every robot with a laser or a sonar ring) also gets the navigation
    stack of thesis appendix A.3: ``amcl`` (localize:0, position2d:2, started at the robot's true
    pose), the local planner (position2d:1) and ``wavefront`` (planner:0), all on the simulated
    floorplan ``sim:map:0``. ``node`` names the node of the simulation and map devices (default
    ``sim``). With ``truth`` every robot also gets
    ``position2d:3``, its ground-truth pose in the world frame (a ``sim`` driver with ``localization =
    "gps"``, describe frame ``gps``): what ``rsal record`` records as the reference of a run.
    ``nav_elsewhere``: the navigation stacks are left out (other servers run them). ``nav_part``
    ``(i, n)``: only the navigation stacks of robots ``i, i+n, ...`` of those that get one, and no
    simulation, map or robot devices (they are required over the fabric).
    """
    from rsal.keys import DeviceAddr, parse_device

    from .drivers.sim import robot_devices
    from .nav import profile

    def block(name, node, provides, requires=(), **params):
        return DriverConfig(
            name,
            [DeviceAddr(node, i, n) for i, n in provides],
            [parse_device(r) for r in requires],
            params,
            None,
            f"{source or 'sim'}: {name} {node}",
        )

    map_addr = f"{node}:map:0"
    drivers = []
    if nav_part is None:
        drivers.append(block("simulation", node, [("simulation", 0), ("crowd", 0)]))
        if map_device and world.grid is not None:
            drivers.append(block("simmap", node, [("map", 0)]))
        for name in world.robot_names:
            drivers.append(block("sim", name, robot_devices(world.model_spec(name)), model=name))
            if truth:
                drivers.append(block("sim", name, [("position2d", TRUTH_INDEX)], model=name, localization="gps"))
    if nav and not nav_elsewhere:
        if world.grid is None or not map_device:
            raise ConfigError(f"{source}: --nav needs the world's floorplan served as {map_addr}")
        wanted = set(nav_robots) if nav_robots else None
        if wanted and "*" in wanted:  # every robot with a ranger, sonar-only ones too
            wanted = {n for n in world.robot_names if world.model_spec(n).rangers}
        elif wanted:
            unknown = sorted(wanted - set(world.robot_names))
            if unknown:
                raise ConfigError(f"{source}: --nav-robots names unknown robot(s) {', '.join(unknown)}")
        stacked = []  # the robots that get a navigation stack, in the world's order
        for name in world.robot_names:
            spec = world.model_spec(name)
            has_laser = any(r.kind != "sonar" for r in spec.rangers)
            if wanted is not None and name not in wanted:
                continue
            if not spec.rangers:
                continue
            if not has_laser and wanted is None:
                continue
            stacked.append(name)
        if nav_part is not None:
            stacked = stacked[nav_part[0] :: nav_part[1]]
        for name in stacked:
            spec = world.model_spec(name)
            has_laser = any(r.kind != "sonar" for r in spec.rangers)
            rng = f"{name}:laser:0" if has_laser else f"{name}:sonar:0"
            x, y, a = world.get_pose(name)
            drivers.append(
                block(
                    "amcl",
                    name,
                    [("localize", 0), ("position2d", 2)],
                    [f"odometry::{name}:position2d:0", rng, map_addr],
                    init_pose=[x, y, math.degrees(a)],
                    init_pose_var=[0.05, 0.05, math.degrees(math.radians(5) ** 2)],
                    **{**profile.AMCL, **({} if has_laser else profile.AMCL_SONAR)},
                )
            )
            # The local planner's goal tolerances must be tighter than wavefront's (thesis A.3: "set this
            # to be GREATER than the corresponding threshold of the underlying position device").
            drivers.append(block(nav, name, [("position2d", 1)], [f"{name}:position2d:0", rng], **profile.LOCAL[nav]))
            drivers.append(
                block(
                    "wavefront",
                    name,
                    [("planner", 0)],
                    [f"output::{name}:position2d:1", f"input::{name}:position2d:2", map_addr],
                    **profile.WAVEFRONT,
                )
            )
    return ServerConfig(node=node, drivers=drivers, source=source)


def _sim(args: argparse.Namespace) -> int:
    from simulator import SimulatorError
    from simulator.loader import load_world
    from simulator.world import World

    try:
        spec = load_world(args.world, seed=args.seed)
        for w in spec.warnings:
            print(f"rsal sim: warning: {w}", file=sys.stderr)
        if args.fast:
            spec.speedup = math.inf
        elif args.speedup is not None:
            spec.speedup = args.speedup
        if args.threads is not None:
            spec.threads = max(1, args.threads)
        world = World(spec)
    except SimulatorError as e:
        print(f"rsal sim: {e}", file=sys.stderr)
        return 1
    if (args.nav_part or args.nav_servers) and not args.nav:
        print("rsal sim: --nav-part and --nav-servers need --nav (vfh, nd or snd): add it", file=sys.stderr)
        return 1
    try:
        cfg = sim_config(
            world,
            map_device=not args.no_map,
            source=str(args.world),
            nav=args.nav,
            nav_robots=args.nav_robots,
            node=args.node,
            truth=args.truth,
            nav_part=args.nav_part,
            nav_elsewhere=bool(args.nav_servers),
        )
    except ConfigError as e:
        print(f"rsal sim: {e}", file=sys.stderr)
        return 1
    if args.nav_part is not None:  # a navigation server: no simulator here
        i, n = args.nav_part
        robots = sorted({d.provides[0].node for d in cfg.drivers}, key=world.robot_names.index)
        print(
            f"[nav] {args.world}: part {i}/{n}: navigation stacks of {len(robots)} robot(s) ({brief(robots)})",
            flush=True,
        )
        return run_server(cfg, args)
    sp = "as fast as possible" if math.isinf(spec.speedup) else f"{spec.speedup:g}x real time"
    print(f"[sim] {args.world}: {len(world.robot_names)} robots ({brief(world.robot_names)}), {sp}", flush=True)
    t0 = time.monotonic()
    rc = run_server(cfg, args, shared={"simulator.world": world})
    wall = time.monotonic() - t0
    if 0 < spec.quit_time <= world.time + 1e-9:
        print(f"[sim] quit_time {spec.quit_time:g} s reached at t={world.time:.1f} s: stopped", flush=True)
    print(
        f"[sim] summary: robots={len(world.robot_names)} sim_seconds={world.time:.1f} wall_seconds={wall:.1f} "
        f"realtime_factor={world.time / wall if wall > 0 else 0:.2f}",
        flush=True,
    )
    return rc


def _part(text: str) -> tuple[int, int]:
    """``I/N`` with ``0 <= I < N``."""
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not I/N (e.g. 0/2: the first of two parts)") from None
    if not 0 <= i < n:
        raise argparse.ArgumentTypeError(f"{text!r}: I must be 0..N-1 (e.g. 0/2 and 1/2)")
    return i, n


def _node_name(text: str) -> str:
    from rsal.keys import DeviceAddr

    try:
        DeviceAddr(text, "simulation", 0)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not a node name ({e})") from None
    return text


def _threads(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of threads >= 0 (0: none besides the stepping one)")
    return n


def register_serve(sub) -> None:
    p = sub.add_parser("serve", help="run a device server from a TOML driver configuration")
    p.add_argument("config_file", metavar="CONFIG", help="TOML file of [[driver]] blocks (see docs/configuration.md)")
    p.add_argument("--node", help="node name for devices written without one (overrides [server] node)")
    p.add_argument(
        "--require-timeout",
        type=positive,
        default=30.0,
        help="seconds a driver waits for its required devices (default 30)",
    )
    add_transport_args(p)
    p.set_defaults(func=_serve)


def register_sim(sub) -> None:
    p = sub.add_parser("sim", help="run the simulator with one device server for all its robots")
    p.add_argument("world", metavar="WORLD", help="a Stage .world or YAML world file, e.g. maps/floor.world")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--speedup", type=positive, help="times real time (default: the world's)")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    p.add_argument("--seed", type=int, help="random seed (default: the world's)")
    p.add_argument(
        "--threads",
        type=_threads,
        metavar="N",
        help="threads for the ray casting, as Stage's 'threads' (0 or 1: the stepping thread alone, least CPU "
        "in all; default: the world's, else every core)",
    )
    p.add_argument("--no-map", action="store_true", help="do not serve the floorplan as NODE:map:0")
    p.add_argument(
        "--node",
        type=_node_name,
        default="sim",
        help="node of the simulation and map devices (default sim); another name lets two simulators share a fabric",
    )
    p.add_argument(
        "--nav",
        choices=("vfh", "nd", "snd"),  # mrs_bridge.nav.profile.LOCAL_PLANNERS
        help="add the navigation stack per robot: amcl, this local planner and wavefront (rsal goto)",
    )
    p.add_argument(
        "--nav-robots",
        type=lambda t: [x for x in t.split(",") if x],
        metavar="R0,R1",
        help="robots that get the navigation stack (default: every robot with a laser; '*': every robot "
        "with a laser or sonar)",
    )
    split = p.add_mutually_exclusive_group()
    split.add_argument(
        "--nav-servers",
        type=int,
        default=0,
        metavar="N",
        help="leave the navigation stacks to N other processes ('rsal sim WORLD --nav .. --nav-part I/N')",
    )
    split.add_argument(
        "--nav-part",
        type=_part,
        metavar="I/N",
        help="run no simulator: only the navigation stacks of robots I, I+N, ... requiring their devices "
        "over the fabric from a simulator started with --nav-servers N",
    )
    p.add_argument(
        "--truth",
        action="store_true",
        help="also serve each robot's ground-truth pose as ROBOT:position2d:3 (frame gps), e.g. to record it",
    )
    p.add_argument("--require-timeout", type=positive, default=30.0, help=argparse.SUPPRESS)
    add_transport_args(p)
    p.set_defaults(func=_sim)


def _warmup(args: argparse.Namespace) -> int:
    from . import kernels

    t0 = time.perf_counter()
    for group, (_, what) in kernels.GROUPS.items():
        print(f"[warmup] {what}: compiling (the first time only; up to a minute) or loading ...", flush=True)
        dt = kernels.prepare(group, label="warmup", notice_after=None)
        print(f"[warmup] {what}: ready in {dt:.1f} s", flush=True)
    print(f"[warmup] every kernel compiled or loaded from the cache in {time.perf_counter() - t0:.1f} s", flush=True)
    return 0


def register_warmup(sub) -> None:
    p = sub.add_parser(
        "warmup",
        help="compile the simulator's and navigation's kernels into numba's cache (the set-up runs it)",
    )
    p.set_defaults(func=_warmup)
