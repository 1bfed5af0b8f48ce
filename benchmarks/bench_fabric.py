"""Fabric overhead: a laser stream through the device server against raw Zenoh, in the same run.

Two pipelines carry the same bytes (an URG-04LX scan, 682 float32 ranges, msgpack-encoded as
:class:`rsal.msgs.RangerData`, about 2.8 kB) from one process to another over loopback TCP:

- **raw**: a bare ``zenoh`` publisher puts the pre-built message (only the stamp changes) in a loop;
  a bare ``zenoh`` subscriber decodes the msgpack map to read the stamp.
- **fabric**: ``rsal serve`` runs the ``replay`` driver (``stamp = "monotonic"``), so the scan goes
  through the server's scheduler, message classes and publisher; the client is an
  :class:`rsal.client.Fabric` with a :class:`rsal.devices.Laser` proxy whose listener runs inline
  (``add_listener(fn, inline=True)``), so the figure includes validation and decoding into a
  :class:`~rsal.msgs.RangerData` with a numpy array and the proxy's bookkeeping.
- **fabric-dispatch**: the same with an ordinary listener, which runs on the client's dispatcher
  thread (one thread hand-off per message); reported, not part of the verdict.

For each pipeline two runs: **throughput** (publisher as fast as it goes, messages/s that reach the
subscriber) and **latency** at a fixed rate well below saturation (``--rate``, default 200 Hz;
publish-to-listener time from the stamp, same clock on one machine, p50/p99). The subscriber skips
a warm-up second, then measures for ``--seconds``. ``--rounds`` (default 3) interleaves the runs and
keeps each mode's best, so a burst of load from other processes does not decide the ratio; the
verdict compares the best runs. ``paired_median_ratio`` is the median over rounds of fabric/raw
within one round (the two runs seconds apart), a second view of the same figure on a machine whose
speed drifts between rounds.

Targets: fabric throughput >= 80 % of raw, added p99 latency < 2 ms.
Output: one parseable line per figure, ``bench=fabric key=value ...``, and a verdict line.
Usage: ``python benchmarks/bench_fabric.py [--seconds 5] [--rate 200] [--quick]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from loopback import free_port  # benchmarks/loopback.py, beside this script

ROOT = Path(__file__).resolve().parent.parent
KEY = "bench/raw/laser"
SAMPLES = 682
WARMUP = 1.0


def zenoh_config(*, listen: str | None = None, connect: str | None = None):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    conf.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    return conf


def scan_message() -> dict:
    import numpy as np

    from rsal.msgs import RangerData

    fov = math.radians(240)
    return RangerData(0.0, np.full(SAMPLES, 1.0, dtype="<f4"), -fov / 2, fov / (SAMPLES - 1), 0.02, 5.6).to_dict()


# ---------------------------------------------------------------------------- child roles
def raw_pub(port: int, rate: float) -> None:
    import msgpack
    import zenoh

    s = zenoh.open(zenoh_config(listen=f"tcp/127.0.0.1:{port}"))
    pub = s.declare_publisher(KEY)
    msg = scan_message()
    period = 1.0 / rate if math.isfinite(rate) else 0.0
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print("ready", flush=True)
    due = time.monotonic()
    while not stop.is_set():
        if period:
            due += period
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        msg["t"] = time.monotonic()
        pub.put(msgpack.packb(msg))
    s.close()


def measure(port: int, mode: str, seconds: float) -> dict:
    """Subscribe (raw or through the RSAL client) and measure for ``seconds`` after a warm-up."""
    import msgpack
    import numpy as np

    lat: list[float] = []
    state = {"t0": None, "n": 0, "t_first": None, "t_last": None}
    done = threading.Event()

    def record(stamp: float) -> None:
        now = time.monotonic()
        if state["t0"] is None:
            state["t0"] = now
        if now - state["t0"] < WARMUP:
            return
        if state["t_first"] is None:
            state["t_first"] = now
        if now - state["t_first"] > seconds:
            done.set()
            return
        state["n"] += 1
        state["t_last"] = now
        lat.append(now - stamp)

    endpoint = f"tcp/127.0.0.1:{port}"
    if mode == "raw":
        import zenoh

        s = zenoh.open(zenoh_config(connect=endpoint))
        sub = s.declare_subscriber(KEY, lambda sample: record(msgpack.unpackb(sample.payload.to_bytes())["t"]))
        ok = done.wait(seconds + 30)
        sub.undeclare()
        s.close()
    else:  # fabric, fabric-dispatch
        from rsal.client import Fabric
        from rsal.transport import TransportArgs

        fab = Fabric.connect(TransportArgs(connect=[endpoint]))
        laser = fab.device("bench:laser:0")
        laser.add_listener(lambda scan: record(scan.t), inline=(mode == "fabric"))
        ok = done.wait(seconds + 30)
        fab.close()
    if not ok or state["n"] < 2:
        return {"error": f"received {state['n']} messages in the window"}
    a = np.array(lat) * 1e3
    span = state["t_last"] - state["t_first"]
    return {
        "msgs": state["n"],
        "rate": state["n"] / span if span > 0 else 0.0,
        "p50_ms": float(np.percentile(a, 50)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
    }


# ---------------------------------------------------------------------------- orchestration
def run_case(mode: str, rate: float, seconds: float) -> dict:
    port = free_port()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    if mode == "raw":
        args = [sys.executable, __file__, "_raw_pub", str(port), str(rate)]
        cfg_file = None
    else:
        cfg_file = tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False)
        rate_toml = "inf" if not math.isfinite(rate) else repr(float(rate))
        cfg_file.write(
            '[server]\nnode = "bench"\n\n[[driver]]\nname = "replay"\nprovides = ["laser:0"]\n'
            f'rate = {rate_toml}\nsamples = {SAMPLES}\nstamp = "monotonic"\n'
        )
        cfg_file.close()
        args = [sys.executable, "-m", "rsal.cli", "serve", cfg_file.name, "--listen", f"tcp/127.0.0.1:{port}"]
    from rsal.procs import die_with_parent

    pub = subprocess.Popen(
        args,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        cwd=ROOT,
        env=env,
        start_new_session=True,
        **die_with_parent(),
    )
    try:
        # wait until the publisher listens, so the subscriber's connect succeeds
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if pub.poll() is not None:
                return {"error": f"publisher exited: {pub.stdout.read().decode(errors='replace')[-500:]}"}
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.05)
        sub = subprocess.run(
            [sys.executable, __file__, "_measure", str(port), mode, str(seconds)],
            capture_output=True,
            text=True,
            cwd=ROOT,
            env=env,
            timeout=seconds + 90,
        )
        lines = [ln for ln in sub.stdout.splitlines() if ln.startswith("{")]
        if not lines:
            return {"error": f"subscriber failed: {(sub.stderr or sub.stdout)[-500:]}"}
        return json.loads(lines[-1])
    finally:
        if pub.poll() is None:
            os.kill(pub.pid, signal.SIGTERM)
            try:
                pub.wait(10)
            except subprocess.TimeoutExpired:
                os.kill(pub.pid, signal.SIGKILL)
                pub.wait(5)
        if cfg_file is not None:
            os.unlink(cfg_file.name)


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "_raw_pub":
        raw_pub(int(sys.argv[2]), float(sys.argv[3]))
        return 0
    if len(sys.argv) > 1 and sys.argv[1] == "_measure":
        print(json.dumps(measure(int(sys.argv[2]), sys.argv[3], float(sys.argv[4]))), flush=True)
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="measurement window per run (default 5)")
    ap.add_argument("--rate", type=float, default=200.0, help="fixed publish rate for latency, Hz (default 200)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds; the best run per mode counts")
    ap.add_argument("--quick", action="store_true", help="2 s windows, one round")
    a = ap.parse_args()
    seconds = 2.0 if a.quick else a.seconds
    if a.quick:
        a.rounds = 1
    res: dict[tuple[str, str], dict] = {}
    pairs: list[float] = []  # fabric/raw throughput of each round (runs next to each other in time)
    for rnd in range(1, a.rounds + 1):  # interleaved rounds; keep each mode's best (least disturbed) run
        for kind, rate in (("throughput", math.inf), ("latency", a.rate)):
            for mode in ("raw", "fabric", "fabric-dispatch"):
                print(f"# round {rnd}/{a.rounds} {kind}: {mode} ...", file=sys.stderr, flush=True)
                r = run_case(mode, rate, seconds)
                if "error" in r:
                    print(f"bench=fabric run={kind} mode={mode} error={r['error']!r}", flush=True)
                    return 1
                print(
                    f"bench=fabric round={rnd} run={kind} mode={mode} rate_hz={rate:g} msgs={r['msgs']} "
                    f"msgs_per_s={r['rate']:.0f} p50_ms={r['p50_ms']:.3f} p99_ms={r['p99_ms']:.3f} "
                    f"max_ms={r['max_ms']:.3f}",
                    flush=True,
                )
                best = res.get((kind, mode))
                better = best is None or (
                    r["rate"] > best["rate"] if kind == "throughput" else r["p99_ms"] < best["p99_ms"]
                )
                if better:
                    res[(kind, mode)] = r
                if kind == "throughput" and mode == "raw":
                    raw_rate = r["rate"]
                elif kind == "throughput" and mode == "fabric":
                    pairs.append(r["rate"] / raw_rate)
    thr = res[("throughput", "fabric")]["rate"] / res[("throughput", "raw")]["rate"]
    thr_d = res[("throughput", "fabric-dispatch")]["rate"] / res[("throughput", "raw")]["rate"]
    added = res[("latency", "fabric")]["p99_ms"] - res[("latency", "raw")]["p99_ms"]
    added50 = res[("latency", "fabric")]["p50_ms"] - res[("latency", "raw")]["p50_ms"]
    pairs.sort()
    paired = pairs[len(pairs) // 2] if len(pairs) % 2 else (pairs[len(pairs) // 2 - 1] + pairs[len(pairs) // 2]) / 2
    ok = thr >= 0.8 and added < 2.0
    verdict = "PASS" if ok else "MISS"
    print(
        f"bench=fabric throughput_ratio={thr:.2f} paired_median_ratio={paired:.2f} "
        f"dispatch_throughput_ratio={thr_d:.2f} "
        f"added_p50_ms={added50:.3f} added_p99_ms={added:.3f} target=ratio>=0.80,added_p99<2ms verdict={verdict}",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
