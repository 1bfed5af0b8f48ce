"""Find and Collect with energy: the dispatcher's charging on (``energy``) and off (``energy_baseline``).

Runs both applications of ``deploy/scenarios/find_collect.yaml`` with ``rsal run`` (real processes:
the simulator with the navigation stack, the dispatcher, the master, the explorer and two
collectors with small batteries in ``maps/collect_energy.world``), ``--runs`` times each, one after
the other, and samples the simulation's battery record (rpc ``batteries``, ground truth) every
0.3 s while a run lasts. The baseline is the same run in the same invocation with the dispatcher's
``charging: false``.

Figures, one line per run (``bench=collect_energy key=value``): the run's result (``ok``), blobs
delivered, simulated and wall seconds, and per collector its lowest charge, seconds flat and joules
charged on a dock (the simulation's record); with charging off, the simulated time at which the
first collector ran flat.

Usage: ``python benchmarks/bench_collect_energy.py --runs 1``.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rsal.client import Fabric  # noqa: E402
from rsal.msgs import RpcError  # noqa: E402
from rsal.transport import TransportArgs  # noqa: E402

SCENARIO = ROOT / "deploy" / "scenarios" / "find_collect.yaml"
COLLECTORS = ("c1", "c2")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_once(app: str, timeout: float) -> dict:
    """One ``rsal run --app APP``; its result and the battery record sampled while it ran."""
    port = _free_port()
    cmd = [sys.executable, "-m", "rsal.cli", "run", str(SCENARIO), "--app", app, "--listen", f"tcp/127.0.0.1:{port}"]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    fab = None
    record: dict = {}
    flat_at = None
    try:
        fab = Fabric.connect(TransportArgs(connect=[f"tcp/127.0.0.1:{port}"]))
        node = fab.node("sim:simulation:0")
        node.wait_for("sim:simulation:0", 1, 120)
        sim = fab.device("sim:simulation:0")
        deadline = time.monotonic() + timeout
        while p.poll() is None and time.monotonic() < deadline:
            try:
                reply = sim.rpc("batteries", timeout=2.0)
            except (RpcError, TimeoutError):
                time.sleep(0.3)
                continue
            record = reply["robots"]
            if flat_at is None and any(record[c]["flat"] > 0 for c in COLLECTORS):
                flat_at = reply["t"]
            time.sleep(0.3)
        out, _ = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
            p.wait(30)
        if fab is not None:
            fab.close()
    wall = time.perf_counter() - t0
    delivered = re.search(r"outcomes: delivered (\d+)", out)
    elapsed = re.search(r"elapsed ([\d.]+) s", out)
    return {
        "ok": int(p.returncode == 0),
        "delivered": int(delivered.group(1)) if delivered else 0,
        "sim_s": float(elapsed.group(1)) if elapsed else float("nan"),
        "wall_s": wall,
        "flat_at_s": flat_at,
        "record": record,
        "result": next((ln for ln in out.splitlines() if "result:" in ln), "").strip(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="runs of each application (default 1)")
    ap.add_argument("--timeout", type=float, default=300.0, help="wall seconds per run (default 300)")
    args = ap.parse_args(argv)
    for i in range(args.runs):
        for app in ("energy", "energy_baseline"):
            r = run_once(app, args.timeout)
            bits = [f"bench=collect_energy app={app} run={i}", f"ok={r['ok']}", f"delivered={r['delivered']}"]
            bits += [f"sim_s={r['sim_s']:.1f}", f"wall_s={r['wall_s']:.1f}"]
            if r["flat_at_s"] is not None:
                bits.append(f"first_flat_at_s={r['flat_at_s']:.1f}")
            for c in COLLECTORS:
                b = r["record"].get(c)
                if b is not None:
                    bits.append(
                        f"{c}_lowest={b['lowest']:.2f} {c}_flat_s={b['flat']:.1f} {c}_charged_J={b['charged']:.0f}"
                    )
            print(" ".join(bits), flush=True)
            print(f"  {r['result']}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
