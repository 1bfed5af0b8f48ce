"""The cost of a neighbourhood broadcast's put against the cell subscriptions its session holds.

A swarm host (``agents.hub.RobotHub.listen_near``) both publishes its robots' positions on
``svc/send_position/<cell>/<sender>`` and subscribes to the cells near them. This measures, in one
run, the CPU and wall time of one put from such a session with ``--senders`` senders each in its own
cell (their keys cycle), for each subscription form the session may hold -- a subscriber per cell
for ``--cells`` cells (the per-cell form) or one subscriber on ``svc/send_position/*/*`` (the
wildcard form, :mod:`agents.cellsub`) -- and each way to put:

- ``put``: ``Session.put`` on the key (what ``Services.publish`` did);
- ``publisher``: a declared publisher per key, kept (``Services.publish`` now, one per sender and cell).

A second session on loopback subscribes to every cell (the other host, the monitor), so every put
also leaves the process. Output: one ``bench=cell_put`` line per (form, way) with ``cpu_us`` (the
publishing thread's CPU per put, load-independent), ``process_cpu_us`` (the whole process's,
Zenoh's and the subscribers' callback threads included, until 0.2 s after the last put, both
sessions) and ``wall_us``. Each form runs on fresh sessions. Usage:
``python benchmarks/bench_cell_put.py --cells 20,400 --senders 500 --count 4000``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cells", default="20,400", help="per-cell subscribers to hold (comma-separated; default 20,400)")
    ap.add_argument("--senders", type=int, default=500, help="senders, each in its own cell (default 500)")
    ap.add_argument("--count", type=int, default=4000, help="puts measured per case (default 4000)")
    ap.add_argument("--warmup", type=int, default=500, help="puts before measuring (default 500)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the payloads' positions")
    args = ap.parse_args()
    try:
        cells = [int(c) for c in args.cells.split(",") if c]
    except ValueError:
        sys.exit(f"bench_cell_put: --cells {args.cells!r} must be comma-separated whole numbers (e.g. 20,400)")

    import random

    from agents.services import SendPosition, encode_message
    from rsal.transport import TransportArgs, open_session

    rnd = random.Random(args.seed)
    side = max(1, int(args.senders**0.5))
    keys = [f"svc/send_position/c{i % side}_{i // side}/swarm{i}" for i in range(args.senders)]
    payloads = [
        encode_message(f"swarm{i}", SendPosition(f"r{i}", rnd.uniform(0, 100), rnd.uniform(0, 100), 0.0), "p0", 1.0)
        for i in range(args.senders)
    ]
    forms = [(f"cells={n}", n) for n in cells] + [("wildcard", 0)]
    for form, n in forms:  # each form on fresh sessions: an undeclared subscriber leaves traces in routing
        ep = f"tcp/127.0.0.1:{_free_port()}"
        host = open_session(TransportArgs(listen=[ep]))
        other = open_session(TransportArgs(connect=[ep]))
        try:
            _measure(host, other, form, n, side, keys, payloads, args)
        finally:
            other.close()
            host.close()


def _measure(host, other, form: str, n: int, side: int, keys: list[str], payloads: list[bytes], args) -> None:
    got = [0]

    def count(_sample) -> None:
        got[0] += 1

    subs = [other.declare_subscriber("svc/send_position/*/*", count)]  # the other host, the monitor
    if n:
        subs += [host.declare_subscriber(f"svc/send_position/c{i % side}_{i // side}/*", count) for i in range(n)]
    else:
        subs.append(host.declare_subscriber("svc/send_position/*/*", count))
    time.sleep(0.5)  # the other session's interest reaches the host
    for way in ("put", "publisher"):
        pubs = {k: host.declare_publisher(k) for k in keys} if way == "publisher" else {}

        def one(i: int, pubs=pubs) -> None:
            k = keys[i % len(keys)]
            if pubs:
                pubs[k].put(payloads[i % len(keys)])
            else:
                host.put(k, payloads[i % len(keys)])

        for i in range(args.warmup):
            one(i)
        c0, p0, t0 = time.thread_time(), time.process_time(), time.perf_counter()
        for i in range(args.count):
            one(i)
        cpu, wall = time.thread_time() - c0, time.perf_counter() - t0
        time.sleep(0.2)  # the receivers' threads finish with what this put
        proc = time.process_time() - p0
        print(
            f"bench=cell_put form={form} way={way} senders={args.senders} count={args.count} "
            f"cpu_us={1e6 * cpu / args.count:.1f} process_cpu_us={1e6 * proc / args.count:.1f} "
            f"wall_us={1e6 * wall / args.count:.1f}",
            flush=True,
        )
        for p in pubs.values():
            p.undeclare()
    for s in subs:
        s.undeclare()


if __name__ == "__main__":
    main()
