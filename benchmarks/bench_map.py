"""Map building accuracy and speed: ``rsal map`` on a simulated tour, judged by ground truth.

A tour of ``--world`` (default maps/floor.world: the laboratory, the corridor, two rooms south of
it and back to the start, a loop) is recorded with :func:`rsal.mapping.tour.run_tour` at the
world's ``odom_error`` for ``--minutes`` simulated minutes (fixed ``--seed``); the map is built
with the robot's true start as ``--initial-pose`` (what ``rsal map`` runs:
:func:`rsal.mapping.cli.build_map`), timed with ``time.perf_counter()``. Figures against the
simulator's ground truth (:mod:`rsal.mapping.evaluate`):

- the trajectory's position error (RMS and max) over the scans used, and the raw odometry's on
  the same scans (the baseline of the same run); targets <= 0.05 m RMS, <= 0.15 m max;
- the fraction of the built map's occupied cells within 0.10 m of a wall of the true bitmap
  (target >= 95 %) and of the true walls the robot saw that the map has (target >= 90 %);
- the wall time of the map building (target < 60 s for a 5-minute tour), with its CPU time and the
  machine's load average (the reference machine is shared: wall time alone says little then);
- AMCL (the ``amcl`` driver's filter, :func:`mrs_bridge.nav.offline.localize_scans`) on the *built*
  map over a second tour with other odometry noise (``--seed`` + 1), started at the true pose: its
  position error against the truth after 5 s (target < 0.15 m throughout; ``--no-amcl`` skips it),
  beside the same filter on the world's true bitmap over the same tour (the baseline of the run).

Output: one parseable line per figure, ``bench=map key=value ...``, and a verdict line.
Usage: ``python benchmarks/bench_map.py [--world maps/floor.world] [--minutes 6] [--seed 1] [--quick]``
(``--quick``: the test room for 1.5 minutes).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rsal.mapping.evaluate import trajectory_error, wall_agreement  # noqa: E402
from rsal.mapping.mapyaml import read_map  # noqa: E402
from rsal.mapping.posegraph import between, compose  # noqa: E402
from rsal.mapping.reader import read_scans  # noqa: E402
from rsal.mapping.slam import run_slam  # noqa: E402
from rsal.mapping.tour import run_tour  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--world", default=str(ROOT / "maps" / "floor.world"))
    ap.add_argument("--minutes", type=float, default=6.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="the test room, 1.5 minutes")
    ap.add_argument("--no-amcl", action="store_true", help="skip AMCL on the built map over a second tour")
    a = ap.parse_args()
    if a.quick:
        a.world, a.minutes = str(ROOT / "maps" / "testroom.world"), 1.5
    from simulator.loader import load_world
    from simulator.world import World

    world = World(load_world(a.world, seed=a.seed), seed=a.seed)
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "tour.mcap"
        t0 = time.perf_counter()
        st = run_tour(a.world, str(rec), minutes=a.minutes, seed=a.seed)
        print(
            f"bench=map what=tour world={Path(a.world).name} sim_s={st.sim_seconds:.0f} scans={st.scans} "
            f"distance_m={st.distance:.1f} loops_driven={st.loops} wall_s={time.perf_counter() - t0:.1f}"
        )
        sc = read_scans(rec)
        start = tuple(float(v) for v in sc.truth[0])  # the robot stands at its world-file pose at first
        # what `rsal map RUN -o NAME --initial-pose X Y YAW` runs, timed end to end (read, SLAM, grid, files)
        from rsal.mapping.cli import build_map

        t0, c0 = time.perf_counter(), time.process_time()
        build_map(str(rec), str(Path(tmp) / "built"), initial_pose=start, quiet=True)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        # the trajectory (the same SLAM run again, deterministic, for its poses)
        res = run_slam(sc, start)
        truth = sc.truth[res.used]
        rms, worst = trajectory_error(res.poses, truth)
        T = compose(np.asarray(start), between(sc.odom[0], np.zeros(3)))
        odo = compose(np.broadcast_to(T, sc.odom.shape), sc.odom)[res.used]
        o_rms, o_max = trajectory_error(odo, truth)
        m = read_map(Path(tmp) / "built.yaml")
        g = world.grid
        precision, coverage = wall_agreement(
            m.occupancy[::-1], m.resolution, m.origin, g.occupied, g.resolution, g.origin
        )
        amcl = None
        if not a.no_amcl:
            from mrs_bridge.nav.grid import NavGrid
            from mrs_bridge.nav.offline import localize_scans

            second = Path(tmp) / "second.mcap"
            run_tour(a.world, str(second), minutes=a.minutes, seed=a.seed + 1)
            sc2 = read_scans(second)
            t0 = time.perf_counter()
            loc = localize_scans(NavGrid(m.cells(), m.resolution, m.origin[:2]), sc2, sc2.truth[0])
            err = loc.after(sc2.t, settle_s=5.0)
            amcl = (float(np.mean(err)), float(np.percentile(err, 95)), float(np.max(err)), len(sc2.t))
            amcl_s = time.perf_counter() - t0
            # the baseline of the same run: the same filter on the world's true bitmap
            true_grid = NavGrid.from_occupancy(g.occupied, g.resolution, g.origin)
            base = localize_scans(true_grid, sc2, sc2.truth[0]).after(sc2.t, settle_s=5.0)
            amcl_true = (float(np.mean(base)), float(np.percentile(base, 95)), float(np.max(base)))
    print(
        f"bench=map what=slam scans_used={len(res.used)} keyframes={len(res.keyframes)} "
        f"loop_closures={len(res.loops)} loop_tries={res.loop_tries}"
    )
    print(f"bench=map what=trajectory rms_m={rms:.4f} max_m={worst:.4f} odom_rms_m={o_rms:.3f} odom_max_m={o_max:.3f}")
    print(f"bench=map what=walls occupied_near_true_wall={precision:.4f} true_walls_covered={coverage:.4f}")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    times = f"map_wall_s={wall:.1f} map_cpu_s={cpu:.1f} load_avg={load:.1f}"
    print(f"bench=map what=time {times} tour_minutes={a.minutes:g}")
    ok = rms <= 0.05 and worst <= 0.15 and precision >= 0.95 and coverage >= 0.90 and wall < 60.0
    if amcl is not None:
        print(
            f"bench=map what=amcl_on_built_map scans={amcl[3]} mean_m={amcl[0]:.3f} p95_m={amcl[1]:.3f} "
            f"max_m={amcl[2]:.3f} wall_s={amcl_s:.1f}"
        )
        print(
            f"bench=map what=amcl_on_true_map mean_m={amcl_true[0]:.3f} p95_m={amcl_true[1]:.3f} "
            f"max_m={amcl_true[2]:.3f}"
        )
        ok = ok and amcl[2] < 0.15
    print(
        f"bench=map verdict={'pass' if ok else 'fail'} "
        "targets='rms<=0.05 max<=0.15 near>=0.95 covered>=0.90 wall<60s amcl_max<0.15'"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
