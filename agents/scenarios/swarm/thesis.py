"""The thesis's Swarm in full (4.2.3, fig. 4.7): every robot localizes on its sonar ring with AMCL
and carries a planner, as Player ran them in each robot's context.

"In the Swarm scenario each robot has a planner and a localize device running the AMCL, Wavefront and
VFH drivers in the robot's context" -- here ``rsal sim --nav vfh --nav-robots '*'`` (scenario
``simulator: {nav: vfh, nav_robots: ["*"]}``) gives each Pioneer 3-AT its ``amcl`` on ``sonar:0``
(``localize:0`` and the map-frame pose ``position2d:2``, started at the pose its world file gives),
``vfh`` (``position2d:1``) and ``wavefront`` (``planner:0``).

:class:`ThesisSwarmAgent` is a :class:`~agents.scenarios.swarm.agents.SwarmAgent` (wall-following
with the crowd's dispersal layer, broadcasting at 2 Hz, accounting every message it receives) whose
robot context also holds its localize and planner devices: it broadcasts the AMCL pose, not its
odometry, and steers its dispersal by it (:class:`ThesisPioneer`). Its odometry is left as it is:
setting it would look to AMCL like a jump of the robot.

Its robot, :class:`ThesisPioneer`, keeps the crowd from touching and its estimate from leaping:
the behaviour's body-aware checks (:func:`params_for_size`: the lane ahead and behind, no turn that
swings a corner into something), the neighbours' broadcast positions filled into its sectors where
the sonar ring's side gaps would miss them (echoes they explain are not walls to follow), and a
guard that re-seeds the localize device when its pose jumps away from where the robot's own
odometry carried it (:meth:`ThesisPioneer.guard`). Its agent also declares the neighbours'
broadcast positions to the localize device at the broadcast rate
(:meth:`ThesisSwarmAgent.declare_neighbours`, a ``localize`` ``cmd``, or ``rpc/set_obstacles``):
AMCL leaves out the echoes they explain instead of scoring them against a map without robots
(:mod:`mrs_bridge.nav.knownobstacles`). With ``vector: true`` a host's robots run this cycle in one
step on arrays (:class:`.thesisstep.ThesisStep`, the same commands for the same inputs).

:class:`ThesisSwarmMonitor` is the :class:`~agents.scenarios.swarm.monitor.SwarmMonitor` with the
two ground-truth checks the full stack needs: every contact of a robot with a wall or another robot,
counted by the simulator in every physics step (``sim:simulation:0`` ``rpc/contacts``), and each
robot's localization error (its AMCL pose on ``position2d:2`` against its true pose) at every sample;
the verdict needs no contact and an error under ``max_loc_error`` for ``loc_share`` of robot-time.
Its duration counts from when every watched robot's agent has reported (a hundred filters and
agents take a while to start).
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import math
import threading
import time
import weakref

import numpy as np

from agents.registry import agent_class
from agents.services import Outcome, SendPosition
from rsal import keys
from rsal.behaviours import SECTOR_COUNT, BehaviourParams, ListSectors
from rsal.cliutil import FirstFew
from rsal.clock import clock
from rsal.data import normalize_angle
from rsal.geometry import compose, relative
from rsal.interfaces.localize import ObstaclesCmd
from rsal.robot import Pioneer

from .agents import SwarmAgent
from .behaviour import SwarmPioneer
from .monitor import SwarmMonitor
from .thesisstep import ThesisStep
from .vector import HostStep

_SECTOR = 360.0 / SECTOR_COUNT
_HALF_SECTOR = _SECTOR / 2

__all__ = ["ThesisPioneer", "ThesisSwarmAgent", "ThesisSwarmMonitor", "params_for_size"]

#: re-seeds logged one line each for a few, then at debug level (each agent counts its own)
_RESEEDS = FirstFew("re-seeds of localize poses")

log = logging.getLogger(__name__)

LOCALIZE = "position2d:2"  # the amcl driver's pose in the map frame (mrs_bridge.drivers.amcl)
DECLARE_TO = "localize:0"  # the amcl driver's localize device: its cmd takes the neighbours

_nav_nodes: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # RobotHub -> its DeviceNode of nav devices
_nav_lock = threading.Lock()


def _nav_node(hub):
    """One DeviceNode per host's hub following every robot's localize pose and planner."""
    with _nav_lock:
        node = _nav_nodes.get(hub)
        if node is None:
            node = _nav_nodes[hub] = hub.fabric.node(f"*:{LOCALIZE}", "*:planner:0")
        return node


class ThesisPioneer(SwarmPioneer):
    """A :class:`SwarmPioneer` whose dispersal layer reads the robot's heading from its localize
    device (the map frame its neighbours' broadcasts are in), not from its odometry, and whose
    sectors also hold its neighbours' bodies where their broadcasts put them (:meth:`sectors`)."""

    localize = None  # the Position2d proxy of <robot>:position2d:2, set by the agent
    #: ``neighbours(x, y, r)``: (k, 2) broadcast positions (map frame) of the other robots within
    #: r m of (x, y), set by the agent; None: sonar only
    neighbours = None
    neighbour_range = 2.5  # m: neighbours nearer than this are fused into the sectors
    neighbour_radius = 0.33  # m: a neighbour's body around its broadcast position (set from the size)
    explained_within = 0.6  # m: an echo this near a neighbour's body or beyond is not a wall
    reseeds = 0  # how often guard() re-seeded the localize device
    _guard_ref = None  # (localize pose, odometry pose, time) of the last check
    _guard_hold = 0.0

    def sectors(self):
        """The sonar ring's sectors with the neighbours' bodies fused in by minimum: each robot
        within :attr:`neighbour_range` of the localize pose, seen as a disc of
        :attr:`neighbour_radius` round its broadcast position, fills the sectors it spans with its
        nearest distance. The ring's 16 cones leave 25 deg gaps at the sides where a robot alongside
        goes unseen; the broadcasts close them (what a real swarm's shared positions are for)."""
        s = super().sectors()
        self.behaviour.walls = None
        m = self.localize.latest if self.localize is not None else None
        if self.neighbours is None or m is None:
            return s
        x, y, yaw = m.pose
        near = self.neighbours(x, y, self.neighbour_range)
        if not len(near):
            return s
        sonar = list(s.dist)
        d = _bodies(near, x, y, yaw, self.neighbour_radius)  # the neighbours' bodies
        # an echo no farther than a neighbour's body (give or take the poses' errors) is that robot
        tol = self.explained_within
        self.behaviour.walls = ListSectors([a if a < b - tol else math.inf for a, b in zip(sonar, d, strict=True)])
        return ListSectors([min(a, b) for a, b in zip(sonar, d, strict=True)])

    #: a localize pose farther than this (m) from where the odometry carried the last one within
    #: ``check_every`` s is a jump of the filter, not a correction: it is re-seeded (:meth:`guard`).
    #: A robot that drifted in open space corrects by up to ~0.6 m in a second when a wall comes
    #: into range; with 0.3 m / 0.35 rad the guard undid those corrections and pinned the estimate
    #: to the odometry's drift (ten robots, 30 s: 93.9 % of robot-time within 0.5 m; 97.4 % with
    #: these limits, 96.4 % with no guard at all)
    jump_limit = 1.0
    jump_yaw = 0.6  # rad, the same for the heading
    check_every = 1.0  # s
    reseed_cov = (0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.005)  # m^2, rad^2: 0.1 m and 4 deg

    def update(self) -> None:
        m = self.localize.latest if self.localize is not None else None
        if m is None:
            super().update()
            return
        self.guard(m.pose)
        self.behaviour.yaw = m.pose[2]
        Pioneer.update(self)

    def guard(self, est) -> None:
        """Re-seed the localize device when its pose jumps away from where the robot's own
        odometry carried it. AMCL on a 16-sonar ring in a crowd sees mostly other robots, which
        are not on its map; now and then the filter settles on a wrong fit and its pose leaps by
        metres in a second, which no wheel turned for. The robot cannot see the truth, but it can
        compare: every ``check_every`` s the pose becomes the reference, and a pose farther than
        ``jump_limit`` m (or ``jump_yaw`` rad) from the reference moved on by the odometry since is
        answered with ``set_pose`` at the odometry's pose (``reseed_cov``). Corrections smaller than
        that (the filter's work near walls) pass."""
        odo = self.position2d.latest
        if odo is None or self.localize is None:
            return
        now = clock().now()
        if self._guard_ref is None:
            self._guard_ref = (tuple(est), odo.pose, now)
            return
        if now < self._guard_hold:
            return
        ref_est, ref_odo, t = self._guard_ref
        pred = compose(ref_est, relative(ref_odo, odo.pose))
        if (
            math.hypot(est[0] - pred[0], est[1] - pred[1]) > self.jump_limit
            or abs(normalize_angle(est[2] - pred[2])) > self.jump_yaw
        ):
            self.reseeds += 1
            _RESEEDS.log(
                log,
                logging.INFO,
                "%s: localize pose jumped %.2f m from the odometry's; re-seeded",
                self.name,
                math.hypot(est[0] - pred[0], est[1] - pred[1]),
            )
            self.localize.rpc_async("set_pose", pose=[float(v) for v in pred], cov=list(self.reseed_cov))
            self._guard_ref = (tuple(pred), odo.pose, now)
            self._guard_hold = now + 0.5  # until the driver has published the new pose
        elif now - t >= self.check_every:
            self._guard_ref = (tuple(est), odo.pose, now)


def _bodies(near, x: float, y: float, yaw: float, r: float) -> list[float]:
    """Per sector, the nearest surface of discs of radius ``r`` centred at the rows of ``near``
    ((k, 2), world frame) seen from a robot at (``x``, ``y``) heading ``yaw``: each disc fills the
    sectors its width spans (inf where none). Plain Python: for the few neighbours within reach it
    is 3-10 times faster than numpy's per-call overhead (measured at 3, 8 and 16 neighbours)."""
    d = [math.inf] * SECTOR_COUNT
    for nx, ny in near.tolist():
        dx, dy = nx - x, ny - y
        dist = math.hypot(dx, dy)
        if dist < 1e-6:
            continue
        surface = max(0.0, dist - r)
        bearing = math.degrees(math.atan2(dy, dx) - yaw)
        half = math.degrees(math.asin(min(1.0, r / dist)))
        i0 = math.floor((bearing - half + _HALF_SECTOR) / _SECTOR)
        i1 = min(math.floor((bearing + half + _HALF_SECTOR) / _SECTOR), i0 + SECTOR_COUNT - 1)
        for i in range(i0, i1 + 1):
            j = i % SECTOR_COUNT
            if surface < d[j]:
                d[j] = surface
    return d


def params_for_size(
    length: float,
    width: float,
    base: BehaviourParams | None = None,
    *,
    lane_margin: float = 0.1,
    sweep_margin: float = 0.05,
) -> BehaviourParams:
    """The behaviour's distances (``radius``, ``stop_dist``, ``avoid_dist``, ``wall_dist``) scaled
    from the Pioneer 2DX's (44 x 38 cm, the defaults of :class:`rsal.behaviours.BehaviourParams`) to
    a base of ``length`` x ``width`` m: a Pioneer 3-AT (62.6 x 50.5 cm) keeps 1.4 times the
    distance, so its longer body stops before it touches what the 2DX's distances let it reach.

    The body-aware checks of :class:`rsal.behaviours.BehaviourParams` are on: the front is the
    lane of the body's half-width plus ``lane_margin`` m (a neighbour at 40 deg is in the way of
    the 3-AT's front corners, outside the plain +-30 deg cone), escape backs up only into a clear
    lane, and nothing turns in place within the body's half-diagonal plus ``sweep_margin`` m."""
    base = base or BehaviourParams()
    k = max(1.0, max(length, width) / 2.0 / 0.22)
    return dataclasses.replace(
        base,
        radius=base.radius * k,
        stop_dist=base.stop_dist * k,
        avoid_dist=base.avoid_dist * k,
        wall_dist=base.wall_dist * k,
        corridor=width / 2.0 + lane_margin,
        sweep=math.hypot(length / 2.0, width / 2.0) + sweep_margin,
    )


@agent_class("ThesisSwarmAgent")
class ThesisSwarmAgent(SwarmAgent):
    """One robot of the thesis's swarm: a :class:`SwarmAgent` whose robot also has a localize device
    (AMCL on its sonar ring, pose on ``<robot>:position2d:2``) and a planner (``<robot>:planner:0``).
    Its broadcasts carry the AMCL pose (``map`` frame); its behaviour's distances fit its base's
    size (:func:`params_for_size`). Takes every :class:`SwarmAgent` argument; ``simulation`` is
    false by default (no true pose is read: the AMCL estimate is the only pose the robot has).
    ``vector`` is false by default: each robot runs its own cycle; true runs the host's robots in
    one step on arrays (:class:`.thesisstep.ThesisStep`: the same commands for the same inputs, but
    at 100 robots its runs so far had 3-4 times the contacts of the per-robot cycle's, not yet
    explained: docs/benchmarks.md)."""

    pioneer_class = ThesisPioneer

    def __init__(self, agent_id: str, *, simulation: bool = False, vector: bool = False, **kw):
        super().__init__(agent_id, simulation=simulation, vector=vector, **kw)
        self.localize = None  # the Position2d proxy of <robot>:position2d:2

    def _join_hub(self):
        """The host's hub, whose batch step (with ``vector``) is the thesis robots'
        (:class:`.thesisstep.ThesisStep`: one step on arrays for all of them, their own cycle's result)."""
        hub = super()._join_hub()
        if type(hub.batch) is HostStep:
            hub.batch = ThesisStep(hub, lambda: clock().now(), ThesisPioneer)
        return hub

    def _build_shared(self, hub) -> Pioneer:  # a worker thread
        name = self.robot
        deadline = time.monotonic() + self.startup_timeout
        node = _nav_node(hub)
        for what in (LOCALIZE, "planner:0"):
            addr = f"{name}:{what}"
            try:
                node.wait_for(addr, 1, max(0.5, deadline - time.monotonic()))
            except TimeoutError:
                raise TimeoutError(
                    f"robot {name!r}: no {addr} within {self.startup_timeout:g} s (the thesis swarm needs the "
                    "navigation stack per robot: rsal sim --nav vfh --nav-robots '*')"
                ) from None
        self.localize = node.device(f"{name}:{LOCALIZE}")
        try:
            self.localize.wait_for_data(max(0.5, deadline - time.monotonic()))
        except TimeoutError:
            raise TimeoutError(f"robot {name!r}: its localize device published no pose in time") from None
        robot = super()._build_shared(hub)
        robot.localize = self.localize
        size = robot.position2d.describe(timeout=5.0).geometry.get("size") or [0.44, 0.38]
        length, width = float(size[0]), float(size[1])
        robot.behaviour.p = params_for_size(length, width, robot.behaviour.p)
        # the crowd is of one model: a neighbour's body is about this robot's, between its
        # inscribed and circumscribed radius
        robot.neighbour_radius = (width / 2.0 + math.hypot(length / 2.0, width / 2.0)) / 2.0
        robot.neighbours = lambda x, y, r: hub.near(x, y, r, exclude=name)
        self._obstacle_radius = math.hypot(length / 2.0, width / 2.0) + self.obstacle_margin
        self.frame = "map"  # what it broadcasts and steers by
        return robot

    def pose_message(self) -> SendPosition | None:
        m = self.localize.latest if self.localize is not None else None
        if m is None:
            return super().pose_message()
        x, y, yaw = m.pose
        return SendPosition(self.robot, x, y, yaw, "map")

    #: m: neighbours whose broadcast positions are declared to the localize device (the sonar's reach)
    obstacle_range = 5.0
    #: m added to a neighbour's circumscribed radius for the errors of both robots' poses
    obstacle_margin = 0.15
    obstacle_ttl = 1.5  # s: the localize device forgets them after this (two missed broadcasts)
    #: how the neighbours are declared: "cmd" (localize:0 ``cmd``, ObstaclesCmd, fire and forget) or
    #: "rpc" (``rpc/set_obstacles``, a query and a reply each)
    declare_by = "cmd"
    _obstacle_radius = 0.55
    _declare_failed = False

    async def step(self) -> None:
        sent = self.sent
        await super().step()
        if self.sent != sent:
            self.declare_neighbours()

    def declare_neighbours(self) -> None:
        """Tell the robot's localize device where its neighbours are, as their broadcasts put them
        (``set_obstacles``, at the broadcast rate): AMCL leaves out the sonar echoes they explain
        instead of scoring them against a map that has no robots on it (thesis 4.2.3: the positions
        are broadcast for the swarm's use; :mod:`mrs_bridge.nav.knownobstacles`)."""
        m = self.localize.latest if self.localize is not None else None
        if m is None or self._hub is None:
            return
        near = self._hub.near(m.pose[0], m.pose[1], self.obstacle_range, exclude=self.robot)
        discs = [[float(x), float(y), self._obstacle_radius] for x, y in near.tolist()]
        if self.declare_by == "rpc":
            fut = self.localize.rpc_async("set_obstacles", obstacles=discs, ttl=self.obstacle_ttl)
            fut.add_done_callback(self._declared)
            return
        # the command form: one put, no query to route and no reply to wait for (2 Hz x 100 robots)
        cmd = ObstaclesCmd(tuple(tuple(d) for d in discs), self.obstacle_ttl)
        self.localize.fabric.send(keys.parse_device(f"{self.robot}:{DECLARE_TO}"), cmd)

    def _declared(self, fut) -> None:  # a zenoh or executor thread: only logs
        e = fut.exception()
        if e is not None and not self._declare_failed:
            self._declare_failed = True  # once per agent: the next broadcasts try again
            log.warning("%s: %s:%s rpc/set_obstacles failed: %s", self.id, self.robot, LOCALIZE, e)


@agent_class("ThesisSwarmMonitor")
class ThesisSwarmMonitor(SwarmMonitor):
    """The swarm's judge with the full stack's checks (module docstring): ``max_loc_error`` (m) and
    ``loc_share`` (the share of robot-samples that must be within it, 0.95) on top of every
    :class:`SwarmMonitor` argument; contacts (robot-robot, robot-wall) of the watched robots must be
    none."""

    def __init__(self, agent_id: str, *, max_loc_error: float = 0.5, loc_share: float = 0.95, **kw):
        super().__init__(agent_id, **kw)
        if not max_loc_error > 0:
            raise ValueError(f"agent {agent_id}: max_loc_error {max_loc_error!r} must be a positive distance in m")
        if not 0 < loc_share <= 1:
            raise ValueError(f"agent {agent_id}: loc_share {loc_share!r} must be in (0, 1]")
        self.max_loc_error = float(max_loc_error)
        self.loc_share = float(loc_share)
        self.estimates: list = []  # Position2d proxies of each watched robot's position2d:2
        self.loc_errors: list[np.ndarray] = []  # per sample: each robot's error (nan: no estimate yet)
        self.contacts: dict = {"robot_robot": 0, "robot_wall": 0, "robots": {}}
        self._est_node = None

    def _simulation(self):  # a worker thread
        sim = super()._simulation()
        self._est_node = self.fabric.node(f"*:{LOCALIZE}")
        deadline = time.monotonic() + self.startup_timeout
        for r in self.robots:
            try:
                self._est_node.wait_for(f"{r}:{LOCALIZE}", 1, max(0.5, deadline - time.monotonic()))
            except TimeoutError:
                raise TimeoutError(
                    f"{self.id}: robot {r} has no localize pose {r}:{LOCALIZE} within {self.startup_timeout:g} s"
                ) from None
            self.estimates.append(self._est_node.device(f"{r}:{LOCALIZE}"))
        return sim

    async def poses(self, sim) -> np.ndarray:
        xy = await super().poses(sim)
        self.contacts = await asyncio.wrap_future(sim.rpc_async("contacts"))
        return xy

    def check(self, xy: np.ndarray, t: float) -> None:
        super().check(xy, t)
        est = np.full((len(self.robots), 2), np.nan)
        for i, dev in enumerate(self.estimates):
            m = dev.latest
            if m is not None:
                est[i] = m.pose[:2]
        if len(est) != len(xy) or (not self.loc_errors and np.isnan(est).any()):
            return  # localization is judged from the first sample with every robot's estimate on
        self.loc_errors.append(np.hypot(*(est - xy).T))

    def localization(self) -> tuple[float, float, float]:
        """(share of robot-samples within ``max_loc_error``, its 95th percentile, the worst) in m."""
        if not self.loc_errors:
            return 0.0, math.nan, math.nan
        e = np.concatenate(self.loc_errors)
        e = np.where(np.isnan(e), np.inf, e)  # a robot without an estimate counts as lost
        return float(np.mean(e <= self.max_loc_error)), float(np.percentile(e, 95)), float(e.max())

    def contact_counts(self) -> tuple[int, int]:
        """(robot-robot, robot-wall) contacts of the watched robots (a pair of watched robots counts
        once for each of them)."""
        per = self.contacts.get("robots", {}) if isinstance(self.contacts, dict) else {}
        watched = set(self.robots)
        rr = sum(int(v[0]) for k, v in per.items() if k in watched)
        rw = sum(int(v[1]) for k, v in per.items() if k in watched)
        return rr, rw

    def judge(self, elapsed: float, final: bool = True, wall: float | None = None) -> Outcome:
        base = super().judge(elapsed, final, wall)
        share, p95, worst = self.localization()
        rr, rw = self.contact_counts()
        problems = []
        if rr or rw:
            problems.append(f"{rr} robot-robot and {rw} robot-wall contact(s)")
        if share < self.loc_share:
            problems.append(
                f"localization within {self.max_loc_error:g} m for {100 * share:.1f} % of robot-time "
                f"< {100 * self.loc_share:g} %"
            )
        text = (
            f"{base.text}; contacts {rr} robot-robot, {rw} robot-wall; localization error p95 {p95:.2f} m, "
            f"worst {worst:.2f} m, within {self.max_loc_error:g} m {100 * share:.1f} %"
        )
        if problems:
            text += " -- " + "; ".join(problems)
        return Outcome(base.event, base.subject, text, ok=base.ok and not problems, final=base.final)

    async def killed(self) -> None:
        if self._est_node is not None:
            self._est_node.close()
        await super().killed()
