"""``rsal watch`` under a 100-robot fleet: does the logger keep up? (thesis 4.2.3 "100 robots", 5.2.3).

``rsal sim`` runs a crowd of ``--robots`` sonar Pioneers in the 128 m arena (the Swarm world of
:func:`agents.scenarios.swarm.crowd_world`): every robot publishes odometry and its sonar ring at 10 Hz and
its battery at 1 Hz (sonar:0 and ranger:0 are the same ring), so 100 robots put about 3,100
samples/s on the fabric; each robot drives a slow circle. In this process a
:class:`rsal.watch.Watcher` subscribes to all of it and logs to an ``.rrd`` file for ``--seconds``
after ``--warmup``.

Baseline in the same run: a bare Zenoh subscriber on the same key expression that only counts
samples (what arrives at all). Figures: samples/s in (baseline and watcher), samples/s the logger
took, superseded/s (overwritten before the logger took them: latest wins, by design), ``rr.log``
calls/s, scans/s skipped by the per-device scan rate limit, tick time mean/max against the tick
period (wall, and the logger thread's own CPU time: on a loaded machine the wall time includes
waiting for a core), late ticks, the most samples drained from Zenoh's ring buffer in one tick
against its capacity (a drain far below the capacity, not growing, is the sign the logger keeps
up; the latest-wins dict itself holds at most one sample per device), plus this process's CPU share.

*Keeps up* (the summary line): the most samples drained in one tick stays below half the ring's
capacity and the logger ticks at least 80 % of ``--rate`` times a second; late ticks are reported
on their own (on a shared machine they measure waiting for a core as much as the logger's work).

Output: ``bench=watch key=value ...`` lines. Usage:
``python benchmarks/bench_watch.py --robots 100 --seconds 20``
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", type=int, default=100, help="robots in the crowd (default 100)")
    ap.add_argument("--seconds", type=float, default=20.0, help="measured wall seconds (default 20)")
    ap.add_argument("--warmup", type=float, default=5.0, help="seconds before measuring (default 5)")
    ap.add_argument("--rate", type=float, default=10.0, help="logger ticks per second (default 10)")
    ap.add_argument("--seed", type=int, default=0, help="headings of the crowd (default 0)")
    args = ap.parse_args()

    import rerun as rr

    from agents.scenarios.swarm import write_crowd_world
    from rsal.msgs import VelocityCmd, encode
    from rsal.transport import TransportArgs, open_session
    from rsal.watch import Watcher, WatchOptions

    with tempfile.TemporaryDirectory() as tmp:
        world = write_crowd_world(Path(tmp) / "crowd.world", args.robots, seed=args.seed)
        ep = f"tcp/127.0.0.1:{_free_port()}"
        from rsal.procs import die_with_parent

        sim = subprocess.Popen(
            [sys.executable, "-m", "rsal.cli", "sim", str(world), "--listen", ep],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            **die_with_parent(),
        )
        try:
            session = open_session(TransportArgs(connect=[ep]))
            # ---- wait for every robot's odometry
            seen: set[str] = set()
            deadline = time.monotonic() + 120
            while len(seen) < args.robots and time.monotonic() < deadline:
                for r in session.liveliness().get("rsal/*/position2d/0", timeout=2.0):
                    if r.ok is not None:
                        seen.add(str(r.ok.key_expr))
                time.sleep(0.5)
            if len(seen) < args.robots:
                print(f"bench_watch: only {len(seen)} of {args.robots} robots appeared", file=sys.stderr)
                sys.exit(1)
            for key in seen:  # every robot drives a slow circle (the last command holds)
                session.put(f"{key}/cmd", encode(VelocityCmd(0.2, 0.2)))
            time.sleep(args.warmup)

            # ---- baseline: count what arrives
            count = [0]

            def bare(sample) -> None:
                count[0] += 1

            sub = session.declare_subscriber("rsal/**/data", bare)
            time.sleep(1.0)
            count[0] = 0
            t0 = time.monotonic()
            time.sleep(args.seconds)
            base_rate = count[0] / (time.monotonic() - t0)
            sub.undeclare()
            print(f"bench=watch case=baseline robots={args.robots} in_per_s={base_rate:.0f}", flush=True)

            # ---- the watcher, logging to a file
            rec = rr.RecordingStream("rsal_watch_bench")
            rec.save(str(Path(tmp) / "bench.rrd"))
            w = Watcher(session, rec, WatchOptions(rate=args.rate, report_every=1e9))
            w.start()
            w.setup()
            stop = threading.Event()
            ticks: list[float] = []
            tick_cpu: list[float] = []
            orig_tick = w.tick

            def timed_tick() -> None:
                t, c = time.perf_counter(), time.thread_time()
                orig_tick()
                ticks.append(time.perf_counter() - t)
                tick_cpu.append(time.thread_time() - c)

            w.tick = timed_tick  # type: ignore[method-assign]
            th = threading.Thread(target=w.run, args=(stop,), daemon=True)
            th.start()
            time.sleep(args.warmup)
            s = w.stats
            a = (s.n_in, s.taken, s.logged, s.downsampled, len(ticks), s.late)
            ticks_before = len(ticks)
            w.stats.drain_max = 0
            c0, t0 = _cpu(), time.monotonic()
            time.sleep(args.seconds)
            dt = time.monotonic() - t0
            cpu = (_cpu() - c0) / dt
            b = (s.n_in, s.taken, s.logged, s.downsampled, len(ticks), s.late)
            stop.set()
            th.join(10)
            w.close()
            rec.flush(timeout_sec=10.0)
            rec.disconnect()
            window = ticks[ticks_before:]
            cpu_window = tick_cpu[ticks_before:]
            cpu_ms = 1000 * sum(cpu_window) / max(len(cpu_window), 1)
            load = os.getloadavg()[0]
            mean_ms = 1000 * sum(window) / max(len(window), 1)
            max_ms = 1000 * max(window, default=0.0)
            in_rate = (b[0] - a[0]) / dt
            ticks_rate = (b[4] - a[4]) / dt
            taken = (b[1] - a[1]) / dt
            print(
                f"bench=watch case=watch robots={len(w._robots)} in_per_s={in_rate:.0f} taken_per_s={taken:.0f} "
                f"superseded_per_s={in_rate - taken:.0f} logged_per_s={(b[2] - a[2]) / dt:.0f} "
                f"scans_skipped_per_s={(b[3] - a[3]) / dt:.0f} ticks_per_s={ticks_rate:.1f} "
                f"tick_mean_ms={mean_ms:.1f} tick_max_ms={max_ms:.1f} tick_cpu_mean_ms={cpu_ms:.1f} "
                f"period_ms={1000 / args.rate:.0f} late_ticks={b[5] - a[5]} drain_max={s.drain_max} "
                f"ring={w.opts.ring} cpu_share={cpu:.2f} loadavg={load:.1f}",
                flush=True,
            )
            print(
                f"bench=watch summary keeps_up={int(s.drain_max < w.opts.ring // 2 and ticks_rate >= 0.8 * args.rate)} "
                f"cpu_fits_period={int(cpu_ms < 1000 / args.rate)} "
                f"in_vs_baseline={in_rate / max(base_rate, 1e-9):.2f}",
                flush=True,
            )
            session.close()
        finally:
            sim.terminate()
            try:
                sim.wait(10)
            except subprocess.TimeoutExpired:
                sim.kill()


if __name__ == "__main__":
    main()
