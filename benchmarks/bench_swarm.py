"""Swarm: N robots and N agents broadcasting positions at 2 Hz (thesis 4.2.3, "100 robots").

For each N of ``--robots``: ``rsal sim`` runs a crowd of N sonar Pioneers in the 128 m arena
(:func:`agents.scenarios.swarm.crowd_world`) in one process; one agent host process runs N
:class:`agents.scenarios.swarm.SwarmAgent` (one Zenoh session, one shared control loop and one
shared ``send_position`` subscriber: :class:`agents.hub.RobotHub`), each wall-following/dispersing
its robot and broadcasting its pose every 0.5 s while every agent receives every other's. After
``--warmup`` seconds the figures are taken over ``--seconds`` wall seconds; then the broadcasts
stop and every receiver's count from every sender is compared with what the sender sent (exact delivery, no sampling).

Figures: published and delivered messages per second, delivery ratio, latency p50/p99/max
(receive wall time - the message's ``time``, log bins: an upper bound within 26 %), the
simulator's real-time factor (simulated / wall time, from its ``simulation`` device), the share
of the agents' 100 ms control period the shared control loop is busy, control cycles that
overran, and the CPU use of both processes; ``update_cpu_us`` is the CPU time of one robot's
behaviour update, ``host_cores_rt`` N x 10 Hz x that plus the host's other CPU per second (messages),
and ``sim_cores_rt`` the simulator's CPU seconds per simulated second: they estimate the cores each
process needs for real time from CPU time, which holds on a machine loaded by other work where the
wall-time figures do not. *Real time* means the simulator keeps >= 0.95 of real
time and fewer than 5 % of control cycles overrun.

Baseline in the same run (``--baseline``, on by default): the same N agents in one host with no
robots and no simulator, broadcasting a fixed pose: the messaging alone.

Neighbourhood form (``--neighbourhood R``): each N runs twice on the same crowd, whose
robots report their true pose (``localization "gps"``): all-to-all (``form=all``, the baseline) and
with broadcasts scoped to R m (``form=near``: :class:`agents.hub.RobotHub` listens only to the cells
of ``--cell-size`` m, default R, within R plus a margin of its robots). The near form's delivery is
judged on ground truth by a :class:`agents.scenarios.swarm.SwarmMonitor` in the host (started
before the agents, it listens to every cell and samples every robot's true pose twice a second):
every (receiver, broadcast) pair whose robots were within R at send time
(:class:`agents.scenarios.swarm.NeighbourhoodDelivery`). ``--all-max`` skips the all-to-all form above
that many robots.

Several agent hosts (``--hosts H``): H agent-host processes share the N robots in consecutive
blocks (as a scenario's ``hosts: H``), start together, measure the same window (files in a
temporary directory are their barrier) and exchange their senders' counts and, in the near form,
their agents' figures for the first host's monitor; the result line combines them (sums; the worse
host's control load and overruns; one latency histogram). Each host runs the swarm's vectorised
host step (:mod:`agents.scenarios.swarm.vector`) unless ``--no-vector``; ``--before`` also runs
each form as before, one host with every robot's own cycle, in the same run. ``--crowd``: the
hosts read and command their robots through the simulator's ``crowd`` device
(:mod:`agents.scenarios.swarm.crowd`: one describe, one data message per step, one command message
per cycle) instead of two device proxies per robot.

Output: ``bench=swarm key=value ...`` lines. Usage:
``python benchmarks/bench_swarm.py --robots 100,200,500 --seconds 30``;
``python benchmarks/bench_swarm.py --robots 100,300,1000 --neighbourhood 5``;
``python benchmarks/bench_swarm.py --robots 100,300 --hosts 2 --before --neighbourhood 5``
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


# ---------------------------------------------------------------------------- the agent host
def _cpu_seconds(pid: int) -> float:
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


async def _barrier(sync: Path, name: str, index: int, hosts: int, timeout: float, write: bool = True) -> None:
    """Wait until every host of the run has written ``<name><k>`` in ``sync`` (after writing its own)."""
    if write:
        (sync / f"{name}{index}").write_text("1")
    deadline = time.monotonic() + timeout
    while not all((sync / f"{name}{k}").exists() or (sync / f"{name}{k}.json").exists() for k in range(hosts)):
        if time.monotonic() > deadline:
            raise TimeoutError(f"bench_swarm: host {index}: the other agent hosts were not {name} in {timeout:g} s")
        await asyncio.sleep(0.1)


async def _host(args) -> dict:
    from agents.hub import RobotHub
    from agents.runtime import AgentHost
    from agents.scenarios.swarm import LatencyHistogram, SwarmAgent, SwarmMonitor
    from agents.services import SendPosition
    from rsal import gcpause
    from rsal.client import Fabric
    from rsal.transport import TransportArgs

    if args.steady_gc:  # as an agent-host process (agents.hostproc) does
        gcpause.tune()

    class BareAgent(SwarmAgent):
        """Broadcasts a fixed pose; no robot (the messaging baseline)."""

        async def created(self) -> None:
            self._join_hub()  # the host's RobotHub and its shared send_position subscription
            self.frame = "map"
            loop = asyncio.get_running_loop()
            self._next_report = loop.time() + (hash(self.id) % 1000) / 1000 * self.report_every
            self._next_stats = loop.time() + 1e9

        def pose_message(self):
            return SendPosition(self.robot, 1.0, 2.0, 0.0, "map")

        async def killed(self) -> None:
            if self._hub is not None:
                self._hub.detach(self)

    n = args.robots
    first, mine = args.first, args.count or n  # this host's robots: r<first> .. r<first + mine - 1>
    sync = Path(args.sync_dir) if args.sync_dir else None
    bare = args.mode == "bare"
    cls = BareAgent if bare else SwarmAgent
    if bare and args.index == 0:  # no simulator: the first host listens on its own port
        transport = TransportArgs(listen=[args.connect])
    else:
        transport = TransportArgs(connect=[args.connect])
    near = args.neighbourhood if args.form == "near" else 0.0
    async with AgentHost.connect(transport) as host:
        host.services.cache_publishers = args.pubcache
        RobotHub.loopback = args.loopback
        t0 = time.perf_counter()
        mon = None
        if near and args.index == 0:  # the ground-truth judge, listening to every cell before the first broadcast
            mon = SwarmMonitor(
                "monitor", robots=n, duration=1e9, neighbourhood=near, startup_timeout=300, await_reports=False
            )
            await host.start(mon)
        kw = {"neighbourhood": near, "cell_size": args.cell_size} if near else {}
        if near:
            kw["wildcard_cells"] = args.wildcard_cells
            kw["bundle"] = args.bundle
        kw["vector"] = args.vector
        if args.crowd and not bare:
            kw["crowd"] = True
        agents = [
            cls(f"swarm{i}", robot=f"r{i}", startup_timeout=300, stats_every=0, **kw)
            for i in range(first, first + mine)
        ]
        await asyncio.gather(*(host.start(a) for a in agents))
        startup = time.perf_counter() - t0
        if args.steady_gc:
            gcpause.freeze_startup()
        if sync is not None:  # every host measures the same window: all started first
            await _barrier(sync, "ready", args.index, args.hosts, args.host_timeout)
        sim = None
        if not bare:
            fab = Fabric(host.session, own_session=False)
            sim = fab.device("sim:simulation:0")
            await asyncio.to_thread(sim.wait_for_data, 30.0)
        await asyncio.sleep(args.warmup)

        def snapshot():
            hub = agents[0]._hub
            return {
                "t": time.perf_counter(),
                "cpu": time.process_time(),
                "sent": sum(a.sent for a in agents),
                "recv": sum(a.received for a in agents),
                "sim_t": sim.latest.t if sim is not None else 0.0,
                "cycles": hub.cycles,
                "busy": hub.busy_s,
                "overruns": hub.overruns,
                "busy_cpu": hub.busy_cpu_s,
                "updates": hub.updates,
            }

        for a in agents:  # measure latency over the window only
            a.latency = LatencyHistogram()
        prof = None
        if args.profile:  # the host loop's thread over the measured window (cProfile)
            import cProfile

            prof = cProfile.Profile()
            prof.enable()
        s0 = snapshot()
        sim_cpu0 = _cpu_seconds(args.sim_pid) if args.sim_pid else float("nan")
        await asyncio.sleep(args.seconds)
        s1 = snapshot()
        if prof is not None:
            prof.disable()
            out = f"{args.profile}.{args.form}.{n}.prof"
            prof.dump_stats(out)
            print(f"profile of the host loop: {out}", file=sys.stderr, flush=True)
        sim_cpu1 = _cpu_seconds(args.sim_pid) if args.sim_pid else float("nan")
        hist = LatencyHistogram()
        for a in agents:
            hist.merge(a.latency)
        for a in agents:
            a.stop_broadcast()
        sent = {a.id: a.sent for a in agents}
        if sync is not None:  # every host's senders, for the all-to-all count
            await asyncio.sleep(0.5)
            (sync / f"sent{args.index}.json").write_text(json.dumps(sent))
            await _barrier(sync, "sent", args.index, args.hosts, 60.0, write=False)
            for k in range(args.hosts):
                sent.update(json.loads((sync / f"sent{k}.json").read_text()))

        def counts():
            got = want = 0
            for a in agents:
                for s, c in sent.items():
                    if s != a.id:
                        first, _last, rec = a.senders.get(s, [0, -1, 0])
                        got += rec
                        want += c - first
            return got, want

        if near:  # ground truth: every receiver within the radius at send time
            await asyncio.sleep(2.0)  # the last broadcasts in flight, then beyond the monitor's settle time
            stats = {a.id: a.stats() for a in agents}
            res = None
            judge_s = 0.0
            got = want = 0
            if sync is not None and args.index > 0:  # the first host's monitor judges every host's agents
                (sync / f"stats{args.index}.json").write_text(json.dumps(stats))
            if mon is not None:
                for k in range(1, args.hosts):
                    f = sync / f"stats{k}.json"
                    deadline = time.monotonic() + 60
                    while not f.exists() and time.monotonic() < deadline:
                        await asyncio.sleep(0.2)
                    await asyncio.sleep(0.2)
                    stats.update(json.loads(f.read_text()))
                t_j = time.perf_counter()
                mon.account_sends()
                res = mon.delivery.result(stats, max_missing=40)
                got, want = res.received, res.expected
                judge_s = time.perf_counter() - t_j
                if res.missing:
                    print(f"missing (receiver, sender, seq, m): {res.missing}", file=sys.stderr, flush=True)
        else:
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline:
                got, want = counts()
                if got >= want:
                    break
                await asyncio.sleep(0.1)
            got, want = counts()
        wall = s1["t"] - s0["t"]
        cycles = max(1, s1["cycles"] - s0["cycles"])
        cpu = s1["cpu"] - s0["cpu"]
        upd_cpu = (s1["busy_cpu"] - s0["busy_cpu"]) / max(1, s1["updates"] - s0["updates"])
        extra = {}
        cells = agents[0]._hub._cells if near and not bare and agents[0]._hub is not None else None
        if cells is not None:  # the hub's cell subscription at the end of the window
            extra["cells"] = len(cells.cells)
            extra["cell_subs"] = cells.subscribers
            extra["cell_switches"] = cells.switches
            extra["cell_dups"] = cells.duplicates
            extra["pub_declared"] = host.services.publishers_declared
        extra["threads"] = _threads()  # the host process's OS threads (Zenoh's and its callbacks' included)
        if near and mon is not None:
            extra |= {
                "radius": near,
                "cell": args.cell_size or near,
                "monitor_missed": res.monitor_missed,
                "judge_s": round(judge_s, 2),
                "overlaps": mon.overlaps,
            }
        return {
            "robots": n,
            "hosts": args.hosts,
            "vector": args.vector,
            "crowd": bool(args.crowd and not bare),
            "pubcache": args.pubcache,
            "loopback": args.loopback,
            "wildcard_cells": args.wildcard_cells,
            "bundle": args.bundle,
            "bundles_sent": host.services.bundles_sent,
            "bundled": host.services.bundled_messages,
            "mode": args.mode,
            "form": "near" if near else "all",
            "startup_s": round(startup, 1),
            "publish_per_s": round((s1["sent"] - s0["sent"]) / wall, 1),
            "deliver_per_s": round((s1["recv"] - s0["recv"]) / wall, 1),
            "delivered": got,
            "expected": want,
            "delivery_pct": round(100.0 * got / want, 4) if want else 0.0,
            "p50_ms": round(1000 * hist.quantile(0.5), 2),
            "p99_ms": round(1000 * hist.quantile(0.99), 2),
            "max_ms": round(1000 * hist.max_s, 1),
            "rtf": round((s1["sim_t"] - s0["sim_t"]) / wall, 3) if sim is not None else None,
            "control_load": round((s1["busy"] - s0["busy"]) / (cycles * 0.1), 3) if not bare else None,
            "overrun_pct": round(100.0 * (s1["overruns"] - s0["overruns"]) / cycles, 2) if not bare else None,
            "host_cpu": round((s1["cpu"] - s0["cpu"]) / wall, 2),
            "sim_cpu": round((sim_cpu1 - sim_cpu0) / wall, 2) if args.sim_pid else None,
            # CPU per unit of work (load-independent): cores each process needs for real time
            "update_cpu_us": round(1e6 * upd_cpu, 1) if not bare else None,
            "host_cores_rt": round(n * 10 * upd_cpu + (cpu - (s1["busy_cpu"] - s0["busy_cpu"])) / wall, 2)
            if not bare
            else None,
            "sim_cores_rt": round((sim_cpu1 - sim_cpu0) / max(1e-9, s1["sim_t"] - s0["sim_t"]), 2)
            if args.sim_pid
            else None,
            **extra,
            "hist": hist.to_dict(),
        }


def _threads() -> int | None:
    """The OS threads of this process (Linux: /proc/self/status), None elsewhere."""
    try:
        with open("/proc/self/status") as f:
            return next((int(ln.split()[1]) for ln in f if ln.startswith("Threads:")), None)
    except OSError:
        return None


def host_main(args) -> None:
    print("RESULT " + json.dumps(asyncio.run(_host(args))), flush=True)


# ---------------------------------------------------------------------------- the driver
def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_host(
    n: int, mode: str, ep: str, args, sim_pid: int = 0, form: str = "all", hosts: int = 1, vector: bool = True
) -> dict:
    """Run ``hosts`` agent-host processes sharing the N robots in consecutive blocks (as a
    scenario's ``hosts:``); their figures combined into one result."""
    from agents.scenarios.swarm import LatencyHistogram

    with tempfile.TemporaryDirectory() as sync:
        procs = []
        for k in range(hosts):
            first, last = k * n // hosts, (k + 1) * n // hosts
            cmd = [sys.executable, __file__, "--role", "host", "--mode", mode, "--robots", str(n), "--connect", ep]
            cmd += ["--form", form, "--neighbourhood", str(args.neighbourhood), "--cell-size", str(args.cell_size)]
            cmd += ["--index", str(k), "--hosts", str(hosts), "--first", str(first), "--count", str(last - first)]
            cmd += ["--sync-dir", sync] + ([] if vector else ["--no-vector"])
            cmd += ["--crowd"] if args.crowd and vector else []
            if args.profile:
                cmd += ["--profile", f"{args.profile}.h{k}"]
            cmd += ["--seconds", str(args.seconds), "--warmup", str(args.warmup), "--sim-pid", str(sim_pid)]
            cmd += ["--host-timeout", str(args.host_timeout), "--wildcard-cells", str(args.wildcard_cells)]
            cmd += [] if args.pubcache else ["--no-pubcache"]
            cmd += [] if args.loopback else ["--no-loopback"]
            cmd += ["--bundle"] if args.bundle else []
            cmd += [] if args.steady_gc else ["--no-steady-gc"]
            procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT))
            if mode == "bare" and k == 0:
                time.sleep(1.0)  # the first host listens; the others connect to it
        results = []
        try:
            while any(p.poll() is None for p in procs):  # a host that ended without a result ends the run
                dead = [k for k, p in enumerate(procs) if p.poll() not in (None, 0)]
                if dead:
                    err = procs[dead[0]].stderr.read()
                    raise RuntimeError(
                        f"agent host {dead[0]} for {n} robots failed (exit {procs[dead[0]].returncode}):\n{err[-2000:]}"
                    )
                time.sleep(0.5)
            for p in procs:
                out, err = p.communicate(timeout=args.seconds + args.warmup + args.host_timeout)
                r = next((json.loads(ln[7:]) for ln in out.splitlines() if ln.startswith("RESULT ")), None)
                for ln in err.splitlines():  # the judge's few missing pairs, if any
                    if ln.startswith("missing "):
                        print(ln, file=sys.stderr, flush=True)
                if r is None:
                    raise RuntimeError(f"agent host for {n} robots failed (exit {p.returncode}):\n{err[-2000:]}")
                results.append(r)
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.wait(5)
    if len(results) == 1:
        r = results[0]
    else:
        r = dict(results[0])
        for key in (
            "publish_per_s",
            "deliver_per_s",
            "delivered",
            "expected",
            "host_cpu",
            "host_cores_rt",
            "bundles_sent",
            "bundled",
        ):
            if r.get(key) is not None:
                r[key] = round(sum(x[key] for x in results), 2)
        for key in ("startup_s", "control_load", "overrun_pct"):
            if r.get(key) is not None:
                r[key] = max(x[key] for x in results)
        if r.get("rtf") is not None:
            r["rtf"] = min(x["rtf"] for x in results)
        if r.get("update_cpu_us") is not None:
            r["update_cpu_us"] = round(sum(x["update_cpu_us"] for x in results) / len(results), 1)
        r["host_cpu_each"] = ",".join(str(x["host_cpu"]) for x in results)
        for key in ("cells", "cell_subs", "cell_switches", "cell_dups", "pub_declared", "threads"):
            if key in r:
                r[key] = ",".join(str(x.get(key)) for x in results)
        r["delivery_pct"] = round(100.0 * r["delivered"] / r["expected"], 4) if r["expected"] else 0.0
    hist = LatencyHistogram()
    for x in results:
        hist.merge(LatencyHistogram.from_dict(x.pop("hist")))
    r.pop("hist", None)
    r["p50_ms"] = round(1000 * hist.quantile(0.5), 2)
    r["p99_ms"] = round(1000 * hist.quantile(0.99), 2)
    r["max_ms"] = round(1000 * hist.max_s, 1)
    return r


def _line(r: dict) -> str:
    return "bench=swarm " + " ".join(f"{k}={v}" for k, v in r.items() if v is not None)


def run(args) -> None:
    largest: dict[str, int] = {}
    for n in args.robot_list:
        if args.baseline:
            ep = f"tcp/127.0.0.1:{_free_port()}"
            r = _run_host(n, "bare", ep, args, hosts=args.hosts)  # no simulator: the first host listens
            print(_line(r), flush=True)
        forms = ["all", "near"] if args.neighbourhood else ["all"]
        if args.neighbourhood and n > args.all_max:
            forms = ["near"]
        variants = [(1, False), (args.hosts, args.vector)] if args.before else [(args.hosts, args.vector)]
        for form in forms:
            for hosts, vector in variants:
                r = _run_sim_and_host(n, form, args, hosts, vector)
                realtime = (r["rtf"] or 0) >= 0.95 and (r["overrun_pct"] or 0) < 5.0
                r["realtime"] = realtime
                print(_line(r), flush=True)
                if realtime:
                    largest[f"{form} hosts={hosts} vector={vector}"] = n
    for form, n in largest.items():
        print(f"bench=swarm summary form={form} largest_realtime={n}", flush=True)


def _run_sim_and_host(n: int, form: str, args, hosts: int = 1, vector: bool = True) -> dict:
    from agents.scenarios.swarm import write_crowd_world
    from rsal.procs import die_with_parent

    with tempfile.TemporaryDirectory() as tmp:
        loc = "gps" if args.neighbourhood else "odom"  # both forms on the same crowd
        world = write_crowd_world(Path(tmp) / f"crowd{n}.world", n, seed=args.seed, localization=loc)
        ep = f"tcp/127.0.0.1:{_free_port()}"
        sim = subprocess.Popen(
            [sys.executable, "-m", "rsal.cli", "sim", str(world), "--listen", ep, "--no-map"]
            + ([] if args.sim_threads is None else ["--threads", str(args.sim_threads)]),
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
            **die_with_parent(),
        )
        try:
            return _run_host(n, "robots", ep, args, sim.pid, form, hosts, vector)
        finally:
            sim.terminate()
            try:
                sim.wait(10)
            except subprocess.TimeoutExpired:
                sim.kill()
                sim.wait(5)


def main() -> None:
    from agents.cellsub import DEFAULT_WILDCARD_ABOVE

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="100", help="comma-separated robot counts (default 100)")
    ap.add_argument("--seconds", type=float, default=30.0, help="measured wall seconds per run (default 30)")
    ap.add_argument("--warmup", type=float, default=5.0, help="seconds after start-up before measuring")
    ap.add_argument("--seed", type=int, default=0, help="seed of the crowd's headings")
    ap.add_argument("--no-baseline", dest="baseline", action="store_false", help="skip the messaging baseline")
    ap.add_argument(
        "--neighbourhood",
        type=float,
        default=0.0,
        help="radius (m): also run the neighbourhood-scoped form (0: all-to-all only)",
    )
    ap.add_argument(
        "--cell-size", type=float, default=0.0, help="cell side (m) of the neighbourhood form (default: the radius)"
    )
    ap.add_argument("--all-max", type=int, default=10**9, help="run the all-to-all form only up to this many robots")
    ap.add_argument(
        "--host-timeout", type=float, default=600.0, help="seconds an agent host may take beyond the run (start-up)"
    )
    ap.add_argument("--profile", default="", help="cProfile the agent host's loop into PREFIX.<form>.<n>.prof")
    ap.add_argument("--hosts", type=int, default=1, help="agent-host processes sharing the robots (default 1)")
    ap.add_argument(
        "--no-vector",
        dest="vector",
        action="store_false",
        help="each robot runs its own behaviour cycle (not the host's vectorised step)",
    )
    ap.add_argument(
        "--sim-threads",
        type=int,
        default=1,
        metavar="N",
        help="the simulator's ray-casting threads (rsal sim --threads; 1, the default and the thousand app's: "
        "the stepping thread alone, least CPU in all; -1: every core)",
    )
    ap.add_argument(
        "--crowd",
        action="store_true",
        help="the hosts read and command their robots through the simulator's crowd device (one message per step)",
    )
    ap.add_argument(
        "--before",
        action="store_true",
        help="also run each form as before: one host, no vectorised step (same run, same crowd)",
    )
    ap.add_argument(
        "--wildcard-cells",
        type=int,
        default=DEFAULT_WILDCARD_ABOVE,
        help="near form: a host watching more cells holds one wildcard subscriber filtered by cell "
        f"(default {DEFAULT_WILDCARD_ABOVE}; 0: a subscriber per cell always)",
    )
    ap.add_argument(
        "--no-pubcache",
        dest="pubcache",
        action="store_false",
        help="near form: every broadcast a Session.put instead of a cached publisher per agent and cell (as before)",
    )
    ap.add_argument(
        "--bundle",
        action="store_true",
        help="near form: each host puts its agents' broadcasts of ~10 ms as one sample (agents.services, bundles)",
    )
    ap.add_argument(
        "--no-loopback",
        dest="loopback",
        action="store_false",
        help="near form: a host's own broadcasts reach its cell subscription through Zenoh (as before), not in process",
    )
    ap.add_argument(
        "--no-steady-gc",
        dest="steady_gc",
        action="store_false",
        help="hosts keep the garbage collector's defaults (as before), not the agent hosts' settings (rsal/gcpause.py)",
    )
    ap.add_argument("--index", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--first", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--count", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--sync-dir", default="", help=argparse.SUPPRESS)
    ap.add_argument("--form", choices=["all", "near"], default="all", help=argparse.SUPPRESS)
    ap.add_argument("--role", choices=["main", "host"], default="main", help=argparse.SUPPRESS)
    ap.add_argument("--mode", choices=["robots", "bare"], default="robots", help=argparse.SUPPRESS)
    ap.add_argument("--connect", default="", help=argparse.SUPPRESS)
    ap.add_argument("--sim-pid", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.sim_threads < 0:
        args.sim_threads = None  # the world's (every core)
    if args.role == "host":
        args.robots = int(args.robots)
        host_main(args)
        return
    try:
        args.robot_list = [int(x) for x in args.robots.split(",") if x.strip()]
    except ValueError:
        sys.exit(f"bench_swarm: --robots {args.robots!r} must be comma-separated integers, e.g. 100,200")
    if args.hosts < 1 or any(n < args.hosts for n in args.robot_list):
        sys.exit(f"bench_swarm: --hosts {args.hosts} must be at least 1 and at most the smallest --robots count")
    if args.neighbourhood < 0 or args.cell_size < 0:
        sys.exit("bench_swarm: --neighbourhood and --cell-size must be >= 0 metres, e.g. --neighbourhood 5")
    run(args)


if __name__ == "__main__":
    main()
