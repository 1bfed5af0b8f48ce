"""A watcher for multi-host tests: prints, as JSON lines on stdout, every device that joins or leaves
the fabric (``{"t": s, "join": "r1:planner:0"}``) and, every ``--every`` seconds, the latest
position2d poses it receives (``{"t": s, "poses": {"r1:position2d:2": [x, y, yaw]}}``) and, with
``--truth r1,r2``, those robots' true poses from the simulation (``{"t": s, "truth": {"r1": [x, y, yaw]}}``).

    python tests/fabric/netwatch.py --connect tcp/10.77.0.1:7447 --template '*:*:*'
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

from rsal.client import Fabric
from rsal.keys import parse_key
from rsal.msgs import Position2dData, decode
from rsal.transport import TransportArgs, add_transport_args


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--template", default="*:*:*")
    ap.add_argument("--every", type=float, default=0.5)
    ap.add_argument("--truth", type=lambda t: [n for n in t.split(",") if n], default=[])
    add_transport_args(ap)
    args = ap.parse_args()
    lock = threading.Lock()
    t0 = time.monotonic()

    def say(**kw) -> None:
        with lock:
            print(json.dumps({"t": round(time.monotonic() - t0, 3), **kw}), flush=True)

    poses: dict[str, list[float]] = {}

    def on_pose(sample) -> None:
        parsed = parse_key(str(sample.key_expr))
        if parsed is None:
            return
        try:
            m = decode(Position2dData, sample.payload.to_bytes())
        except Exception:
            return
        with lock:
            poses[str(parsed[0])] = [round(v, 3) for v in m.pose]

    with Fabric.connect(TransportArgs.from_namespace(args)) as fab:
        node = fab.node(args.template)
        node.on_join(lambda a: say(join=str(a)))
        node.on_leave(lambda a: say(leave=str(a)))
        sub = fab.session.declare_subscriber("rsal/*/position2d/*/data", on_pose)
        say(ready=True)
        try:
            while True:
                time.sleep(args.every)
                with lock:
                    snap = dict(poses)
                say(poses=snap)
                if args.truth and node.is_alive("sim:simulation:0"):
                    truth = {}
                    for name in args.truth:
                        try:
                            truth[name] = [
                                round(v, 4) for v in fab.device("sim:simulation:0").get_pose(name).as_tuple()
                            ]
                        except Exception:  # a slow answer: this round goes without it
                            pass
                    say(truth=truth)
        except KeyboardInterrupt:
            pass
        finally:
            sub.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(main())
