"""Sonar localization in a dense crowd, offline: AMCL on each robot's 16 sonars, judged on the truth.

The thesis's swarm (4.2.3) starts 100 Pioneer 3-AT 1.2 m apart; at that density most sonar echoes
are other robots, which the map does not hold. This benchmark rebuilds that crowd at a cost one
core affords: the thesis world (:func:`agents.scenarios.swarm.crowd_world`, 100 Pioneer 3-AT in the
hall) with a ``--rows`` x ``--cols`` block of it at the corner (r0.., nearest the hall's walls)
wandering for ``--seconds`` simulated seconds in one process, the other robots standing (the
simulator's ``wander`` controller, not the agents' behaviour: the figure is the localizer's, not
the crowd's). Each wandering robot has its own :class:`mrs_bridge.nav.amcl.Amcl` configured as
``rsal sim --nav`` configures it for a sonar ring, fed every odometry pose and every sonar scan as
the ``amcl`` driver is.

Three filters per robot are run on the same scans in the same run:

- ``known=off``: the filter as it was (the map only);
- ``known=on``: every ``--broadcast`` s each robot learns its neighbours' *estimated* positions (what
  their agents broadcast; never the truth; a standing robot's is where it stands) within
  ``--radius`` m, declared to its filter as known obstacles (:meth:`Amcl.set_obstacles`, discs of
  ``--disc`` m); the readings they explain are left out (:mod:`mrs_bridge.nav.knownobstacles`);
- ``known=landmark``: the same declarations (from this variant's own estimates), the readings they
  explain scored against the neighbours' bodies (:mod:`mrs_bridge.nav.landmarks`,
  ``known_obstacle_sigma`` = ``--landmark-sigma``).

Figures per variant: the share of robot-samples (every 0.5 s) within 0.5 m of the true pose (overall,
``inner``: samples of robots with no wall within 5 m, the sonar's range, and ``outer``), the
95th percentile and the worst error, and the share of readings the known obstacles left out.
Output: ``bench=crowdloc key=value ...`` lines.
Also per variant: the particle count the KLD bound reaches (mean and 95th percentile after each
update) and the CPU milliseconds per sensor update. Usage:
``python benchmarks/bench_crowdloc.py [--rows 5] [--cols 6] [--seconds 40] [--seed 0] [--pf-max-samples N]``
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from agents.scenarios.swarm.world import crowd_world  # noqa: E402
from mrs_bridge.drivers.simmsgs import ranger_geometry  # noqa: E402
from mrs_bridge.nav import profile  # noqa: E402
from mrs_bridge.nav.amcl import Amcl  # noqa: E402
from mrs_bridge.nav.amclparams import AmclParams  # noqa: E402
from mrs_bridge.nav.conebeam import ConeMap  # noqa: E402
from mrs_bridge.rigs.stacksim import _scan, grid_of  # noqa: E402
from rsal.geometry import compose, relative  # noqa: E402
from rsal.interfaces.ranger import RangerGeometry  # noqa: E402
from simulator.controllers import wander  # noqa: E402
from simulator.loader import load_world  # noqa: E402
from simulator.world import World  # noqa: E402

SAMPLE_EVERY = 0.5  # s, as the thesis swarm's monitor samples
BOUND = 0.5  # m, the thesis swarm's verdict
INNER = 5.0  # m: a robot with no wall this near (the sonar's range) is an inner one
VARIANTS = ("off", "on", "landmark")


def run(
    rows: int,
    cols: int,
    seconds: float,
    seed: int,
    broadcast: float,
    radius: float,
    disc: float,
    speed: float,
    max_samples: int | None = None,
    landmark_sigma: float = 0.3,
) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "crowd.world"
        path.write_text(crowd_world(100, model="pioneer3at", bitmap=str(ROOT / "maps" / "hall.png"), seed=seed))
        world = World(load_world(str(path), seed=seed))
    grid = grid_of(world)
    names = [f"r{r * 10 + c}" for r in range(rows) for c in range(cols)]
    standing = [n for n in world.robot_names if n not in names]
    still = {n: tuple(world.get_pose(n)) for n in standing}
    prm = {**profile.AMCL, **profile.AMCL_SONAR}
    if max_samples is not None:
        prm["pf_max_samples"] = max_samples
    variants = VARIANTS
    filters = {v: {} for v in variants}
    cones = ConeMap(~grid.free, grid.resolution, grid.origin)  # clear: m to the nearest wall
    est = {v: {} for v in variants}  # robot -> (estimate at its last update, odometry then)
    geo = {}
    for r in names:
        t = world.get_pose(r)
        for v in variants:
            extra = {"known_obstacle_sigma": landmark_sigma if v == "landmark" else 0.0}
            p = AmclParams(
                **{**prm, **extra}, init_pose=tuple(t), init_pose_var=(0.05, 0.05, math.radians(5) ** 2), seed=seed
            )
            filters[v][r] = Amcl(grid, p)
            est[v][r] = (tuple(t), None)
        geo[r] = RangerGeometry(ranger_geometry(world.rangers(r)[0]))
    errors = {v: [] for v in variants}
    inner = []  # per sample: no wall within INNER m of the robot's true position
    left_out = {v: [0, 0] for v in variants}
    counts = {v: [] for v in variants}  # particles after each update
    cpu = {v: 0.0 for v in variants}  # s of CPU in the sensor updates
    dt = world.spec.interval_sim
    every_sample = max(1, round(SAMPLE_EVERY / dt))
    every_broadcast = max(1, round(broadcast / dt))
    wall = time.perf_counter()
    for k in range(int(round(seconds / dt))):
        wander(world, speed=speed)
        for n in standing:
            world.set_velocity(n, 0.0, 0.0)
        world.step()
        odo = {r: world.odometry(r) for r in names}

        def pose(v, r, odo=odo):
            e, o0 = est[v][r]
            return e if o0 is None else compose(e, relative(o0, odo[r]))

        if k % every_broadcast == 0:  # the agents' broadcasts: estimated positions, not the truth
            for v in variants[1:]:
                xy = np.array([pose(v, r)[:2] for r in names] + [p[:2] for p in still.values()])
                for i, r in enumerate(names):
                    d = np.hypot(*(xy - xy[i]).T)
                    near = d < radius
                    near[i] = False
                    filters[v][r].set_obstacles(np.column_stack([xy[near], np.full(near.sum(), disc)]))
        for r in names:
            rd = world.ranger(r, 0)
            sc = _scan(rd) if rd is not None else None
            for v in variants:
                a = filters[v][r]
                a.odometry(odo[r])
                if sc is None:
                    continue
                origins, bearings = geo[r].beams(sc)
                c0 = time.process_time()
                done = a.sensor(
                    sc.ranges, bearings, origins, sc.range_min, sc.range_max, beam_width=geo[r].beam_width(sc)
                )
                cpu[v] += time.process_time() - c0
                if done:
                    counts[v].append(a.particles.shape[0])
                    m, _ = a.estimate()
                    est[v][r] = (tuple(float(x) for x in m), odo[r])
                    left_out[v][0] += a.n_explained
                    left_out[v][1] += len(sc.ranges)
        if k % every_sample == 0:
            for r in names:
                tr = world.get_pose(r)
                ix = int((tr[0] - grid.origin[0]) / grid.resolution)
                iy = int((tr[1] - grid.origin[1]) / grid.resolution)
                inner.append(float(cones.clear[iy, ix]) > INNER)
                for v in variants:
                    e = pose(v, r)
                    errors[v].append(math.dist(e[:2], tr[:2]))
    out = {"wall_s": time.perf_counter() - wall}
    inner = np.array(inner)
    for v in variants:
        e = np.array(errors[v])
        out[v] = {
            "within": float(np.mean(e <= BOUND)),
            "within_inner": float(np.mean(e[inner] <= BOUND)) if inner.any() else float("nan"),
            "within_outer": float(np.mean(e[~inner] <= BOUND)) if (~inner).any() else float("nan"),
            "inner_share": float(np.mean(inner)),
            "p95": float(np.percentile(e, 95)),
            "worst": float(e.max()),
            "explained": left_out[v][0] / max(1, left_out[v][1]),
            "particles": float(np.mean(counts[v])) if counts[v] else 0.0,
            "particles_p95": float(np.percentile(counts[v], 95)) if counts[v] else 0.0,
            "updates_per_robot_s": len(counts[v]) / (len(names) * seconds),
            "cpu_ms_per_update": 1e3 * cpu[v] / max(1, len(counts[v])),
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=5, help="rows of the thesis crowd that wander (default 5)")
    ap.add_argument("--cols", type=int, default=6, help="columns of the thesis crowd that wander (default 6)")
    ap.add_argument("--seconds", type=float, default=40.0, help="simulated seconds (default 40)")
    ap.add_argument("--seed", type=int, default=0, help="headings and filter seeds (default 0)")
    ap.add_argument("--broadcast", type=float, default=0.5, help="s between position broadcasts (default 0.5)")
    ap.add_argument("--radius", type=float, default=5.0, help="m: neighbours declared (default 5)")
    ap.add_argument("--disc", type=float, default=0.55, help="m: a neighbour's disc radius (default 0.55)")
    ap.add_argument("--speed", type=float, default=0.4, help="m/s the robots wander at (default 0.4)")
    ap.add_argument(
        "--pf-max-samples", type=int, default=None, help="the filters' pf_max_samples (default: the sonar profile's)"
    )
    ap.add_argument(
        "--landmark-sigma", type=float, default=0.3, help="m: known=landmark's known_obstacle_sigma (default 0.3)"
    )
    a = ap.parse_args()
    if not (1 <= a.rows <= 10 and 1 <= a.cols <= 10):
        ap.error(f"--rows {a.rows} and --cols {a.cols} must be 1..10 (the thesis crowd is 10 x 10)")
    if a.landmark_sigma <= 0:
        ap.error(f"--landmark-sigma {a.landmark_sigma} must be > 0 (m)")
    r = run(
        a.rows, a.cols, a.seconds, a.seed, a.broadcast, a.radius, a.disc, a.speed, a.pf_max_samples, a.landmark_sigma
    )
    nmax = a.pf_max_samples or {**profile.AMCL, **profile.AMCL_SONAR}["pf_max_samples"]
    for v in VARIANTS:
        f = r[v]
        print(
            f"bench=crowdloc robots={a.rows * a.cols} seconds={a.seconds:g} seed={a.seed} known={v} "
            f"within_0.5m={f['within']:.3f} inner={f['within_inner']:.3f} outer={f['within_outer']:.3f} "
            f"inner_share={f['inner_share']:.2f} p95_m={f['p95']:.2f} worst_m={f['worst']:.2f} "
            f"explained={f['explained']:.3f} pf_max_samples={nmax} particles_mean={f['particles']:.0f} "
            f"particles_p95={f['particles_p95']:.0f} updates_per_robot_s={f['updates_per_robot_s']:.2f} "
            f"cpu_ms_per_update={f['cpu_ms_per_update']:.2f} wall_s={r['wall_s']:.0f}"
        )


if __name__ == "__main__":
    main()
