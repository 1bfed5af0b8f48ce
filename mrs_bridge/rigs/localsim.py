"""Closed-loop runs of local planners on simulated robots: the bench of :mod:`mrs_bridge.nav.local`.

Drives robots of a :class:`simulator.world.World` with :class:`~mrs_bridge.nav.local.LocalPlanner`
commands the way a planner driver does on the device server (thesis 3.4.1): every simulation step
(``interval_sim``, 100 ms in the project's worlds) each robot's planner gets its pose (ground truth
or odometry), its current velocity and its laser's hits as robot-frame points (max-range readings
removed), and its command goes to the robot's drive. A robot counts as collided when its body
touches any solid shape -- a wall, a box or another robot -- which pymunk reports exactly; the
closest obstacle point each robot saw is recorded too.

Used by the tests, the parameter sweep and the success-rate trials of ``benchmarks/bench_local.py``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from rsal.geometry import compose, invert, wrap
from simulator.world import World

from ..nav.local import LocalPlanner, Status

__all__ = ["Agent", "RunResult", "Trial", "draw_trial", "in_contact", "laser_points", "run", "run_trial"]


def laser_points(world: World, name: str, ranger: int | None = None) -> np.ndarray:
    """Robot-frame obstacle points of a robot's laser (its first multi-sample ranger, or
    ``ranger``); readings at or beyond the maximum range are dropped."""
    specs = world.rangers(name)
    if ranger is None:
        ranger = next((i for i, r in enumerate(specs) if r.kind == "laser"), 0)
    reading = world.ranger(name, ranger)
    if reading is None:
        return np.empty((0, 2))
    spec = specs[ranger]
    s = spec.sensors[0]
    n = reading.ranges.shape[0]
    ox, oy, _ = compose(spec.pose, s.pose)
    a0 = spec.pose[2] + s.pose[2] - s.fov / 2.0
    ang = a0 + np.arange(n) * (s.fov / (n - 1) if n > 1 else 0.0)
    r = reading.ranges.astype(np.float64)
    ok = (r < s.range_max - 1e-3) & (r > s.range_min)
    r, ang = r[ok], ang[ok]
    return np.column_stack((ox + r * np.cos(ang), oy + r * np.sin(ang)))


def in_contact(world: World, name: str) -> bool:
    """Whether the model's body touches any solid shape (wall, box, robot)."""
    shape = world._model(name).shape
    return any(not q.shape.sensor for q in world.space.shape_query(shape))


@dataclass
class Agent:
    """A robot driven by a planner to a goal given in world coordinates."""

    robot: str
    planner: LocalPlanner
    goal: tuple[float, float, float]
    odometry: bool = False  # feed the drifting odometry (goal converted at the start) instead of truth


@dataclass
class RunResult:
    robot: str
    status: str  # the planner's final status
    reached: bool  # status "done" within tolerance: of the true pose, or of the odometry when driving on it
    collided: bool  # the body touched a solid shape at some step
    time: float  # simulated seconds until done (or the timeout)
    error: float  # m, true distance from the goal at the end
    min_range: float  # m, the closest obstacle point seen from the robot's centre
    path: float  # m driven
    blocked_time: float = 0.0  # s spent in status "blocked"
    collided_at: float | None = None  # simulated time of the first contact
    poses: list[tuple[float, float, float]] = field(default_factory=list)


def run(
    world: World,
    agents: Sequence[Agent],
    *,
    timeout: float = 60.0,
    slack: float = 0.15,
    on_step: Callable[[World], None] | None = None,
    record: bool = False,
) -> list[RunResult]:
    """Drive every agent until all are done (or ``timeout`` simulated seconds).

    ``reached`` checks the final position in the frame the planner drove in against its tolerance
    plus ``slack``: the true pose, or for an odometry agent the odometry (whose drift is the base's
    error, not the planner's; ``error`` is always the true distance). ``on_step`` runs before each
    world step (other robots' control).
    """
    dt = world.spec.interval_sim
    if world.ranger(agents[0].robot, 0) is None:
        world.step()  # first scans
    goals = []
    for ag in agents:
        if ag.odometry:
            odom = world.odometry(ag.robot)
            true = world.get_pose(ag.robot)
            to_odom = compose(odom, invert(true))
            goals.append(compose(to_odom, ag.goal))
        else:
            goals.append(tuple(ag.goal))
        ag.planner.set_goal(goals[-1])
    n = len(agents)
    collided: list[float | None] = [None] * n
    min_range = [math.inf] * n
    path = [0.0] * n
    blocked = [0.0] * n
    done_at = [None] * n
    last = [world.get_pose(a.robot) for a in agents]
    poses: list[list] = [[] for _ in agents]
    steps = int(round(timeout / dt))
    for _ in range(steps):
        for i, ag in enumerate(agents):
            if done_at[i] is not None:
                world.set_velocity(ag.robot, 0.0, 0.0)
                continue
            pts = laser_points(world, ag.robot)
            if len(pts):
                min_range[i] = min(min_range[i], float(np.hypot(pts[:, 0], pts[:, 1]).min()))
            pose = world.odometry(ag.robot) if ag.odometry else world.get_pose(ag.robot)
            v, w = ag.planner.step(pose, world.velocity(ag.robot), pts, dt)
            world.set_velocity(ag.robot, v, w)
            if ag.planner.status == Status.BLOCKED:
                blocked[i] += dt
            if ag.planner.status == Status.DONE:
                done_at[i] = world.time
        if on_step is not None:
            on_step(world)
        world.step()
        for i, ag in enumerate(agents):
            p = world.get_pose(ag.robot)
            path[i] += math.hypot(p[0] - last[i][0], p[1] - last[i][1])
            last[i] = p
            if record:
                poses[i].append(p)
            if collided[i] is None and in_contact(world, ag.robot):
                collided[i] = world.time
        if all(d is not None for d in done_at):
            break
    out = []
    for i, ag in enumerate(agents):
        p = world.get_pose(ag.robot)
        err = math.hypot(p[0] - ag.goal[0], p[1] - ag.goal[1])
        if ag.odometry:
            o = world.odometry(ag.robot)
            own = math.hypot(o[0] - goals[i][0], o[1] - goals[i][1])
        else:
            own = err
        status = str(ag.planner.status)
        out.append(
            RunResult(
                robot=ag.robot,
                status=status,
                reached=status == Status.DONE and own <= ag.planner.pos_tol + slack,
                collided=collided[i] is not None,
                collided_at=collided[i],
                time=done_at[i] if done_at[i] is not None else world.time,
                error=err,
                min_range=min_range[i],
                path=path[i],
                blocked_time=blocked[i],
                poses=poses[i],
            )
        )
    return out


# ----------------------------------------------------------------------------------------------- trials
def _clear(grid, x: float, y: float) -> float:
    """Map clearance at one point (arrays in: GridMap.clearance bounds-checks only those)."""
    return float(grid.clearance(np.array([x]), np.array([y]))[0])


def _segment_clearance(grid, a, b, step: float = 0.05) -> float:
    n = max(2, int(math.hypot(b[0] - a[0], b[1] - a[1]) / step) + 1)
    t = np.linspace(0.0, 1.0, n)
    return float(np.min(grid.clearance(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))))


@dataclass
class Trial:
    """One randomly drawn local-planning task: a straight 2-5 m run on the map with a box that is
    not on the map in the way, and other robots driving their own runs across it."""

    start: tuple[float, float, float]
    goal: tuple[float, float, float]
    box: tuple[float, float, float]  # x, y, side (m)
    others: list[tuple[tuple[float, float, float], tuple[float, float, float]]]  # (start, goal) per robot


def draw_trial(grid, rng: np.random.Generator, *, others: int = 2, tries: int = 10000) -> Trial:
    """A trial on ``grid`` (the world's :class:`~simulator.gridmap.GridMap`): the straight line from
    start to goal keeps 0.5 m from walls and has room to pass the box (1.1 m at its centre)."""
    x0, x1, y0, y1 = grid.extent
    for _ in range(tries):
        sx, sy = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if _clear(grid, sx, sy) < 0.6:
            continue
        length = rng.uniform(2.0, 5.0)
        heading = rng.uniform(-math.pi, math.pi)
        gx, gy = sx + length * math.cos(heading), sy + length * math.sin(heading)
        if _segment_clearance(grid, (sx, sy), (gx, gy)) < 0.5:
            continue
        f = rng.uniform(0.4, 0.6)
        side = rng.uniform(0.3, 0.5)
        lat = rng.uniform(-0.15, 0.15)
        bx = sx + f * (gx - sx) - lat * math.sin(heading)
        by = sy + f * (gy - sy) + lat * math.cos(heading)
        if _clear(grid, bx, by) < 1.1 + 0.5 * side:
            continue
        start = (sx, sy, float(wrap(heading + rng.uniform(-0.5, 0.5))))
        goal = (gx, gy, float(rng.uniform(-math.pi, math.pi)))
        taken = [(sx, sy, 0.6), (gx, gy, 0.6), (bx, by, 0.5 * side * math.sqrt(2.0) + 0.4)]
        runs = []
        for i in range(others):
            run_ = _draw_other(grid, rng, start, goal, taken, head_on=(i == 0))
            if run_ is None:
                break
            runs.append(run_)
            taken.append((run_[0][0], run_[0][1], 0.7))
        if len(runs) < others:
            continue
        return Trial(start, goal, (bx, by, side), runs)
    raise RuntimeError("could not draw a trial on this map; is there open space?")


def _draw_other(grid, rng, start, goal, taken, *, head_on: bool):
    """Another robot's run near the main one: head-on from the goal's end, or crossing it. Only
    its start is kept clear of the main run; its goal may lie anywhere free on the map near the
    main run (which only makes a trial harder)."""
    for _ in range(200):
        if head_on:
            ox, oy = goal[0] + rng.uniform(-1.0, 1.0), goal[1] + rng.uniform(-1.0, 1.0)
            tx, ty = start[0] + rng.uniform(-1.0, 1.0), start[1] + rng.uniform(-1.0, 1.0)
        else:
            mx, my = 0.5 * (start[0] + goal[0]), 0.5 * (start[1] + goal[1])
            a = rng.uniform(-math.pi, math.pi)
            dist = rng.uniform(1.5, 3.0)
            ox, oy = mx + dist * math.cos(a), my + dist * math.sin(a)
            tx, ty = mx - dist * math.cos(a), my - dist * math.sin(a)
        if _clear(grid, ox, oy) < 0.6 or _clear(grid, tx, ty) < 0.6:
            continue
        if any(math.hypot(ox - x, oy - y) < r + 0.35 for x, y, r in taken):
            continue
        if _segment_clearance(grid, (ox, oy), (tx, ty)) < 0.45:
            continue
        heading = math.atan2(ty - oy, tx - ox)
        return (ox, oy, heading), (tx, ty, float(rng.uniform(-math.pi, math.pi)))
    return None


def run_trial(
    world: World,
    trial: Trial,
    make_planner: Callable[[tuple[float, float]], LocalPlanner],
    *,
    robots: Sequence[str] | None = None,
    timeout: float = 60.0,
) -> list[RunResult]:
    """Place the trial's robots and box in ``world`` (its first robots are used, in order) and
    drive them all with planners from ``make_planner(geometry)`` (``geometry`` the robot's length and
    width). The first result is the main robot's."""
    from simulator.presets import box

    names = list(robots or world.robot_names)[: 1 + len(trial.others)]
    if len(names) < 1 + len(trial.others):
        raise ValueError(f"the world has {len(names)} robots; the trial needs {1 + len(trial.others)}")
    for extra in world.robot_names:
        if extra not in names:
            world.set_pose(extra, *_parking(world, extra))
    world.set_pose(names[0], *trial.start)
    for name, (s, _) in zip(names[1:], trial.others, strict=True):
        world.set_pose(name, *s)
    bx, by, side = trial.box
    world.add_model(box("trial_box", (bx, by, 0.0), size=(side, side, 0.5)))
    world.step()
    agents = []
    for name, g in zip(names, [trial.goal, *(o[1] for o in trial.others)], strict=True):
        size = world.model_spec(name).size
        agents.append(Agent(name, make_planner((size[0], size[1])), g))
    try:
        return run(world, agents, timeout=timeout)
    finally:
        world.remove_model("trial_box")


def _parking(world: World, name: str) -> tuple[float, float, float]:
    x0, x1, y0, y1 = world.grid.extent if world.grid is not None else (-50, 50, -50, 50)
    return (x1 + 5.0 + 2.0 * world.robot_names.index(name), y1 + 5.0, 0.0)
