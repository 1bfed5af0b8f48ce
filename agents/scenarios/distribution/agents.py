"""The Distribution scenario (thesis 4.2.4): a DispersionAgent spreads the navigating robots over the map.

The thesis's central planner "pings" every agent, sorts the answers on a blackboard by the class of
the responding agent, gives each navigating agent a distribution point (nearest free one first)
and sends it there with the NewGoalService; agents that do not answer are ignored. Its points were
predefined by hand; the thesis's "Advanced Distribution Scenario" asks for points computed from the
map at run time that are "mutually reachable and not too close to a wall", spread "with equal,
maximized distances", in rooms as well as along the corridor. That is what :func:`target_points`
does here:

1. free cells of the map (Player's -1) whose distance to the nearest occupied cell
   (``scipy.ndimage.distance_transform_edt``) lets a robot of ``robot_radius`` pass form the
   drivable space; its connected components (8-neighbourhood) that hold a robot are reachable;
2. reachable cells at least ``clearance`` m from any wall are candidates;
3. farthest-point sampling (Gonzalez 1985, the 2-approximation of the k-centre problem) picks the
   targets: first the candidate farthest from the robots, then each time the candidate farthest
   from all targets chosen so far, while that distance is at least ``spacing`` m. The long corridor
   alone would give points on a line; the rooms off it hold the farthest points, so they are
   chosen too. The order is nested: the first k targets are a spread for k robots.

:class:`DispersionAgent` assigns the targets to the robots so that the total straight-line distance
is minimal (``scipy.optimize.linear_sum_assignment``) and sends each agent its ``new_goal``. It
watches the agents' liveliness tokens (``agents/<id>``): when an agent disappears before it
arrived, it is dropped and the live agents are assigned again, from where they are now, to the
first k targets (k = the live agents): the most spread targets stay covered, and agents that already
stand on a kept target (distance 0) keep it. Each change is published on ``outcome`` as
``assigned``; when every live agent has reported ``arrived`` for its target, the final verdict
``Outcome("verdict", "distribution", ok, final=True)`` says how many robots reached how many distinct
targets and their minimum spacing.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import zenoh

from agents.maps import fetch_map
from agents.registry import agent_class
from agents.runtime import Agent
from agents.services import Message, NewGoal, Outcome, SendPosition, match
from rsal.clock import clock, wait_for
from rsal.data import Board, BoardObject, Position
from rsal.msgs import MapData

__all__ = ["DispersionAgent", "Targets", "assign", "target_points"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Targets:
    """Distribution points (``xy``, (n, 2) metres, map frame, in sampling order) and the grids they
    came from: ``reachable`` drivable cells connected to a robot, ``clearance`` metres to the
    nearest wall per cell (both row 0 at the bottom of the map)."""

    xy: np.ndarray
    reachable: np.ndarray
    clearance: np.ndarray
    resolution: float
    origin: tuple[float, float]

    def cell(self, x: float, y: float) -> tuple[int, int]:
        """(row, column) of a map point."""
        return (
            int(math.floor((y - self.origin[1]) / self.resolution)),
            int(math.floor((x - self.origin[0]) / self.resolution)),
        )

    def min_spacing(self) -> float:
        return _min_spacing(self.xy)


def _min_spacing(xy: np.ndarray) -> float:
    if len(xy) < 2:
        return math.inf
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    d[np.diag_indices(len(xy))] = np.inf
    return float(d.min())


def target_points(
    grid: MapData,
    starts: Sequence[Sequence[float]],
    n: int,
    *,
    clearance: float = 0.6,
    spacing: float = 2.0,
    robot_radius: float = 0.3,
    step: float = 0.2,
    within: Sequence[float] | None = None,
) -> Targets:
    """Up to ``n`` distribution points on ``grid`` for robots at ``starts`` ([x, y] each, map frame).

    ``clearance``: minimum distance of a point to a wall (m); ``spacing``: minimum distance between
    points (fewer than ``n`` come back when no more fit); ``robot_radius``: half the width of the
    narrowest gap a robot passes (connectivity); ``step``: the candidates' grid (m, a subsample of the
    map's cells); ``within``: optional box [xmin, ymin, xmax, ymax] the points must lie in.
    Raises ValueError when no robot stands on drivable space."""
    from scipy import ndimage

    if n < 1:
        raise ValueError(f"number of targets {n!r} must be at least 1")
    cells = np.asarray(grid.cells)
    res = float(grid.resolution)
    ox, oy = float(grid.origin[0]), float(grid.origin[1])
    free = cells < 0
    dist = ndimage.distance_transform_edt(free) * res  # metres to the nearest non-free cell
    drivable = dist >= robot_radius
    labels, _ = ndimage.label(drivable, structure=np.ones((3, 3), dtype=bool))
    keep = set()
    h, w = cells.shape
    for x, y in ((float(s[0]), float(s[1])) for s in starts):
        r, c = int(math.floor((y - oy) / res)), int(math.floor((x - ox) / res))
        if not (0 <= r < h and 0 <= c < w):
            continue
        # a robot standing close to a wall: take the nearest drivable cell within 1 m
        k = int(math.ceil(1.0 / res))
        r0, r1, c0, c1 = max(0, r - k), min(h, r + k + 1), max(0, c - k), min(w, c + k + 1)
        win = labels[r0:r1, c0:c1]
        if not win.any():
            continue
        rr, cc = np.nonzero(win)
        i = int(np.argmin((rr + r0 - r) ** 2 + (cc + c0 - c) ** 2))
        keep.add(int(win[rr[i], cc[i]]))
    if not keep:
        raise ValueError("no robot stands on drivable space of the map (are the robots' positions in the map frame?)")
    reachable = np.isin(labels, sorted(keep))
    cand = reachable & (dist >= clearance)
    stride = max(1, int(round(step / res)))
    sub = np.zeros_like(cand)
    sub[stride // 2 :: stride, stride // 2 :: stride] = True
    rr, cc = np.nonzero(cand & sub)
    empty = Targets(np.zeros((0, 2)), reachable, dist, res, (ox, oy))
    if rr.size == 0:
        return empty
    pts = np.column_stack([ox + (cc + 0.5) * res, oy + (rr + 0.5) * res])
    if within is not None:
        x0, y0, x1, y1 = (float(v) for v in within)
        inside = (pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)
        pts = pts[inside]
        if len(pts) == 0:
            return empty
    st = np.asarray([[float(s[0]), float(s[1])] for s in starts], dtype=float).reshape(-1, 2)
    # farthest-point sampling, seeded by the distance to the robots
    far = np.min(np.hypot(pts[:, None, 0] - st[None, :, 0], pts[:, None, 1] - st[None, :, 1]), axis=1)
    chosen = [int(np.argmax(far))]
    d = np.hypot(pts[:, 0] - pts[chosen[0], 0], pts[:, 1] - pts[chosen[0], 1])
    while len(chosen) < n:
        i = int(np.argmax(d))
        if d[i] < spacing:
            break
        chosen.append(i)
        d = np.minimum(d, np.hypot(pts[:, 0] - pts[i, 0], pts[:, 1] - pts[i, 1]))
    return Targets(pts[chosen], reachable, dist, res, (ox, oy))


def assign(robots: np.ndarray, targets: np.ndarray) -> list[tuple[int, int]]:
    """Pairs (robot index, target index) with minimal total straight-line distance; with more robots
    than targets some robots get none (and vice versa)."""
    from scipy.optimize import linear_sum_assignment

    if len(robots) == 0 or len(targets) == 0:
        return []
    r = np.asarray(robots, dtype=float).reshape(-1, 2)
    t = np.asarray(targets, dtype=float).reshape(-1, 2)
    cost = np.hypot(r[:, None, 0] - t[None, :, 0], r[:, None, 1] - t[None, :, 1])
    ri, ti = linear_sum_assignment(cost)
    return sorted(zip(ri.tolist(), ti.tolist(), strict=True))


@agent_class("DispersionAgent")
class DispersionAgent(Agent):
    """The thesis's DispersionAgent (4.2.4, "Advanced Distribution Scenario"): pings with ``hello``,
    keeps the answers on a blackboard by agent class, computes distribution points from the map,
    assigns them to the navigating agents (classes ``classes``) by minimum total distance and sends
    each its ``new_goal``; re-assigns when an agent disappears; publishes the verdict.

    ``map``: the map device; ``expect``: how many navigating agents to wait for (0: those answering
    the first ping, at least one) within ``startup_timeout`` s; ``clearance``, ``spacing``,
    ``robot_radius``, ``within``: as :func:`target_points`; ``targets``: fixed points [[x, y], ...]
    instead (the thesis's predefined ones); ``goal_timeout``: seconds for all to arrive;
    ``retries``: times a failed goal is sent again.
    """

    capabilities = ("outcome",)

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str = "",
        period: float = 0.5,
        classes: Sequence[str] = ("NavAgent",),
        map: str = "sim:map:0",  # noqa: A002 - the scenario argument's name
        expect: int = 0,
        clearance: float = 0.6,
        spacing: float = 2.0,
        robot_radius: float = 0.3,
        within: Sequence[float] | None = None,
        targets: Sequence[Sequence[float]] | None = None,
        startup_timeout: float = 60.0,
        goal_timeout: float = 600.0,
        retries: int = 1,
        hello_timeout: float = 1.0,
    ):
        super().__init__(agent_id, period=period, robot=robot)
        if isinstance(classes, str):
            classes = [classes]
        if not classes or not all(isinstance(c, str) and c for c in classes):
            raise ValueError(f"agent {agent_id}: classes {classes!r} must name agent classes, e.g. [NavAgent]")
        if isinstance(expect, bool) or not isinstance(expect, int) or expect < 0:
            raise ValueError(f"agent {agent_id}: expect {expect!r} must be a count >= 0")
        if within is not None and (len(within) != 4 or not within[0] < within[2] or not within[1] < within[3]):
            raise ValueError(f"agent {agent_id}: within {within!r} must be [xmin, ymin, xmax, ymax]")
        if targets is not None:
            try:
                targets = [(float(t[0]), float(t[1])) for t in targets]
            except (TypeError, ValueError, IndexError):
                raise ValueError(f"agent {agent_id}: targets must be a list of [x, y] points") from None
        for name, v in (("clearance", clearance), ("robot_radius", robot_radius), ("goal_timeout", goal_timeout)):
            if not (isinstance(v, int | float) and v > 0):
                raise ValueError(f"agent {agent_id}: {name} {v!r} must be a positive number")
        self.classes = set(classes)
        self.map_addr = map
        self.expect = expect
        self.clearance = float(clearance)
        self.spacing = float(spacing)
        self.robot_radius = float(robot_radius)
        self.within = list(within) if within is not None else None
        self.fixed_targets = targets
        self.startup_timeout = float(startup_timeout)
        self.goal_timeout = float(goal_timeout)
        self.retries = int(retries)
        self.hello_timeout = float(hello_timeout)
        self.board = Board()  # participants by class (topic) and the robots' latest positions
        self.targets: np.ndarray = np.zeros((0, 2))
        self.participants: dict[str, str] = {}  # agent id -> robot id
        self.assignment: dict[str, int] = {}  # live agent id -> target index
        self.arrived: set[str] = set()  # agents that reported arriving at their current target
        self.dropped: list[str] = []
        self.failures: dict[str, int] = {}
        self.history: list[tuple[str, int]] = []  # every (agent, target) sent, in order
        self.verdict: Outcome | None = None
        self.grid: MapData | None = None
        self._live_sub = None
        self._changed: asyncio.Event | None = None
        self._resent: dict[str, int] = {}  # agent -> failures answered with a resend

    # ------------------------------------------------------------------ inputs
    async def created(self) -> None:
        self._changed = asyncio.Event()
        self.subscribe(SendPosition.SERVICE, self._on_position)
        self.subscribe(Outcome.SERVICE, self._on_outcome, filter=match(event="arrived"))
        host = self._require_host()
        self._live_sub = host.session.liveliness().declare_subscriber(
            "agents/*", lambda s: host.services.call_soon(self._on_token, str(s.key_expr), s.kind)
        )

    def _on_position(self, msg: Message) -> None:
        b: SendPosition = msg.body
        if b.frame == "map":
            self.board.put(("pos", b.robot), BoardObject(topic="position", position=Position(b.x, b.y, b.yaw)))

    def _on_outcome(self, msg: Message) -> None:
        o: Outcome = msg.body
        agent = next((a for a, r in self.participants.items() if r == o.subject and a in self.assignment), None)
        if agent is None or agent != msg.sender:
            return
        if o.ok:
            i = self.assignment[agent]
            p = self.position_of(o.subject)
            tx, ty = self.targets[i]
            if p is not None and math.hypot(p.x - tx, p.y - ty) > 1.5:
                return  # an arrival at an earlier target, reported after a re-assignment
            self.arrived.add(agent)
            self.publish(Outcome.SERVICE, Outcome("progress", o.subject, f"{o.subject} reached target {i}"))
        else:
            self.failures[agent] = self.failures.get(agent, 0) + 1
            log.warning("%s: %s failed its goal: %s", self.id, o.subject, o.text)
        assert self._changed is not None
        self._changed.set()

    def _on_token(self, key: str, kind: zenoh.SampleKind) -> None:
        agent = key.rsplit("/", 1)[-1]
        if kind != zenoh.SampleKind.DELETE or agent not in self.assignment or self.verdict is not None:
            return
        log.info("%s: agent %s left; its robot %s is dropped", self.id, agent, self.participants.get(agent))
        del self.assignment[agent]
        self.arrived.discard(agent)
        self.dropped.append(agent)
        self.reassign()
        assert self._changed is not None
        self._changed.set()

    def position_of(self, robot: str) -> Position | None:
        o = self.board.get(("pos", robot))
        return o.position if o is not None else None

    # ------------------------------------------------------------------ planning
    def _load_map(self) -> MapData:  # a worker thread
        hint = "is 'rsal sim' running with its floorplan, or set 'map'"
        return fetch_map(self._require_host().session, self.map_addr, self.startup_timeout, self.id, hint)

    async def load_map(self) -> MapData:
        """The map the targets are computed on (override to supply one)."""
        return await asyncio.to_thread(self._load_map)

    async def discover(self) -> dict[str, str]:
        """Ping with ``hello`` until ``expect`` navigating agents answered with a map position (or
        the first answers, when ``expect`` is 0); returns agent id -> robot."""
        deadline = clock().now() + self.startup_timeout
        while True:
            for h in await self._require_host().who_is_there(self.hello_timeout):
                self.board.put(("agent", h.id), BoardObject(topic=h.cls, data=h, timeout=0))
            found = {
                o.data.id: o.data.robot
                for c in self.classes
                for o in self.board.values(c)
                if o.data.robot and self.position_of(o.data.robot) is not None
            }
            want = self.expect or 1
            if len(found) >= want or (clock().now() >= deadline and found):
                return found
            if clock().now() >= deadline:
                raise TimeoutError(
                    f"{self.id}: {len(found)} of {want} navigating agent(s) ({', '.join(sorted(self.classes))}) "
                    f"answered with a map position within {self.startup_timeout:g} s"
                )
            await clock().asleep(0.5)

    def send_goal(self, agent: str, i: int) -> None:
        x, y = self.targets[i]
        self.publish(NewGoal.SERVICE, NewGoal(agent, float(x), float(y), 0.0))
        self.history.append((agent, i))
        robot = self.participants[agent]
        p = self.position_of(robot)
        dist = f", {math.hypot(x - p.x, y - p.y):.1f} m away" if p is not None else ""
        text = f"{robot} -> target {i} ({x:.1f}, {y:.1f}){dist}"
        self.publish(Outcome.SERVICE, Outcome("assigned", robot, text, at=(float(x), float(y))))

    def reassign(self) -> None:
        """Assign the live agents, from where they are now, to the first k targets (k live agents);
        send a goal to every agent whose target changed."""
        live = sorted(self.assignment)
        k = min(len(live), len(self.targets))
        if k == 0:
            return
        xy = []
        for a in live:
            p = self.position_of(self.participants[a])
            xy.append((p.x, p.y) if p is not None else tuple(self.targets[self.assignment[a]]))
        pairs = assign(np.array(xy), self.targets[:k])
        new = {live[r]: t for r, t in pairs}
        for a in live:
            if a not in new:  # more agents than targets: nothing for it
                self.assignment.pop(a)
                continue
            if new[a] != self.assignment[a]:
                self.assignment[a] = new[a]
                self.arrived.discard(a)
                self.failures.pop(a, None)
                self._resent.pop(a, None)
                self.send_goal(a, new[a])

    # ------------------------------------------------------------------ life
    async def body(self) -> None:
        self.grid = await self.load_map()
        self.participants = await self.discover()
        agents = sorted(self.participants)
        starts = [self.position_of(self.participants[a]) for a in agents]
        if self.fixed_targets is not None:
            self.targets = np.array(self.fixed_targets, dtype=float).reshape(-1, 2)
        else:
            t = await asyncio.to_thread(
                target_points,
                self.grid,
                [(p.x, p.y) for p in starts],
                len(agents),
                clearance=self.clearance,
                spacing=self.spacing,
                robot_radius=self.robot_radius,
                within=self.within,
            )
            self.targets = t.xy
        log.info("%s: %d agent(s), %d target(s)", self.id, len(agents), len(self.targets))
        for r, i in assign(np.array([(p.x, p.y) for p in starts]), self.targets):
            self.assignment[agents[r]] = i
        for a in agents:
            if a not in self.assignment:
                log.warning("%s: no target left for %s", self.id, a)
        for a, i in sorted(self.assignment.items()):
            self.send_goal(a, i)
        deadline = clock().now() + self.goal_timeout
        assert self._changed is not None
        while True:
            for a, n in list(self.failures.items()):
                if a in self.assignment and a not in self.arrived and self._resent.get(a, 0) < n <= self.retries:
                    self._resent[a] = n
                    self.send_goal(a, self.assignment[a])
            failed = [a for a, n in self.failures.items() if a in self.assignment and n > self.retries]
            done = self.assignment and all(a in self.arrived for a in self.assignment)
            if done or failed or clock().now() >= deadline or not self.assignment:
                break
            self._changed.clear()
            try:
                await wait_for(self._changed.wait(), max(0.1, min(1.0, deadline - clock().now())))
            except TimeoutError:
                pass
        self.verdict = self.judge()
        self.publish(Outcome.SERVICE, self.verdict)
        log.info("%s: %s", self.id, self.verdict.text)

    def judge(self) -> Outcome:
        reached = sorted(a for a in self.assignment if a in self.arrived)
        n = len(self.assignment)
        idx = sorted({self.assignment[a] for a in reached})
        spacing = _min_spacing(self.targets[idx]) if idx else math.nan
        sp = f"{spacing:.1f} m" if math.isfinite(spacing) else "n/a"
        text = f"{len(reached)} robots reached {len(idx)} distinct targets, min spacing {sp}"
        if self.dropped:
            text += f"; dropped {', '.join(self.participants.get(a, a) for a in self.dropped)}"
        ok = n > 0 and len(reached) == n == len(idx)
        if not ok:
            missing = [self.participants.get(a, a) for a in sorted(self.assignment) if a not in self.arrived]
            text += f" -- not reached: {', '.join(missing) or 'none assigned'}"
        return Outcome("verdict", "distribution", text, ok=ok, final=True)

    async def killed(self) -> None:
        if self._live_sub is not None:
            try:
                self._live_sub.undeclare()
            except Exception:
                pass
