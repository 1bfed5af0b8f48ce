"""The ``rsal`` command line.

``rsal`` itself knows the commands of the RSAL layer (``ls``, ``goto``, ``estop``, ``record``, ``play``,
``map``, ``tour``,
``router``, ``secure``, ``watch``); the other layers add theirs through the ``rsal.commands``
entry-point group (``serve`` and ``sim`` from ``mrs_bridge``, ``demo`` from ``agents``), so this package
never imports the layers above or beside it. Each entry point is a function ``register(subparsers)``
that adds a sub-command whose ``func(args) -> int`` runs it.

Every command runs inside one safety net (:func:`rsal.errnet.run_guarded`): a failure -- a bad
file or flag, nothing to talk to, a device that does not answer, a port in use, or a bug -- prints
one line on stderr naming what failed and what to do, and exits 1; Ctrl-C exits 130 after a clean
stop. ``-v`` (before or after the command) or ``RSAL_DEBUG=1`` adds the traceback, also in the
processes the command starts.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from importlib.metadata import entry_points

from .errnet import DEBUG_ENV, OneLineFormatter, debug_enabled, describe, install_thread_hook, run_guarded
from .transport import TransportArgs, add_transport_args

__all__ = ["main", "setup_logging"]


def setup_logging(verbosity: int = 0) -> None:
    """INFO by default, DEBUG with ``-v``; one line per record on stderr (a logged exception's
    traceback only in debug mode, see :func:`rsal.errnet.debug_enabled`).

    Zenoh's own (Rust) log stays silent by default, so that a refused connection or a retry does
    not add lines to a command's output; ``-v`` turns it on at warning level, and ``RUST_LOG``
    chooses the level explicitly (e.g. ``RUST_LOG=zenoh=debug``).
    """
    debug = debug_enabled(verbosity)
    handler = logging.StreamHandler()
    handler.setFormatter(OneLineFormatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S", debug=debug))
    logging.basicConfig(level=logging.DEBUG if verbosity > 0 else logging.INFO, handlers=[handler])
    try:
        import zenoh

        if verbosity > 0:
            zenoh.init_log_from_env_or("warn")
        elif os.environ.get("RUST_LOG"):
            zenoh.try_init_log_from_env()
    except Exception:  # the log is already set up, or this zenoh has no such call: keep the default
        pass


def _cmd_ls(args: argparse.Namespace) -> int:
    from .client import Fabric
    from .msgs import Describe, RpcError

    with Fabric.connect(TransportArgs.from_namespace(args)) as fab:
        node = fab.node(args.template)
        # Liveliness history arrives quickly; give the network the wait the user asked for.
        deadline = time.monotonic() + args.wait
        last = -1
        while time.monotonic() < deadline:
            n = len(node.devices())
            if n == last and n > 0 and time.monotonic() > deadline - args.wait / 2:
                break
            last = n
            time.sleep(0.1)
        devs = node.devices()
        if not devs:
            print(
                f"rsal ls: no devices match {args.template or '**'!r} (is a device server running? try "
                f"'rsal sim maps/floor.world')",
                file=sys.stderr,
            )
            return 1
        info: dict = {}
        for a in devs:
            try:
                info[a] = Describe.from_dict(fab.rpc(a, "describe", timeout=args.timeout))
            except Exception as e:  # one silent device must not hide the others
                info[a] = describe(e) if not isinstance(e, RpcError) else f"{e.code}: {e.message}"
        rows = [("NODE", "INTERFACE", "INDEX", "DRIVER", "RATE")]
        for a in devs:
            d = info[a]
            if isinstance(d, Describe):
                rows.append((a.node, a.interface, str(a.index), d.driver, f"{d.rate:g} Hz"))
            else:
                rows.append((a.node, a.interface, str(a.index), "?", "?"))
        widths = [max(len(r[i]) for r in rows) for i in range(5)]
        for r in rows:
            print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
        silent = [a for a in devs if not isinstance(info[a], Describe)]
        if silent:
            print(
                f"rsal ls: {len(silent)} device(s) did not answer 'describe' within {args.timeout:g} s (shown with ?), "
                f"e.g. {silent[0]}: {info[silent[0]]}",
                file=sys.stderr,
            )
    return 0


def _follow(args: argparse.Namespace, addr: str, node, planner, fut, t0: float) -> int:
    """Print progress lines until the goal's future is done (0); 1 after one error line when the
    planner is lost or ``--timeout`` runs out (the robot is then stopped)."""
    import math

    from .msgs import RpcError

    last_print = 0.0
    while not fut.done():
        now = time.monotonic()
        if not node.is_alive(addr):
            print(f"rsal goto: {addr}: the planner was lost (its server stopped?)", file=sys.stderr)
            return 1
        if now - t0 > args.timeout:
            try:
                planner.stop()
                print(f"rsal goto: {addr}: not there after {args.timeout:g} s; stopped", file=sys.stderr)
            except RpcError as e:
                print(f"rsal goto: {addr}: not there after {args.timeout:g} s; stop failed: {e}", file=sys.stderr)
            return 1
        if now - last_print >= args.progress:
            last_print = now
            m = planner.latest
            if m is not None:
                d = math.hypot(m.pose[0] - args.x, m.pose[1] - args.y)
                print(
                    f"[goto] {now - t0:5.1f} s  pose ({m.pose[0]:.2f}, {m.pose[1]:.2f})  {d:.2f} m to go  "
                    f"waypoint {m.waypoint_index}/{max(m.waypoint_count - 1, 0)}  {m.status}",
                    flush=True,
                )
        time.sleep(0.05)
    return 0


def _cmd_goto(args: argparse.Namespace) -> int:
    import math

    from .client import Fabric
    from .data import Position
    from .msgs import ErrorCode, RpcError

    addr = f"{args.node}:planner:{args.index}"
    with Fabric.connect(TransportArgs.from_namespace(args)) as fab:
        node = fab.node(addr)
        deadline = time.monotonic() + args.wait
        try:
            node.wait_for(addr, timeout=args.wait)
        except TimeoutError:
            print(
                f"rsal goto: no planner {addr} on the fabric within {args.wait:g} s (start one: "
                f"'rsal sim maps/floor.world --nav vfh', or a wavefront driver with 'rsal serve')",
                file=sys.stderr,
            )
            return 1
        planner = fab.device(addr)
        goal = Position(args.x, args.y, math.radians(args.yaw))
        while True:
            fut = planner.set_goal(goal, timeout=min(10.0, args.wait))
            err = fut.exception() if fut.done() else None
            # A planner that has just started answers "unavailable" until its map and a localized
            # pose are in: ask again until --wait runs out.
            if not (isinstance(err, RpcError) and err.code == ErrorCode.UNAVAILABLE and time.monotonic() < deadline):
                break
            time.sleep(0.2)
        if err is not None:
            print(f"rsal goto: {addr}: {describe(err)}", file=sys.stderr)
            return 1
        print(f"[goto] {addr}: goal ({args.x:g}, {args.y:g}, {args.yaw:g} deg), {planner.waypoint_count} waypoints")
        t0 = time.monotonic()
        try:
            if _follow(args, addr, node, planner, fut, t0):
                return 1
        except KeyboardInterrupt:  # the goal dies with the command: stop the robot, then exit 130
            try:
                planner.stop()
            except RpcError:
                pass
            raise
        try:
            fut.result()
        except RpcError as e:
            print(f"rsal goto: {addr}: {e}", file=sys.stderr)
            return 1
        m = planner.latest
        pose = f" at ({m.pose[0]:.2f}, {m.pose[1]:.2f}, {math.degrees(m.pose[2]):.0f} deg)" if m else ""
        print(f"[goto] {addr}: done after {time.monotonic() - t0:.1f} s{pose}", flush=True)
    return 0


def _cmd_estop(args: argparse.Namespace) -> int:
    from . import keys
    from .client import Fabric
    from .estop import estop

    if (args.robot is None) == (not args.all):
        print("rsal estop: name one robot (rsal estop r0) or --all for every robot on the fabric", file=sys.stderr)
        return 1
    if args.robot is not None:
        keys.check_name("robot", args.robot)
    with Fabric.connect(TransportArgs.from_namespace(args)) as fab:
        deadline = time.monotonic() + args.wait
        while True:  # the session may still be connecting: ask again until a base answers
            res = estop(fab.session, args.robot, release=args.release, timeout=min(2.0, args.wait))
            if res.confirmed or time.monotonic() >= deadline:
                break
    for text in res.failed:
        print(f"rsal estop: {text}", file=sys.stderr)
    if not res.confirmed:
        who = f"no base of {args.robot}" if args.robot else "no robot"
        print(
            f"rsal estop: {who} answered within {args.wait:g} s; check the robot is on the fabric (rsal ls) "
            "and the endpoint (--connect)",
            file=sys.stderr,
        )
        return 1
    print(res.summary(), flush=True)
    return 1 if res.failed else 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rsal", description="RSAL fabric: peer-to-peer multi-robot platform over Zenoh.")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    ls = sub.add_parser("ls", help="list the devices alive on the fabric")
    ls.add_argument("template", nargs="?", default="**", help="device template, e.g. 'r0:*:*' or 'rsal/*/laser/*'")
    ls.add_argument("--wait", type=float, default=1.0, help="seconds to collect devices (default 1)")
    ls.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for each describe reply")
    add_transport_args(ls)
    ls.set_defaults(func=_cmd_ls)
    go = sub.add_parser("goto", help="send a robot to a map pose through its planner and follow it there")
    go.add_argument("node", metavar="NODE", help="the robot, e.g. r0")
    go.add_argument("x", type=float, help="goal x in the map frame (m)")
    go.add_argument("y", type=float, help="goal y in the map frame (m)")
    go.add_argument("yaw", type=float, nargs="?", default=0.0, help="goal heading (degrees, default 0)")
    go.add_argument("--index", type=int, default=0, help="planner index (default 0)")
    go.add_argument("--timeout", type=float, default=300.0, help="give up after this many seconds (default 300)")
    go.add_argument(
        "--wait", type=float, default=10.0, help="seconds to wait for the planner to appear and be ready (default 10)"
    )
    go.add_argument("--progress", type=float, default=2.0, help="seconds between progress lines (default 2)")
    add_transport_args(go)
    go.set_defaults(func=_cmd_goto)
    es = sub.add_parser(
        "estop",
        help="latch (or release) the emergency stop of a robot or of every robot",
        description="Latch the emergency stop of ROBOT's bases, or of every base on the fabric with --all: they stop "
        "and refuse velocity commands until released with --release. Prints the robots that confirmed.",
    )
    es.add_argument("robot", metavar="ROBOT", nargs="?", help="the robot (node), e.g. r0")
    es.add_argument("--all", action="store_true", help="every robot on the fabric")
    es.add_argument("--release", action="store_true", help="release the latch instead of pressing it")
    es.add_argument("--wait", type=float, default=5.0, help="seconds to wait for the bases' answers (default 5)")
    add_transport_args(es)
    es.set_defaults(func=_cmd_estop)
    from .record import register as register_record

    register_record(sub)
    from .mapping.cli import register as register_mapping

    register_mapping(sub)
    from .router import register as register_router

    register_router(sub)
    from .secure import register as register_secure

    register_secure(sub)
    from .watch import register as register_watch

    register_watch(sub)
    for ep in sorted(entry_points(group="rsal.commands"), key=lambda e: e.name):
        try:
            ep.load()(sub)
        except Exception as e:  # a broken plug-in must not break the other commands
            print(f"rsal: command {ep.name!r} is unavailable: {e}", file=sys.stderr)
    for p in sub.choices.values():  # "-v" after the command too: "rsal ls -v"
        try:
            p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        except argparse.ArgumentError:  # the command has its own -v
            pass
    return ap


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and run the command inside the safety net; returns the exit code."""
    ap = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["map"]:  # its own parser: 'rsal map RUN.mcap ...', 'rsal map align ...', '--from-world'
        from .mapping.cli import main as map_main

        rest = [a for a in argv[1:] if a not in ("-v", "--verbose")]
        args = argparse.Namespace(command="map", verbose=len(argv) - 1 - len(rest), func=lambda _a: map_main(rest))
    else:
        args = ap.parse_args(argv)
    if not getattr(args, "func", None):
        ap.print_help()
        return 2
    verbose = getattr(args, "verbose", 0) or 0
    if verbose:
        os.environ[DEBUG_ENV] = "1"  # the processes this command starts keep their tracebacks too
    debug = debug_enabled(verbose)
    prog = f"rsal {args.command}"
    setup_logging(verbose)
    install_thread_hook(prog, debug=debug)
    return run_guarded(prog, lambda: args.func(args), debug=debug)


if __name__ == "__main__":
    sys.exit(main())
