"""The whole navigation stack in one process on a simulated world: the bench of the nav drivers.

Per robot, the same chain the ``amcl``, ``wavefront`` and ``vfh``/``nd``/``snd`` drivers make on the
fabric (thesis 3.4.1, appendix A.3), called directly and stepped with the world, so trials are
deterministic for a seed and run as fast as the CPU allows:

1. odometry and the laser scan go into :class:`~mrs_bridge.nav.amcl.Amcl`; the localized pose is the
   last estimate moved on by the odometry since (as the amcl driver publishes it);
2. :class:`~mrs_bridge.nav.executive.Executive` turns the localized pose into the current waypoint,
   moved into the odometry frame by :class:`~mrs_bridge.drivers.navcommon.Handover`;
3. the local planner drives the base with the laser's points.

The parameters are those of ``rsal sim --nav`` (:mod:`mrs_bridge.nav.profile`). Used by the
navigation success tests and ``benchmarks/bench_nav.py``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from rsal.geometry import compose, relative
from rsal.interfaces.ranger import RangerGeometry
from simulator.world import World

from ..drivers.navcommon import Handover
from ..nav import profile
from ..nav.amcl import Amcl, AmclParams
from ..nav.executive import Executive
from ..nav.grid import NavGrid
from ..nav.wavefront import PlanError, Wavefront

__all__ = ["RobotStack", "GoalResult", "make_local", "grid_of", "in_contact"]


def make_local(name: str, geometry=None, params: dict | None = None):
    from ..nav.nd import ND
    from ..nav.snd import SND
    from ..nav.vfh import VFH

    cls = {"vfh": VFH, "nd": ND, "snd": SND}[name]
    p = dict(profile.LOCAL[name])
    p.update(params or {})
    return cls(p, geometry=geometry)


def grid_of(world: World) -> NavGrid:
    g = world.grid
    return NavGrid.from_occupancy(g.occupied, g.resolution, g.origin)


def in_contact(world: World, name: str) -> bool:
    """Whether the robot's body touches any solid shape (wall, box, robot)."""
    shape = world._model(name).shape
    return any(not q.shape.sensor for q in world.space.shape_query(shape))


def _scan(reading):
    """The scan as the ``sim`` driver publishes it (a RangerData with the beam geometry)."""
    from ..drivers.simmsgs import ranger_data

    return ranger_data(reading)


@dataclass
class GoalResult:
    robot: str
    goal: tuple[float, float, float]
    status: str  # done | aborted | invalid | timeout
    reached: bool  # done and the true pose within the global tolerance plus slack
    collided: bool
    time: float  # simulated seconds
    error: float  # m, true final position to goal
    loc_error_max: float  # m, largest localization error on the way
    message: str = ""
    loc_error_mean: float = 0.0  # m, mean localization error over the steps on the way


class RobotStack:
    """AMCL + Wavefront executive + a local planner for one robot of ``world``."""

    def __init__(
        self,
        world: World,
        name: str,
        local: str,
        planner: Wavefront,
        *,
        seed: int = 0,
        amcl: dict | None = None,
        init_sd: tuple[float, float] = (0.1, math.radians(3)),
    ):
        self.world, self.name = world, name
        spec = world.model_spec(name)
        self.laser = next(i for i, r in enumerate(world.rangers(name)) if r.kind == "laser")
        r = world.rangers(name)[self.laser]
        self.beams = RangerGeometry(
            {
                "pose": list(r.pose),
                "sensors": [{"pose": list(s.pose), "fov": s.fov, "samples": s.samples} for s in r.sensors],
            }
        )
        truth = world.get_pose(name)
        p = dict(profile.AMCL)
        p.update(amcl or {})
        self.amcl = Amcl(
            planner.grid,
            AmclParams(
                **p,
                init_pose=tuple(truth),
                init_pose_var=(init_sd[0] ** 2, init_sd[0] ** 2, init_sd[1] ** 2),
                seed=seed,
            ),
        )
        w = profile.WAVEFRONT
        self.exec = Executive(
            planner,
            distance_epsilon=w["distance_epsilon"],
            angle_epsilon=math.radians(w["angle_epsilon"]),
        )
        self.local = make_local(local, geometry=spec.size[:2])
        self.handover = Handover()
        self._est = None
        self.amcl_ms: list[float] = []
        self.local_ms: list[float] = []

    # ------------------------------------------------------------------ per step
    def localized(self):
        if self._est is None:
            return None
        pose, odom_then = self._est
        return compose(pose, relative(odom_then, self.world.odometry(self.name)))

    def sense(self) -> None:
        """Odometry and the latest scan into AMCL."""
        w, n = self.world, self.name
        odom = w.odometry(n)
        self.amcl.odometry(odom)
        reading = w.ranger(n, self.laser)
        if reading is None:
            return
        scan = _scan(reading)
        origins, bearings = self.beams.beams(scan)
        t0 = time.perf_counter()
        if self.amcl.sensor(scan.ranges, bearings, origins, scan.range_min, scan.range_max) or self._est is None:
            mean, _ = self.amcl.estimate()
            self._est = (tuple(float(v) for v in mean), odom)
            self.amcl_ms.append((time.perf_counter() - t0) * 1e3)

    def set_goal(self, goal) -> None:
        """Plan from the localized pose; raises :class:`PlanError` for an invalid goal."""
        self.handover.reset()
        self.exec.set_goal(self.localized(), goal, self.world.time)

    def control(self, dt: float) -> str:
        """One control cycle; returns the executive's status."""
        w, n = self.world, self.name
        loc = self.localized()
        odom = w.odometry(n)
        status = self.exec.status
        if loc is not None and status == "driving":
            target, status = self.exec.update(loc, w.time)
            if status == "driving" and target is not None:
                t_odom = self.handover.due(loc, odom, tuple(float(v) for v in target), w.time)
                if t_odom is not None:
                    self.local.set_goal(t_odom)
            elif status in ("done", "aborted"):
                self.local.stop()
        reading = w.ranger(n, self.laser)
        pts = self.beams.points(_scan(reading)) if reading is not None else np.zeros((0, 2))
        t0 = time.perf_counter()
        v, om = self.local.step(odom, w.velocity(n), pts, dt)
        self.local_ms.append((time.perf_counter() - t0) * 1e3)
        w.set_velocity(n, v, om)
        return status

    def loc_error(self) -> float:
        loc = self.localized()
        if loc is None:
            return math.inf
        t = self.world.get_pose(self.name)
        return math.hypot(loc[0] - t[0], loc[1] - t[1])


def run_goal(
    stack: RobotStack,
    goal,
    *,
    timeout: float = 120.0,
    others=None,
    slack: float = 0.15,
) -> GoalResult:
    """Drive ``stack``'s robot to ``goal`` (map frame); ``others(world)`` moves the other robots
    before each step. Stops at done/aborted/timeout or at the first collision."""
    w = stack.world
    dt = w.spec.interval_sim
    if w.ranger(stack.name, stack.laser) is None:
        w.step()  # the first scan
    stack.sense()
    t0 = w.time
    try:
        stack.set_goal(goal)
    except PlanError as e:
        return GoalResult(stack.name, tuple(goal), "invalid", False, False, 0.0, math.inf, 0.0, str(e))
    status = "driving"
    collided = False
    loc_max = 0.0
    loc_sum, loc_n = 0.0, 0
    while w.time - t0 < timeout:
        status = stack.control(dt)
        if status in ("done", "aborted"):
            break
        if others is not None:
            others(w)
        w.step()
        stack.sense()
        e = stack.loc_error()
        loc_max = max(loc_max, e)
        loc_sum, loc_n = loc_sum + e, loc_n + 1
        if in_contact(w, stack.name):
            collided = True
            break
    w.set_velocity(stack.name, 0.0, 0.0)
    t = w.get_pose(stack.name)
    err = math.hypot(t[0] - goal[0], t[1] - goal[1])
    if status == "driving":
        status = "timeout"
    eps = profile.WAVEFRONT["distance_epsilon"]
    msg = str(stack.exec.error) if stack.exec.error else ""
    return GoalResult(
        stack.name,
        tuple(goal),
        status,
        status == "done" and err <= eps + slack and not collided,
        collided,
        w.time - t0,
        err,
        loc_max,
        msg,
        loc_sum / loc_n if loc_n else 0.0,
    )


# ----------------------------------------------------------------------------------------------- trials
class Movers:
    """Other robots as moving obstacles: each drives with a VFH local planner on ground truth to random
    free goals in a radius around its start, a new goal whenever it arrives or gets stuck."""

    def __init__(self, world: World, names, planner: Wavefront, rng: np.random.Generator, radius: float = 4.0):
        self.world, self.names, self.rng, self.radius = world, list(names), rng, radius
        self.allowed = planner
        self.locals = {
            n: make_local("vfh", geometry=world.model_spec(n).size[:2], params={"max_speed": 0.3}) for n in names
        }
        self.home = {n: world.get_pose(n) for n in names}
        self.laser = {n: next(i for i, r in enumerate(world.rangers(n)) if r.kind == "laser") for n in names}
        self.beams = {}
        for n in names:
            r = world.rangers(n)[self.laser[n]]
            self.beams[n] = RangerGeometry(
                {
                    "pose": list(r.pose),
                    "sensors": [{"pose": list(s.pose), "fov": s.fov, "samples": s.samples} for s in r.sensors],
                }
            )
        self.since = {n: 0.0 for n in names}

    def _new_goal(self, n: str) -> None:
        hx, hy, _ = self.home[n]
        g = self.allowed
        for _ in range(200):
            x = hx + self.rng.uniform(-self.radius, self.radius)
            y = hy + self.rng.uniform(-self.radius, self.radius)
            if g.grid.clearance(x, y) >= 0.5:
                self.locals[n].set_goal((x, y, float(self.rng.uniform(-math.pi, math.pi))))
                self.since[n] = 0.0
                return
        self.locals[n].stop()

    def __call__(self, world: World) -> None:
        dt = world.spec.interval_sim
        for n in self.names:
            lp = self.locals[n]
            self.since[n] += dt
            if lp.goal is None or lp.status in ("done", "idle") or self.since[n] > 30.0:
                self._new_goal(n)
            reading = world.ranger(n, self.laser[n])
            pts = self.beams[n].points(_scan(reading)) if reading is not None else np.zeros((0, 2))
            v, om = lp.step(world.get_pose(n), world.velocity(n), pts, dt)
            world.set_velocity(n, v, om)


def free_pose(grid_clear, rng: np.random.Generator, extent, clearance: float):
    x0, x1, y0, y1 = extent
    for _ in range(100000):
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if grid_clear(x, y) >= clearance:
            return (float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
    raise RuntimeError("no free pose found")


def goal_trials(
    world_file: str,
    local: str,
    n: int,
    *,
    seed: int = 0,
    min_dist: float = 4.0,
    max_dist: float = 12.0,
    timeout: float = 150.0,
    movers: int = 2,
    progress=None,
    amcl: dict | None = None,
) -> list[GoalResult]:
    """``n`` random reachable start/goal pairs on ``world_file``'s map for robot ``r0`` with
    ``local`` behind Wavefront and AMCL, ``movers`` other robots moving near the route; ``amcl``
    overrides the navigation profile's filter parameters."""
    from simulator.loader import load_world

    spec = load_world(world_file, seed=seed)
    world = World(spec)
    others = [r for r in world.robot_names if r != "r0"][:movers]
    for extra in world.robot_names:
        if extra != "r0" and extra not in others:
            world.remove_model(extra)
    grid = grid_of(world)
    radius = 0.5 * math.hypot(*world.model_spec("r0").size[:2])
    base = Wavefront(grid, robot_radius=radius, safety_dist=profile.WAVEFRONT["safety_dist"])
    rng = np.random.default_rng(seed)
    results: list[GoalResult] = []
    clear = grid.clearance
    ext = grid.extent
    for k in range(n):
        # a reachable pair at a distance in [min_dist, max_dist]
        while True:
            s = free_pose(clear, rng, ext, 0.6)
            g = free_pose(clear, rng, ext, 0.6)
            d = math.hypot(g[0] - s[0], g[1] - s[1])
            if not min_dist <= d <= max_dist:
                continue
            try:
                base.plan(s, g)
            except PlanError:
                continue
            break
        world.set_pose("r0", *s)
        world.set_velocity("r0", 0.0, 0.0)
        # the movers start around the middle of the route, where they get in the way
        mid = ((s[0] + g[0]) / 2, (s[1] + g[1]) / 2)
        for o in others:
            for _ in range(1000):
                p = (
                    mid[0] + rng.uniform(-2.5, 2.5),
                    mid[1] + rng.uniform(-2.5, 2.5),
                    float(rng.uniform(-math.pi, math.pi)),
                )
                if (
                    clear(p[0], p[1]) >= 0.6
                    and math.hypot(p[0] - s[0], p[1] - s[1]) > 1.5
                    and math.hypot(p[0] - g[0], p[1] - g[1]) > 1.5
                ):
                    world.set_pose(o, *p)
                    break
            else:
                world.set_pose(o, *free_pose(clear, rng, ext, 0.6))
        world.step()
        stack = RobotStack(world, "r0", local, base.clone(), seed=seed * 1000 + k, amcl=amcl)
        mv = Movers(world, others, base, rng) if others else None
        r = run_goal(stack, g, timeout=timeout, others=mv)
        results.append(r)
        if progress is not None:
            progress(k, r)
    return results
