"""The thesis swarm's robot cycle for N robots of one host: per robot vs the thesis batch step.

:class:`agents.scenarios.swarm.thesis.ThesisPioneer` robots (a Pioneer 3-AT's 16-sonar ring, the
body-aware checks of :func:`~agents.scenarios.swarm.thesis.params_for_size`, a localize pose, the
neighbours' broadcast positions on a hub's board) standing 1 m apart in a square block, on real
device proxies over an in-memory fabric (:class:`rsal.testing.FakeFabric`: no network, a command
is recorded instead of put), fed random scans, odometry and localize poses each cycle. The
baseline, in the same run on the same data: every robot's own ``update()``; then
:class:`agents.scenarios.swarm.thesisstep.ThesisStep`, one step for all. Figures: CPU microseconds
per robot cycle (``time.thread_time``), so a machine loaded by other work changes them little; the
network's own cost per command (a Zenoh put) is not in them.

Output: ``bench=thesis_step key=value`` lines. Usage:
``python benchmarks/bench_thesis_step.py --robots 10,100 --cycles 50``
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

RING = [90, 50, 30, 10, -10, -30, -50, -90, -90, -130, -150, -170, 170, 150, 130, 90]  # degrees
GEOMETRY = {
    "kind": "sonar",
    "pose": [0.0, 0.0, 0.0],
    "sensors": [
        {"pose": [0.2 * math.cos(math.radians(a)), 0.15 * math.sin(math.radians(a)), math.radians(a)]} for a in RING
    ],
}


def hub_board(xy: np.ndarray, names: list[str]):
    """A hub's board of received broadcasts (what near() and received_positions() read), no network."""
    from agents.hub import RobotHub

    hub = RobotHub.__new__(RobotHub)
    hub.board_timeout = 5.0
    hub._index, hub._xy, hub._stamp = {}, np.zeros((0, 2)), np.zeros(0)
    for name, (x, y) in zip(names, xy.tolist(), strict=True):
        hub._remember(name, x, y)
    return hub


def crowd(fab, names: list[str], hub):
    from agents.scenarios.swarm.thesis import ThesisPioneer, params_for_size
    from rsal.devices import Position2d, Sonar

    robots = []
    for i, name in enumerate(names):
        pos = fab.device(Position2d, f"{name}:position2d:0", {"max_speed": [0.5, 1.0]})
        sonar = fab.device(Sonar, f"{name}:sonar:0", GEOMETRY)
        r = ThesisPioneer([pos, sonar], name=name, period=0.1, laser=False)
        r.set_wallfollow(True, side="left" if i % 2 else "right")
        r.behaviour.p = params_for_size(0.626, 0.505, r.behaviour.p)
        r.localize = fab.device(Position2d, f"{name}:position2d:2")
        r.localize.rpc_async = lambda op, **a: None
        r.neighbours = lambda x, y, rr, _n=name: hub.near(x, y, rr, exclude=_n)
        robots.append(r)
    return robots


def run(n: int, cycles: int, warmup: int, seed: int) -> dict:
    from agents.scenarios.swarm.thesis import ThesisPioneer
    from agents.scenarios.swarm.thesisstep import ThesisStep
    from rsal.clock import clock
    from rsal.msgs import Position2dData, RangerData
    from rsal.testing import FakeFabric

    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(n))
    names = [f"r{i}" for i in range(n)]
    pose = np.column_stack([np.arange(n) // side * 1.0, np.arange(n) % side * 1.0, rng.uniform(-3, 3, n)])
    hub = hub_board(pose[:, :2], names)
    fab = FakeFabric()
    robots = crowd(fab, names, hub)
    step = ThesisStep(hub, lambda: clock().now(), ThesisPioneer)
    cpu = {"per_robot": 0.0, "vector": 0.0}
    for c in range(warmup + cycles):
        pose[:, :2] += rng.uniform(-0.01, 0.01, (n, 2))
        ranges = rng.uniform(0.3, 5.0, (n, len(RING)))
        for i, r in enumerate(robots):  # the network's samples: not timed
            fab.push(r.position2d, Position2dData(0.0, tuple(pose[i]), (0.0, 0.0, 0.0), False))
            fab.push(r.sonars[0], RangerData(0.0, ranges[i], 0.0, 0.0, 0.1, 5.0))
            fab.push(r.localize, Position2dData(0.0, tuple(pose[i]), (0.0, 0.0, 0.0), False))
        for form in ("per_robot", "vector"):
            t0 = time.thread_time()
            if form == "per_robot" or c == 0:  # the first cycle learns the beam geometry
                for r in robots:
                    r.update()
            else:
                rest = step(robots)
                assert not rest, f"{len(rest)} robots left to their own cycle"
            if c >= warmup:
                cpu[form] += time.thread_time() - t0
    per = {k: 1e6 * v / (n * cycles) for k, v in cpu.items()}
    return {
        "robots": n,
        "per_robot_us": round(per["per_robot"], 1),
        "vector_us": round(per["vector"], 1),
        "ratio": round(per["per_robot"] / per["vector"], 2),
        "cores_10hz_per_robot": round(per["per_robot"] * n * 10 / 1e6, 4),
        "cores_10hz_vector": round(per["vector"] * n * 10 / 1e6, 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="10,100", help="comma-separated crowd sizes")
    ap.add_argument("--cycles", type=int, default=50)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    for n in (int(x) for x in a.robots.split(",")):
        r = run(n, a.cycles, a.warmup, a.seed)
        print("bench=thesis_step " + " ".join(f"{k}={v}" for k, v in r.items()), flush=True)


if __name__ == "__main__":
    main()
