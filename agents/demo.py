"""``rsal demo``: the embedded default, end to end on loopback and headless.

Starts the simulator with its device server (``rsal sim``, a separate process) on the floor map,
finds every robot through a DeviceNode, gives each a :class:`rsal.robot.Pioneer` that
wall-follows with the subsumption behaviour (thesis 3.6.2.4), prints progress, and ends with a
summary: robots, distance each travelled, escapes, simulated and wall time. Exit 0 when every
robot travelled at least ``--min-distance`` metres, 1 otherwise; Ctrl-C stops everything cleanly.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from pathlib import Path

from rsal.cliutil import positive
from rsal.procs import die_with_parent
from rsal.transport import DEFAULT_ENDPOINT, TransportArgs, port_free

__all__ = ["register", "run_demo"]

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_WORLD = ROOT / "maps" / "floor.world"


def run_demo(args: argparse.Namespace) -> int:
    from rsal.client import Fabric
    from rsal.robot import Pioneer, robot_devices

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
    cmd = [sys.executable, "-m", "rsal.cli", "sim", str(world), "--listen", endpoint, "--speedup", str(args.speedup)]
    print(f"[demo] starting the simulator: {world.name} at {args.speedup:g}x real time on {endpoint}", flush=True)
    sim = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True, **die_with_parent()
    )
    stopping: list[int] = []
    old = {s: signal.signal(s, lambda n, f: stopping.append(n)) for s in (signal.SIGINT, signal.SIGTERM)}
    robots: list[Pioneer] = []
    try:
        with Fabric.connect(TransportArgs(connect=[endpoint])) as fab:
            node = fab.node("**")
            try:
                node.wait_for("sim:simulation:0", 1, timeout=args.startup_timeout)
            except TimeoutError:
                print("rsal demo: the simulator did not come up; its output:\n" + _drain(sim), file=sys.stderr)
                return 1
            sim_dev = node.device("sim:simulation:0")
            names = sim_dev.models()["robots"]
            for name in names:
                devs = robot_devices(node, name, timeout=args.startup_timeout)
                node.wait_for(f"{name}:*:*", len(devs), timeout=5)
                r = Pioneer(devs, name=name)
                r.position2d.wait_for_data(10)
                r.set_wallfollow(True, side="left" if len(robots) % 2 == 0 else "right")
                robots.append(r.start())
            print(f"[demo] {len(robots)} robots wall-following: {', '.join(names)}", flush=True)
            t0 = time.monotonic()
            next_report = t0 + args.report_every
            while time.monotonic() - t0 < args.duration and not stopping:
                if sim.poll() is not None:
                    print("rsal demo: the simulator stopped unexpectedly:\n" + _drain(sim), file=sys.stderr)
                    return 1
                time.sleep(0.1)
                if time.monotonic() >= next_report:
                    next_report += args.report_every
                    st = sim_dev.latest
                    parts = [f"{r.name} {r.distance:5.1f} m {r.state}" for r in robots]
                    t_sim = st.t if st else 0.0
                    print(f"[demo] t={t_sim:6.1f} s  " + "  ".join(parts), flush=True)
            st = sim_dev.latest
            wall = time.monotonic() - t0
            for r in robots:
                r.shutdown()
            ok = all(r.distance >= args.min_distance for r in robots)
            print("[demo] summary:", flush=True)
            for r in robots:
                print(
                    f"[demo]   {r.name}: travelled {r.distance:.1f} m, {r.behaviour.escapes} escape(s), "
                    f"final behaviour {r.state}",
                    flush=True,
                )
            t_sim = st.t if st else 0.0
            print(
                f"[demo]   robots={len(robots)} sim_seconds={t_sim:.1f} wall_seconds={wall:.1f} "
                f"result={'ok' if ok else 'FAILED (a robot did not move ' + str(args.min_distance) + ' m)'}",
                flush=True,
            )
            return 0 if ok and not stopping else (130 if stopping else 1)
    finally:
        for r in robots:
            r.shutdown()
        if sim.poll() is None:
            sim.send_signal(signal.SIGTERM)
            try:
                sim.wait(10)
            except subprocess.TimeoutExpired:
                sim.kill()
                sim.wait(5)
        for s, h in old.items():
            signal.signal(s, h)


def _drain(p: subprocess.Popen) -> str:
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()
    out = p.stdout.read() if p.stdout else ""
    return "\n".join(out.strip().splitlines()[-15:])


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the embedded default: simulator, robots and wall-following, headless")
    p.add_argument("--world", default=str(DEFAULT_WORLD), help="world file (default maps/floor.world)")
    p.add_argument("--duration", type=positive, default=30.0, help="wall seconds to run (default 30)")
    p.add_argument("--speedup", type=positive, default=2.0, help="simulation speed-up (default 2)")
    p.add_argument("--endpoint", default=DEFAULT_ENDPOINT, help=f"loopback endpoint (default {DEFAULT_ENDPOINT})")
    p.add_argument("--report-every", type=positive, default=5.0, help="seconds between progress lines")
    p.add_argument("--min-distance", type=float, default=2.0, help="metres each robot must travel (default 2)")
    p.add_argument("--startup-timeout", type=positive, default=60.0, help=argparse.SUPPRESS)
    p.set_defaults(func=run_demo)
