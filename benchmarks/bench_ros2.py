"""Exporter throughput: does ``rsal ros2`` keep up with 100 robots' lasers at 10 Hz on one core?

This process plays the fleet on one Zenoh session (listening on a loopback port): for each of
``--robots`` robots the liveliness tokens of ``laser:0`` and ``position2d:0``, a ``describe``
answer, and at ``--hz`` a URG-04LX scan (682 float32 ranges, RangerData) and an odometry sample
(Position2dData). ``rsal ros2`` runs as a process of its own, connected to that port. A second
session here (the observer) subscribes to both streams: the RSAL scans (``rsal/*/laser/0/data``)
and the ROS scans (``0/*/scan/...``), and pairs them by robot and stamp.

Figures, after a warm-up (every robot exported, then ``--warmup`` s): the exporter's CPU share
(user + system time of its process over the window, ``/proc/<pid>/stat``, in % of one core), the
ROS scans delivered against the RSAL scans seen in the same window, and the latency the exporter
adds: ROS arrival minus RSAL arrival of the same scan at the observer (p50, p95, max). The fleet
and the observer share one interpreter, so the latency is pessimistic. Fixed seed; times by
``time.perf_counter()``. Output: one parseable line per figure, ``bench=ros2 key=value ...``, and
a verdict line (CPU under 100 % of a core and at least 95 % of the scans delivered).
Usage: ``python benchmarks/bench_ros2.py [--robots 100] [--hz 10] [--seconds 10] [--warmup 2]``
"""

from __future__ import annotations

import argparse
import os
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from loopback import free_port, session  # noqa: E402

from rsal.interfaces.position2d import Position2dData  # noqa: E402
from rsal.interfaces.ranger import RangerData  # noqa: E402
from rsal.msgs import Describe, ok_reply  # noqa: E402


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


LASER_GEOM = {
    "kind": "laser",
    "pose": [0.13, 0.0, 0.0],
    "sensors": [{"pose": [0, 0, 0], "fov": 4.18879, "samples": 682, "range_min": 0.02, "range_max": 5.6}],
}


def describe_answer(query) -> None:
    _, node, iface, idx = str(query.key_expr).split("/")[:4]
    geom = LASER_GEOM if iface == "laser" else {"max_speed": [0.5, 1.0], "frame": "odom"}
    d = Describe(node, iface, int(idx), "bench", 10.0, geom)
    query.reply(query.key_expr, ok_reply(**d.to_dict()))


def ros_stamp(payload: bytes) -> float:
    sec, nsec = struct.unpack_from("<iI", payload, 4)
    return round(sec + nsec * 1e-9, 6)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument("--hz", type=float, default=10.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=2.0)
    a = ap.parse_args()
    rng = np.random.default_rng(7)
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    names = [f"r{i}" for i in range(a.robots)]
    lock = threading.Lock()
    rsal_seen: dict[tuple[str, float], float] = {}
    ros_seen: dict[tuple[str, float], float] = {}
    recording = threading.Event()

    def on_rsal(s) -> None:
        if recording.is_set():
            m = RangerData.from_bytes(s.payload.to_bytes())
            with lock:
                rsal_seen[(str(s.key_expr).split("/")[1], round(m.t, 6))] = time.perf_counter()

    def on_ros(s) -> None:
        if recording.is_set():
            with lock:
                ros_seen[(str(s.key_expr).split("/")[1], ros_stamp(s.payload.to_bytes()))] = time.perf_counter()

    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with session(listen=ep) as fleet:
        tokens = [fleet.liveliness().declare_token(f"rsal/{n}/{i}/0") for n in names for i in ("laser", "position2d")]
        q = fleet.declare_queryable("rsal/*/*/0/rpc/describe", describe_answer)
        scan_pubs = [fleet.declare_publisher(f"rsal/{n}/laser/0/data") for n in names]
        odom_pubs = [fleet.declare_publisher(f"rsal/{n}/position2d/0/data") for n in names]
        exp = subprocess.Popen(
            [sys.executable, "-m", "rsal.cli", "ros2", "--connect", ep],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
            start_new_session=True,
        )
        try:
            want = f"{a.robots} robot(s) exported"
            deadline = time.monotonic() + 120
            for line in exp.stdout:  # the progress lines, until every robot is exported
                if want in line or time.monotonic() > deadline:
                    break
            threading.Thread(target=lambda: [None for _ in exp.stdout], daemon=True).start()
            with (
                session(connect=ep) as obs,
                obs.declare_subscriber("rsal/*/laser/0/data", on_rsal),
                obs.declare_subscriber("0/*/scan/**", on_ros),
            ):
                ranges = [rng.uniform(0.02, 5.6, 682).astype(np.float32) for _ in range(16)]
                period = 1.0 / a.hz
                t0 = time.perf_counter()
                k, cpu0, w0 = 0, None, None
                while True:
                    now = time.perf_counter() - t0
                    if now >= a.warmup + a.seconds:
                        break
                    if cpu0 is None and now >= a.warmup:
                        cpu0, w0 = cpu_seconds(exp.pid), time.perf_counter()
                        recording.set()
                    t = round(k * period, 6)
                    for i in range(a.robots):
                        scan_pubs[i].put(RangerData(t, ranges[(k + i) % 16], -2.0944, 0.006151, 0.02, 5.6).to_msgpack())
                        odom_pubs[i].put(Position2dData(t, (0.1 * i, 0.0, 0.0), (0.2, 0.0, 0.1)).to_msgpack())
                    k += 1
                    sleep = t0 + k * period - time.perf_counter()
                    if sleep > 0:
                        time.sleep(sleep)
                recording.clear()
                cpu = (cpu_seconds(exp.pid) - cpu0) / (time.perf_counter() - w0)
                time.sleep(0.5)  # the last scans in flight
        finally:
            exp.terminate()
            exp.wait(10)
            q.undeclare()
            for tk in tokens:
                tk.undeclare()
    with lock:
        lat = np.array([ros_seen[k] - t for k, t in rsal_seen.items() if k in ros_seen]) * 1e3
        n_rsal, n_ros = len(rsal_seen), sum(1 for k in rsal_seen if k in ros_seen)
    delivered = n_ros / max(n_rsal, 1)
    print(f"bench=ros2 robots={a.robots} hz={a.hz:g} seconds={a.seconds:g} exporter_cpu_pct={100 * cpu:.1f}")
    print(f"bench=ros2 rsal_scans={n_rsal} ros_scans={n_ros} delivered_pct={100 * delivered:.1f}")
    if lat.size:
        print(
            f"bench=ros2 added_latency_ms_p50={np.percentile(lat, 50):.2f} "
            f"p95={np.percentile(lat, 95):.2f} max={lat.max():.2f}"
        )
    ok = cpu < 1.0 and delivered >= 0.95
    print(f"bench=ros2 verdict={'PASS' if ok else 'FAIL'} (exporter under one core, >= 95 % of scans delivered)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
