"""The simulator server's CPU per simulated second, split by phase (``rsal sim`` on a crowd).

Runs the device server of ``rsal sim WORLD`` (default ``maps/swarm1000.world``: 1000 Pioneers with 8
sonars, localization "gps", the ``thousand`` app's world) in this process, as fast as possible, for
``--sim-seconds`` after ``--warmup`` simulated seconds, with no agents: the robots stand (``--drive
stand``) or drive fixed arcs (``--drive arcs``, default: each robot a seeded random forward speed
and turn rate, set once, so physics sees moving, colliding bodies and no controller costs CPU per
step). A subscriber process listens to ``rsal/**`` (as ``rsal watch`` or the recorder would;
``--listen KEYEXPR`` another key, e.g. ``rsal/*/crowd/*/data`` for the crowd device alone: a device
nobody subscribes to is not published), so every publication is delivered over TCP, and reports the
``data`` samples it received per interface over the whole run (``rx_<iface>``, ``rx_total``; beside
the server's ``published`` count: the same devices, the same rates, nothing lost).

Figures are CPU time, which holds on a shared machine where wall time does not: ``cores_rt`` =
process CPU seconds per simulated second (the cores real time needs), and its split by phase, each
from ``time.thread_time`` around the scheduler thread's calls: ``physics`` (pymunk ``Space.step``
and the motors), ``motion`` (acceleration limits, odometry), ``energy`` (:mod:`simulator.energy`),
``sensors`` (ray casting and the other sensors' steps), ``publish`` (the sim drivers' publications:
encoding plus Zenoh puts, ``encode`` and ``put`` apart where measured), ``crowd`` (the crowd
device's message: built and put), ``devices`` (the sim drivers' other per-device Python), ``server``
(the scheduler and everything else on that thread) and ``other_threads`` (the process's other
threads), split from ``/proc`` by thread: ``raycast_threads`` (numba's workers casting the rays
beside the scheduler thread: the ``sensors`` phase above is only the scheduler thread's part),
``zenoh_runtime`` (Zenoh's named Rust threads, sending the samples) and ``callback_threads``
(Zenoh's Python callback threads: one per subscriber, queryable and matching listener declared
with a Python callback). ``--threads 1`` casts the rays on the scheduler thread alone.
``--profile`` also prints cProfile's top functions.

Output: one parseable line, ``bench=sim_cpu key=value ...``.
Usage: ``python benchmarks/bench_sim_cpu.py [--world maps/swarm1000.world] [--sim-seconds 10]``
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

_SUB = r"""
import sys, time, collections
sys.path.insert(0, sys.argv[2])
from benchmarks.loopback import session
s = session(connect=sys.argv[1])
counts = collections.Counter()
def cb(sample):
    k = str(sample.key_expr).split("/")
    if k[-1] == "data":
        counts[k[2]] += 1
sub = s.declare_subscriber(sys.argv[3], cb)
print("ready", flush=True)
for line in sys.stdin:
    if line.startswith("mark"):
        last = -1
        while sum(counts.values()) != last:  # the samples still on their way arrive first
            last = sum(counts.values())
            time.sleep(0.5)
        print(" ".join(f"{k}={v}" for k, v in sorted(counts.items())) or "none", flush=True)
    else:
        break
"""


def thread_cpu() -> dict[int, tuple[str, float]]:
    """CPU seconds of every thread of this process so far, by thread id: (name, seconds)."""
    import os

    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                stat = f.read()
        except OSError:  # ended meanwhile
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        out[int(tid)] = (name, (int(fields[11]) + int(fields[12])) / tick)  # utime + stime
    return out


def split_threads(before, after, main: int, raycast: set[int]) -> dict[str, float]:
    """CPU seconds between two :func:`thread_cpu` snapshots of the threads besides ``main``:
    the ray caster's workers (``raycast``: numba's pool), Zenoh's runtime (its threads have names:
    ``app-0``, ``net-0``, ``rx-3``, ...) and the rest (Zenoh's Python callback threads)."""
    got = {"raycast_threads": 0.0, "zenoh_runtime": 0.0, "callback_threads": 0.0}
    for tid, (name, t1) in after.items():
        if tid == main:
            continue
        dt = t1 - before.get(tid, (name, 0.0))[1]
        if tid in raycast:
            got["raycast_threads"] += dt
        elif name != "python" and not name.startswith("python"):
            got["zenoh_runtime"] += dt
        else:
            got["callback_threads"] += dt
    return got


class Meter:
    """CPU time (this thread) of calls to wrapped functions, per phase."""

    def __init__(self):
        self.t: dict[str, float] = {}

    def wrap(self, phase: str, fn):
        clock = time.thread_time
        t = self.t
        t.setdefault(phase, 0.0)

        def timed(*a, **k):
            t0 = clock()
            try:
                return fn(*a, **k)
            finally:
                t[phase] += clock() - t0

        return timed


def instrument(world, server, meter: Meter) -> None:
    from mrs_bridge.drivers.sim import SimDriver, SimulationDriver

    world.space.step = meter.wrap("physics", world.space.step)
    world.bodies.run_motors = meter.wrap("physics", world.bodies.run_motors)
    world.drives.accelerate = meter.wrap("motion", world.drives.accelerate)
    world.drives.odometry = meter.wrap("motion", world.drives.odometry)
    world.batteries.step = meter.wrap("energy", world.batteries.step)
    for s in world.sensors.values():
        s.step = meter.wrap("sensors", s.step)
    # publishing: every sim driver's on_step (after the server looked the drivers up), and the
    # server's publish (encode + put) inside it
    orig_on_step = SimDriver.on_step
    SimDriver.on_step = meter.wrap("sim_drivers", orig_on_step)
    if hasattr(SimDriver, "on_world_step"):
        SimDriver.on_world_step = meter.wrap("sim_drivers", SimDriver.on_world_step)
    server.publish = meter.wrap("publish", server.publish)
    if hasattr(server, "publish_each"):
        server.publish_each = meter.wrap("publish", server.publish_each)
    SimulationDriver.update = meter.wrap("sim_update", SimulationDriver.update)
    from mrs_bridge.drivers.simcrowd import CrowdView

    CrowdView.on_step = meter.wrap("crowd", CrowdView.on_step)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", default=str(ROOT / "maps" / "swarm1000.world"))
    ap.add_argument("--sim-seconds", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=2.0, help="simulated seconds before measuring")
    ap.add_argument("--drive", choices=("stand", "arcs"), default="arcs")
    ap.add_argument("--no-listener", action="store_true", help="no subscriber process (nothing is published)")
    ap.add_argument(
        "--listen",
        default="rsal/**",
        help="the subscriber's key expression (default rsal/**, every device; rsal/*/crowd/*/data: the crowd only)",
    )
    ap.add_argument(
        "--always-publish",
        action="store_true",
        help="build and put every device's data even without a subscriber (the server before it asked)",
    )
    ap.add_argument("--no-phases", action="store_true", help="total CPU only (no timers around calls)")
    ap.add_argument("--profile", type=int, default=0, metavar="N", help="print cProfile's top N functions")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--threads",
        type=int,
        metavar="N",
        help="the ray caster's threads, as rsal sim --threads (0 or 1: the stepping thread alone; default every core)",
    )
    args = ap.parse_args()

    import numpy as np

    import mrs_bridge.drivers  # noqa: F401
    from benchmarks.loopback import free_port
    from mrs_bridge.cli import sim_config
    from mrs_bridge.server import DeviceServer
    from rsal.transport import TransportArgs, open_session
    from simulator.loader import load_world
    from simulator.world import World

    spec = load_world(args.world, seed=args.seed)
    spec.speedup = math.inf
    if args.threads is not None:
        spec.threads = max(1, args.threads)
    world = World(spec)
    # numba's pool starts with the first parallel cast: start it now, before Zenoh's threads, so
    # the threads that exist at this point besides this one are the ray caster's workers.
    import threading

    from simulator.raycast import cast_fans

    one = {k: np.zeros(1) for k in ("x", "y", "th0", "dth", "rmax")}
    cast_fans(None, {**one, "n": np.ones(1, dtype=np.int64), "owner": np.full(1, -1)})
    main_tid = threading.get_native_id()
    raycast_tids = set(thread_cpu()) - {main_tid}
    n = len(world.robot_names)
    if args.drive == "arcs":
        rng = np.random.default_rng(args.seed)
        for name in world.robot_names:
            world.set_velocity(name, float(rng.uniform(0.05, 0.3)), float(rng.uniform(-0.3, 0.3)))
    cfg = sim_config(world, source=str(args.world))
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    session = open_session(TransportArgs(mode="peer", listen=[ep]), server=True)
    sub = None
    if not args.no_listener:
        sub = subprocess.Popen(
            [sys.executable, "-c", _SUB, ep, str(ROOT), args.listen],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        assert sub.stdout.readline().strip() == "ready"
    if args.always_publish:  # the baseline: every device counts as listened to
        from mrs_bridge.server.devices import _Device

        _Device._on_match = lambda self, status: None
        _Device.listened = property(lambda self: True, lambda self, v: None)
        from mrs_bridge.drivers.simcrowd import CrowdView

        CrowdView.on_step = lambda self, w: None  # nor was there a crowd device
    server = DeviceServer(cfg, session, shared={"simulator.world": world})
    server.start()  # the arcs were set on the world, not commanded: no base guard times them out
    meter = Meter()

    def run_until(t_sim: float) -> None:
        while world.time < t_sim - 1e-9:
            server.run(until=time.monotonic() + 0.2)

    run_until(args.warmup)
    if not args.no_phases:
        instrument(world, server, meter)

    def mark() -> str:
        sub.stdin.write("mark\n")
        sub.stdin.flush()
        return sub.stdout.readline().strip()

    prof = None
    if args.profile:
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    cpu0 = thread_cpu()
    t0, p0, th0, w0 = world.time, time.process_time(), time.thread_time(), time.perf_counter()
    run_until(args.warmup + args.sim_seconds)
    t1, p1, th1, w1 = world.time, time.process_time(), time.thread_time(), time.perf_counter()
    cpu1 = thread_cpu()
    others = split_threads(cpu0, cpu1, main_tid, raycast_tids)
    if prof:
        prof.disable()
    sim = t1 - t0
    rates = ""
    if sub:
        got = dict(kv.split("=") for kv in mark().split() if "=" in kv)
        rates = " ".join(f"rx_{k}={v}" for k, v in sorted(got.items()))
        rates += f" rx_total={sum(int(v) for v in got.values())}"
        sub.stdin.write("quit\n")
        sub.stdin.flush()
        try:
            sub.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sub.kill()
    server.stop()
    server.close()
    session.close()
    total = (p1 - p0) / sim
    main_t = (th1 - th0) / sim
    out = {
        "robots": n,
        "drive": args.drive,
        "listener": "none" if args.no_listener else args.listen,
        "always_publish": args.always_publish,
        "sim_seconds": round(sim, 1),
        "rtf": round(sim / (w1 - w0), 3),
        "cores_rt": round(total, 3),
        "main_thread": round(main_t, 3),
        "other_threads": round(total - main_t, 3),
        **{k: round(v / (t1 - t0), 3) for k, v in others.items()},
        "threads": len(cpu1),
        "published_per_sim_s": round(server.stats["published"] / max(world.time, 1e-9)),
        "published": server.stats["published"],
    }
    if not args.no_phases:
        ph = {k: v / sim for k, v in meter.t.items()}
        world_phases = ph["physics"] + ph["motion"] + ph["energy"] + ph["sensors"]
        out.update({k: round(ph[k], 3) for k in ("physics", "motion", "energy", "sensors", "publish")})
        out["devices"] = round(ph["sim_drivers"] - ph["publish"], 3)
        out["crowd"] = round(ph.get("crowd", 0.0), 3)
        out["world_other"] = round(ph["sim_update"] - world_phases - ph["sim_drivers"] - ph.get("crowd", 0.0), 3)
        out["server"] = round(main_t - ph["sim_update"], 3)
    print("bench=sim_cpu " + " ".join(f"{k}={v}" for k, v in out.items()) + (" " + rates if rates else ""), flush=True)
    if prof:
        import pstats

        pstats.Stats(prof).sort_stats("tottime").print_stats(args.profile)
    return 0


if __name__ == "__main__":
    sys.exit(main())
