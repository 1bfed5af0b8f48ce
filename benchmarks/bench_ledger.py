"""The neighbourhood swarm's accounting per hub (agents.scenarios.swarm.ledger.NearLedger) against
the per-agent path it replaced, on one agent host's share of the 1000-robot swarm.

``--agents`` agents (default 500: one of two hosts) stand at random on a square of ``--side`` m and
watch the cells within ``--reach`` m (5 m cells, as ``--neighbourhood 5``); each flush logs
``--messages`` broadcasts at random points (2 Hz x 1000 robots x 0.5 s), then:

- ``per_hub``: :meth:`NearLedger.flush` (all agents' pairs at once, one histogram for the hub);
- ``per_agent`` (the baseline, as the ledger did before): messages grouped by cell in Python, each
  agent's message indices concatenated, its keys and latencies handed to it in one call
  (``Received.add_keys`` and ``LatencyHistogram.add_many``).

Both give every agent the same keys and histogram (checked). Prints one line per form with the CPU
milliseconds per flush (``time.process_time``: load-independent on a shared machine) and the
pairs per flush. (Reading an agent's figures, ``swarm_stats``, costs both forms alike.)

    .venv/bin/python benchmarks/bench_ledger.py [--agents 500 --messages 1000 --flushes 20]
"""

from __future__ import annotations

import argparse
import time
from types import SimpleNamespace

import numpy as np

from agents.cells import cell_of, cells_near
from agents.scenarios.swarm import LatencyHistogram, SwarmAgent
from agents.scenarios.swarm.ledger import NearLedger, Received, code, latency_bins
from agents.services import Message, SendPosition

_SEQ_BITS = 24


def _per_agent_flush(hub, log: list[tuple[int, str, float]], got: dict, hist: dict) -> None:
    """The per-agent path (the baseline): one Python pass per message, one call per agent."""
    keys = np.asarray([k for k, _, _ in log], dtype=np.int64)
    lat = np.maximum(np.asarray([t for _, _, t in log]), 0.0)
    bins = latency_bins(lat)
    by_cell: dict[str, list[int]] = {}
    for i, (_, c, _) in enumerate(log):
        by_cell.setdefault(c, []).append(i)
    per_agent: dict[int, tuple[object, list[np.ndarray]]] = {}
    for c, idx in by_cell.items():
        arr = np.asarray(idx)
        for a in hub.agents_in(c):
            e = per_agent.get(id(a))
            if e is None:
                per_agent[id(a)] = (a, [arr])
            else:
                e[1].append(arr)
    senders = keys >> _SEQ_BITS
    for a, parts in per_agent.values():
        idx = parts[0] if len(parts) == 1 else np.concatenate(parts)
        idx = idx[senders[idx] != code(a.id)]
        if len(idx):
            got[a.id].add_keys(keys[idx])
            hist[a.id].add_many(bins[idx], lat[idx])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--agents", type=int, default=500, help="agents of the host (default 500)")
    ap.add_argument("--messages", type=int, default=1000, help="broadcasts per flush (default 1000)")
    ap.add_argument("--side", type=float, default=50.0, help="side of the square they stand on, m (default 50)")
    ap.add_argument("--reach", type=float, default=5.5, help="radius + margin of their cells, m (default 5.5)")
    ap.add_argument("--flushes", type=int, default=20, help="measured flushes per form (default 20)")
    ap.add_argument("--warmup", type=int, default=3, help="flushes before measuring (default 3)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    rng = np.random.default_rng(args.seed)
    agents = [SwarmAgent(f"b{i}", robot=f"b{i}", neighbourhood=5.0) for i in range(args.agents)]
    by_cell: dict[str, list[SwarmAgent]] = {}
    for a, (x, y) in zip(agents, rng.uniform(0, args.side, (args.agents, 2)), strict=True):
        for c in cells_near(x, y, args.reach, 5.0):
            by_cell.setdefault(c, []).append(a)
    hub = SimpleNamespace(cell_size=5.0, agents_in=lambda c: by_cell.get(c, []))
    ledger = NearLedger(hub)
    for a in agents:
        a.join_ledger(ledger)
    got = {a.id: Received() for a in agents}
    hist = {a.id: LatencyHistogram() for a in agents}
    now = time.time()
    cpu = {"per_hub": 0.0, "per_agent": 0.0}
    for f in range(args.warmup + args.flushes):
        xy = rng.uniform(0, args.side, (args.messages, 2))
        lat = rng.exponential(0.02, args.messages)
        log = []
        for i, ((x, y), dt) in enumerate(zip(xy.tolist(), lat.tolist(), strict=True)):
            s = agents[i % args.agents].id
            seq = f * (args.messages // args.agents + 1) + i // args.agents
            ledger.on_message(hub, Message("send_position", s, f"p{seq}", now - dt, SendPosition(s, x, y, 0.0)), now)
            log.append(((code(s) << _SEQ_BITS) | seq, cell_of(x, y, 5.0), now - (now - dt)))
        pairs0 = ledger.pairs
        t0 = time.process_time()
        ledger.flush()
        t1 = time.process_time()
        _per_agent_flush(hub, log, got, hist)
        t2 = time.process_time()
        if f >= args.warmup:
            cpu["per_hub"] += t1 - t0
            cpu["per_agent"] += t2 - t1
    pairs = ledger.pairs - pairs0
    for a in agents:  # the same figures both ways
        assert a.ranges == got[a.id].ranges(), a.id
        assert a.latency.to_dict()["counts"] == hist[a.id].to_dict()["counts"], a.id
    for form, s in cpu.items():
        print(
            f"bench=ledger form={form} agents={args.agents} messages={args.messages} pairs={pairs} "
            f"flush_cpu_ms={1000 * s / args.flushes:.2f} ns_per_pair={1e9 * s / args.flushes / max(pairs, 1):.0f}"
        )


if __name__ == "__main__":
    main()
