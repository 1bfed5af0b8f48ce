"""``rsal ros2``: export the fleet to ROS 2 over rmw_zenoh's wire until stopped (docs/ros2.md)."""

from __future__ import annotations

import argparse
import os
import re
import sys

from rsal.transport import TransportArgs, add_transport_args

__all__ = ["register"]

_CHUNK = re.compile(r"^[A-Za-z0-9_\-.*]+$")


def _robots(text: str) -> tuple[str, ...]:
    pats = tuple(p.strip() for p in text.split(",") if p.strip())
    bad = [p for p in pats if not _CHUNK.match(p) or "**" in p]
    if not pats or bad:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give robot names or patterns separated by commas, e.g. 'r0,r1' or 'r*' "
            f"(letters, digits, _ - . and * only)"
        )
    return pats


def _domain(text: str) -> int:
    if not text.isdigit() or int(text) > 232:
        raise argparse.ArgumentTypeError(f"{text!r} must be a ROS domain id, an integer from 0 to 232")
    return int(text)


def register(sub) -> None:
    p = sub.add_parser(
        "ros2", help="export the fleet to ROS 2 (rmw_zenoh): scan, odom, tf, cmd_vel, amcl_pose, goal_pose, plan"
    )
    p.add_argument(
        "--robots",
        type=_robots,
        default=("*",),
        metavar="TEMPLATE",
        help="robots to export: names or patterns, comma-separated ('r0,r1', 'r*'; default every robot)",
    )
    p.add_argument(
        "--domain",
        type=_domain,
        default=None,
        help="ROS domain id (default: the ROS_DOMAIN_ID environment variable, else 0)",
    )
    p.add_argument(
        "--frame-prefix",
        default="{robot}/",
        metavar="TEMPLATE",
        help="prefix of every frame id, {robot} the robot's name (default '{robot}/': r0/odom, r0/base_link)",
    )
    p.add_argument(
        "--map-node",
        default="*",
        metavar="NODE",
        help="node of the map device published as /map (default: the first found; '' for none)",
    )
    p.add_argument("--map-frame", default="map", help="frame id of the shared floor plan (default map)")
    p.add_argument("--no-clock", action="store_true", help="no /clock, even when a simulator runs")
    p.add_argument("--node-name", default="rsal", help="the ROS node in each robot's namespace (default rsal)")
    add_transport_args(p)
    p.set_defaults(func=_run)


def _resolve_domain(args: argparse.Namespace) -> int | None:
    if args.domain is not None:
        return args.domain
    env = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not env:
        return 0
    try:
        return _domain(env)
    except argparse.ArgumentTypeError:
        print(
            f"rsal ros2: ROS_DOMAIN_ID={env!r} is not an integer from 0 to 232; fix it or pass --domain N",
            file=sys.stderr,
        )
        return None


def _run(args: argparse.Namespace) -> int:
    from rsal.client import Fabric
    from rsal.cliutil import stop_on_signals

    from .export import ExportConfig, Exporter

    domain = _resolve_domain(args)
    if domain is None:
        return 1
    try:
        args.frame_prefix.format(robot="r0")
    except (KeyError, IndexError, ValueError):
        print(
            f"rsal ros2: --frame-prefix {args.frame_prefix!r} may only use {{robot}}, e.g. '{{robot}}/'",
            file=sys.stderr,
        )
        return 1
    if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", args.node_name):
        print(f"rsal ros2: --node-name {args.node_name!r} is not a ROS node name (letters, digits, _)", file=sys.stderr)
        return 1
    if args.map_node and (not _CHUNK.match(args.map_node) or "**" in args.map_node):
        print(
            f"rsal ros2: --map-node {args.map_node!r} is not a node name or pattern (e.g. 'sim'; '' for no /map)",
            file=sys.stderr,
        )
        return 1
    config = ExportConfig(
        domain, tuple(args.robots), args.frame_prefix, args.node_name, args.map_frame, args.map_node, not args.no_clock
    )
    stop, _ = stop_on_signals()
    last: list[str] = []

    def progress(ex) -> None:
        robots = ex.robots()
        line = ", ".join(f"{n} ({' '.join(t)})" for n, t in robots.items()) or "none yet"
        fleet = ex.fleet_topics()
        if fleet:
            line += f"; fleet: {' '.join('/' + t for t in fleet)}"
        if line != (last[0] if last else None):
            last[:] = [line]
            print(f"rsal ros2: domain {domain}: {len(robots)} robot(s) exported: {line}", flush=True)

    with Fabric.connect(TransportArgs.from_namespace(args)) as fab, Exporter(fab, config, progress) as ex:
        print(
            f"rsal ros2: domain {domain}: looking for robots matching {','.join(config.robots)} "
            f"(zenoh id {ex.part.zid})",
            flush=True,
        )
        stop.wait()
    return 0
