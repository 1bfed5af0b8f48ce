"""Recorder and player throughput: do ``rsal record`` and ``rsal play`` keep up with 100 robots' lasers at 10 Hz?

One process holds two Zenoh sessions on loopback TCP: a publisher session with ``--robots``
publishers ``rsal/r<i>/laser/0/data`` putting a URG-04LX scan (682 float32 ranges in the fabric's
msgpack layout, about 2.8 kB, its ``t`` stamp changing) at ``--hz`` each, and a second session
running :class:`rsal.record.Recorder` on ``**``. Publisher and recorder share one interpreter (one
GIL), so the figure is pessimistic against a recorder in a process of its own.

Two runs after a warm-up second: **paced** (robots x hz messages/s for ``--seconds``: the target;
verdict: nothing dropped and every message written) and **flood** (the publishers as fast as they
go for up to 3 s: the recorder's ceiling, messages/s written; Zenoh drops what the subscriber's
link cannot take and the recorder counts what its queue cannot). Fixed seed; time by
``time.perf_counter()``.
**play**: a recording of ``--robots`` lasers at ``--hz`` for ``--seconds`` (written with the
``mcap`` package in the layout of docs/recording.md, the robots' scans evenly interleaved, each
scan's ``t`` its recorded offset) is played by a real ``rsal play --rate 1`` process to a
subscriber in this process, which counts what arrives (drops: recorded minus received) and each
scan's lag: its arrival after the first scan's, minus its recorded offset after the first's
(p50, p99, max); the verdict: nothing dropped and p99 under 50 ms.

Output: one parseable line per figure, ``bench=record key=value ...`` / ``bench=play ...``, and a
verdict line each.
Usage: ``python benchmarks/bench_record.py [--robots 100] [--hz 10] [--seconds 10] [--quick] [--only record|play]``
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import ormsgpack

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from loopback import free_port, session  # noqa: E402

from rsal.record import Recorder, RecordOptions  # noqa: E402


def scan(rng: np.random.Generator, t: float) -> bytes:
    ranges = rng.uniform(0.02, 5.6, 682).astype(np.float32).tobytes()
    msg = {"t": float(t), "ranges": ranges, "angle_min": -2.09, "angle_step": 0.00614}
    return ormsgpack.packb({**msg, "range_min": 0.02, "range_max": 5.6})


def run(pubs, payloads, rec: Recorder, rate: float | None, seconds: float) -> dict:
    st = rec.stats
    m0, d0 = st.messages, st.dropped
    sent, t0 = 0, time.perf_counter()
    n = len(pubs)
    while True:
        now = time.perf_counter() - t0
        if now >= seconds:
            break
        due = int(now * rate) if rate else sent + n
        while sent < due:
            pubs[sent % n].put(payloads[sent % len(payloads)])
            sent += 1
        if rate:
            time.sleep(0.001)
    pub_s = time.perf_counter() - t0
    deadline = time.perf_counter() + 30
    while st.messages - m0 + st.dropped - d0 < sent and time.perf_counter() < deadline:
        time.sleep(0.01)
    wall = time.perf_counter() - t0
    got = st.messages - m0
    return {"sent": sent, "written": got, "dropped": st.dropped - d0, "pub_s": pub_s, "wall_s": wall}


def write_recording(path: Path, robots: int, hz: float, seconds: float, payload_of) -> int:
    """``robots`` lasers at ``hz`` for ``seconds`` in the rsal layout; returns the scans written."""
    from mcap.writer import CompressionType, Writer

    t0 = time.time_ns()
    n = 0
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=256 * 1024, compression=CompressionType.ZSTD)
        w.start(profile="rsal", library="bench_record")
        w.add_metadata("rsal.recording", {"format_version": "1", "protocol_version": "1"})
        ids = []
        for r in range(robots):
            key = f"rsal/r{r}/laser/0"
            meta = {"device": f"r{r}:laser:0"}
            live = w.register_channel(key, "msgpack", 0, {"kind": "liveliness", **meta})
            w.add_message(live, t0, ormsgpack.packb({"alive": True}), t0)
            ids.append(w.register_channel(f"{key}/data", "msgpack", 0, {"kind": "data", **meta}))
        period = 1e9 / hz
        for k in range(int(seconds * hz)):
            for r in range(robots):
                off = int(k * period + r * period / robots)  # the robots evenly interleaved
                w.add_message(ids[r], t0 + off, payload_of(off / 1e9, r), t0 + off, sequence=n)
                n += 1
        w.finish()
    return n


def bench_play(a, seconds: float, rng) -> bool:
    """``rsal play --rate 1`` of ``robots`` lasers to a subscriber here: lag and drops."""
    base = scan(rng, 0.0)

    def payload(t: float, r: int) -> bytes:  # the scan with its recorded offset as t, and its robot
        m = ormsgpack.unpackb(base)
        m["t"], m["robot"] = t, r
        return ormsgpack.packb(m)

    ep = f"tcp/127.0.0.1:{free_port()}"
    arrivals: list[tuple[float, float]] = []
    lock = threading.Lock()

    def on_scan(smp) -> None:
        now = time.perf_counter()
        t = ormsgpack.unpackb(smp.payload.to_bytes())["t"]
        with lock:
            arrivals.append((now, t))

    with tempfile.TemporaryDirectory() as d, session(listen=ep) as s:
        path = Path(d) / "play.mcap"
        n = write_recording(path, a.robots, a.hz, seconds, payload)
        sub = s.declare_subscriber("rsal/*/laser/0/data", on_scan)
        cmd = [sys.executable, "-m", "rsal.cli", "play", str(path), "--rate", "1", "--connect", ep, "--delay", "2"]
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=seconds + 120, cwd=ROOT)
        time.sleep(0.5)  # the last scans in flight
        sub.undeclare()
    summary = [ln for ln in p.stderr.splitlines() if "behind" in ln]
    got = sorted(arrivals)
    lag = np.array([(w - got[0][0]) - (t - got[0][1]) for w, t in got]) if got else np.zeros(1)
    lag -= min(lag.min(), 0.0)  # the first scan may itself have been late: lags relative to the earliest
    p50, p99, worst = (float(np.percentile(lag, q)) for q in (50, 99, 100))
    print(
        f"bench=play robots={a.robots} hz={a.hz:g} seconds={seconds:g} recorded={n} received={len(got)} "
        f"dropped={n - len(got)} lag_p50_ms={p50 * 1e3:.1f} lag_p99_ms={p99 * 1e3:.1f} lag_max_ms={worst * 1e3:.1f} "
        f"exit={p.returncode}"
    )
    if summary:
        print(f"bench=play player_summary={summary[-1].split('] ', 1)[-1]!r}")
    ok = p.returncode == 0 and len(got) == n and p99 < 0.05
    print(f"bench=play verdict={'PASS' if ok else 'FAIL'} (rate 1: every scan received, p99 lag under 50 ms)")
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument("--hz", type=float, default=10.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--quick", action="store_true", help="3 s runs")
    ap.add_argument("--only", choices=("record", "play"), help="one of the two benchmarks")
    a = ap.parse_args()
    seconds = 3.0 if a.quick else a.seconds
    rng = np.random.default_rng(7)
    ok = True
    if a.only != "play":
        ok = bench_record(a, seconds, rng)
    if a.only != "record":
        ok = bench_play(a, seconds, rng) and ok
    return 0 if ok else 1


def bench_record(a, seconds: float, rng) -> bool:
    payloads = [scan(rng, i * 0.1) for i in range(64)]
    ep = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as d, session(listen=ep) as srec, session(connect=ep) as spub:
        pubs = [spub.declare_publisher(f"rsal/r{i}/laser/0/data") for i in range(a.robots)]
        rec = Recorder(srec, Path(d) / "bench.mcap", RecordOptions(templates=["**"]))
        rec.start()
        time.sleep(1.0)  # warm-up: the sessions connect, subscriptions propagate
        run(pubs, payloads, rec, a.robots * a.hz, 1.0)
        paced = run(pubs, payloads, rec, a.robots * a.hz, seconds)
        flood = run(pubs, payloads, rec, None, min(seconds, 3.0))  # a flood fills the disk fast
        rec.stop()
        size = rec.size
        raw = rec.stats.bytes
    target = a.robots * a.hz
    print(
        f"bench=record run=paced robots={a.robots} hz={a.hz:g} target_msgs_per_s={target:.0f} "
        f"sent={paced['sent']} written={paced['written']} dropped={paced['dropped']} "
        f"written_per_s={paced['written'] / paced['pub_s']:.0f}"
    )
    print(
        f"bench=record run=flood sent={flood['sent']} written={flood['written']} dropped={flood['dropped']} "
        f"written_per_s={flood['written'] / flood['wall_s']:.0f}"
    )
    print(f"bench=record file_mb={size / 1e6:.1f} wire_mb={raw / 1e6:.1f} compression={raw / max(size, 1):.2f}")
    ok = paced["dropped"] == 0 and paced["written"] == paced["sent"]
    print(f"bench=record verdict={'PASS' if ok else 'FAIL'} (paced run: every message written, none dropped)")
    return ok


if __name__ == "__main__":
    sys.exit(main())
