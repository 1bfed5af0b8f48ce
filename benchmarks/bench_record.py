"""Recorder throughput: does ``rsal record`` keep up with 100 robots' lasers at 10 Hz?

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
Output: one parseable line per figure, ``bench=record key=value ...``, and a verdict line.
Usage: ``python benchmarks/bench_record.py [--robots 100] [--hz 10] [--seconds 10] [--quick]``
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import ormsgpack
import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rsal.record import Recorder, RecordOptions  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def session(listen: str | None = None, connect: str | None = None) -> zenoh.Session:
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        c.insert_json5("listen/endpoints", json.dumps([listen]))
    if connect:
        c.insert_json5("connect/endpoints", json.dumps([connect]))
    return zenoh.open(c)


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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument("--hz", type=float, default=10.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--quick", action="store_true", help="3 s runs")
    a = ap.parse_args()
    seconds = 3.0 if a.quick else a.seconds
    rng = np.random.default_rng(7)
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
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
