"""The Find and Collect scenario's agents (thesis 4.2.2): ExploreAgent, CollectAgent and MasterAgent.

Two groups of robots work together. *Explorers* wall-follow with a blobfinder (a colour camera) and
report every newly seen blob with its map position; *collectors* have a gripper and the navigation
stack (amcl, wavefront, vfh) and fetch blobs to their home position (by default where they start).
A *master* keeps the blackboard of participants and blobs (thesis fig. 3.14, :class:`rsal.data.Board`),
merges repeated reports of one blob and hands each blob to one collector: the nearest free one
(``allocation: direct``), or, in the thesis's "advanced" variant, the one that wins a FIPA
contract-net call among the collectors (``allocation: contract_net``, :mod:`agents.contractnet`,
cost = straight-line distance to the blob).

Services (bodies without a schema in :mod:`agents.services`; fields validated here):

``blob``       explorer → all: ``robot`` str, ``color`` int 0xRRGGBB, ``x``, ``y`` m (map frame). The
               thesis's ReceiveNewGoalService report of a new blob. Explorers repeat their blobs
               every ``repeat_every`` seconds, so a master that starts late still learns them.
``collect``    master → collector: ``to``, ``blob`` id, ``x``, ``y`` m: fetch that blob home.
``collected``  collector → master: ``to``, ``blob``, ``ok`` bool, ``x``, ``y`` (where it was put
               down, or where the collector gave up), ``reason`` str (empty when ok).

When a blob is home the master publishes ``Outcome("delivered", subject=<blob id>, ...)``.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np

from rsal.client import Fabric
from rsal.clock import clock, wait_for
from rsal.data import BlobfinderBlob, Board, BoardObject, Position, normalize_angle
from rsal.devices import Simulation
from rsal.msgs import MapData, MessageError, RpcError, get_float, get_int, get_str
from rsal.robot import ExploreRobot, NavRobot, Robot

from .classes import RobotAgent, WallfollowAgent
from .contractnet import Initiator, Participant
from .runtime import Agent
from .services import Hello, Message, Outcome, SendPosition, match

__all__ = [
    "BLOB",
    "COLLECT",
    "COLLECTED",
    "BlobReport",
    "CollectAgent",
    "ExploreAgent",
    "FetchResult",
    "MasterAgent",
]

log = logging.getLogger(__name__)

BLOB = "blob"
COLLECT = "collect"
COLLECTED = "collected"
ALLOCATIONS = ("direct", "contract_net")


def _number(agent_id: str, name: str, value, lo: float = 0.0, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not lo < value <= hi or math.isnan(value):
        raise ValueError(f"agent {agent_id}: {name} {value!r} must be a number in ({lo:g}, {hi:g}]")
    return float(value)


def _point(agent_id: str, name: str, value) -> Position | None:
    if value is None:
        return None
    try:
        vals = list(value)
        if len(vals) not in (2, 3):
            raise ValueError
        return Position.from_degrees(*vals) if len(vals) == 3 else Position(*vals)
    except (TypeError, ValueError):
        raise ValueError(f"agent {agent_id}: {name} {value!r} must be [x, y] or [x, y, degrees]") from None


@dataclass(frozen=True)
class BlobReport:
    """A ``blob`` message body: robot ``robot`` saw a blob of ``color`` at (``x``, ``y``), map frame."""

    robot: str
    color: int
    x: float
    y: float

    @classmethod
    def from_dict(cls, m: dict) -> BlobReport:
        return cls(get_str(m, "robot"), get_int(m, "color", 0, lo=0, hi=0xFFFFFF), get_float(m, "x"), get_float(m, "y"))

    def to_dict(self) -> dict:
        return {"robot": self.robot, "color": self.color, "x": self.x, "y": self.y}


# ============================================================================ explorer
class _Explorer(ExploreRobot):
    """An ExploreRobot whose map pose may come from the simulation (thesis 3.6.2.2: a robot aware of
    its simulation): ``truth`` set to the simulation device makes it read its true pose each cycle."""

    truth: Simulation | None = None
    _truth_pose: Position | None = None

    @property
    def position(self) -> Position | None:
        if self.truth is not None and self._truth_pose is not None:
            return self._truth_pose
        return super().position

    def update(self) -> None:
        if self.truth is not None:
            try:
                self._truth_pose = Position(*self.truth.rpc("get_pose", timeout=0.5, name=self.name)["pose"])
            except Exception as e:  # the simulation is gone or slow: keep the last pose
                log.debug("%s: no true pose: %s", self.name, e)
        super().update()


class ExploreAgent(WallfollowAgent):
    """Wall-follows with an :class:`~rsal.robot.ExploreRobot` (thesis 4.2.2), publishes the robot's
    pose on ``send_position`` and every newly seen blob on ``blob`` (map frame: from the robot's
    localizer if it has one, else, with ``simulation``, its true pose in the simulation, else its
    odometry anchored at ``pose``). ``side`` is the wall kept ("left" or "right"), ``merge_dist`` (m)
    how far apart two sightings must be to count as two blobs, ``repeat_every`` (s) how often all
    blobs found so far are reported again."""

    capabilities = ("send_position", "explore", BLOB)
    needs = ("blobfinder",)

    def __init__(
        self,
        agent_id: str,
        *,
        side: str = "left",
        merge_dist: float = 0.5,
        repeat_every: float = 10.0,
        **kw,
    ):
        super().__init__(agent_id, **kw)
        if side not in ("left", "right"):
            raise ValueError(f"agent {agent_id}: side {side!r} must be 'left' or 'right'")
        self.side = side
        self.merge_dist = _number(agent_id, "merge_dist", merge_dist, 0.0, 10.0)
        self.repeat_every = _number(agent_id, "repeat_every", repeat_every, 0.0, 3600.0)
        self.blobs: list[BlobReport] = []  # every blob found, in order
        self.reports = 0  # blob messages published
        self._next_repeat = 0.0

    def make_robot(self, devices: list) -> Robot:
        return _Explorer(devices, name=self.robot, period=self.period, laser=self.laser, merge_dist=self.merge_dist)

    async def find_robot(self, fabric: Fabric) -> Robot:
        robot = await super().find_robot(fabric)
        if self.simulation and robot.localize is None:
            robot.truth = await asyncio.to_thread(self._simulation, fabric)
            self.frame = "map"
        return robot

    def _simulation(self, fabric: Fabric) -> Simulation:  # a worker thread
        node = fabric.node("*:simulation:0")
        try:
            found = node.wait_for("*:simulation:0", 1, self.startup_timeout)
        except TimeoutError:
            raise TimeoutError(
                f"robot {self.robot!r}: no simulation device appeared within {self.startup_timeout:g} s "
                "(simulation=true needs a simulator)"
            ) from None
        return node.device(found[0])

    def configure(self, robot: Robot) -> None:
        super().configure(robot)
        loop = asyncio.get_running_loop()
        robot.on_blob(lambda b: loop.call_soon_threadsafe(self._found, b))  # the robot's thread

    def _found(self, blob: BlobfinderBlob) -> None:
        if self.state != "running" or blob.discovered is None:
            return
        rep = BlobReport(self.robot, blob.color, blob.discovered.x, blob.discovered.y)
        self.blobs.append(rep)
        log.info("%s: new %s blob at (%.2f, %.2f)", self.id, blob.color_name, rep.x, rep.y)
        self.publish(BLOB, rep.to_dict())
        self.reports += 1

    async def step(self) -> None:
        await super().step()
        now = clock().now()
        if self.blobs and now >= self._next_repeat:
            for rep in self.blobs:
                self.publish(BLOB, rep.to_dict())
                self.reports += 1
        if now >= self._next_repeat:
            self._next_repeat = now + self.repeat_every

    def pose_message(self) -> SendPosition | None:
        r = self.pioneer
        if isinstance(r, _Explorer) and r.truth is not None:
            p = r.position
            return SendPosition(self.robot, p.x, p.y, p.yaw, "map") if p is not None else None
        return super().pose_message()

    def status(self) -> str:
        return f"{super().status()}  {len(self.blobs)} blob(s) found"


# ============================================================================ collector
@dataclass
class FetchResult:
    """What became of one fetch: ``ok``, ``reason`` when not, and where the blob was left."""

    ok: bool
    reason: str = ""
    x: float = math.nan
    y: float = math.nan


class CollectAgent(RobotAgent):
    """Fetches blobs home with a gripper (thesis 4.2.2). On a task (a ``collect`` message, or an
    accepted contract-net proposal) it drives (wavefront goal) to ``approach`` metres before the
    blob, facing it, opens the gripper, creeps forward, steered by its blobfinder if it has one (else
    by its map pose), until the gripper's beams break, closes and lifts, drives to ``home`` ([x, y]
    or [x, y, degrees], map frame; default its start pose), lowers and opens the gripper, backs off
    and reports ``collected`` (and, for a contract, inform-done or failure). A goal it cannot reach
    or a blob that is not at the spot is reported as a failure."""

    capabilities = ("send_position", "collect")
    needs = ("planner", "gripper")

    def __init__(
        self,
        agent_id: str,
        *,
        home: Sequence[float] | None = None,
        approach: float = 0.8,
        goto_timeout: float = 180.0,
        creep_speed: float = 0.12,
        **kw,
    ):
        super().__init__(agent_id, **kw)
        self.home = _point(agent_id, "home", home)
        self.approach = _number(agent_id, "approach", approach, 0.3, 3.0)
        self.goto_timeout = _number(agent_id, "goto_timeout", goto_timeout, 0.0, 3600.0)
        self.creep_speed = _number(agent_id, "creep_speed", creep_speed, 0.0, 0.3)
        self.busy: str | None = None  # the blob being fetched
        self.task_state = "idle"
        self.delivered: list[str] = []
        self.failed: list[str] = []
        self.cnp: Participant | None = None
        self._last_bid = -math.inf
        self._map: MapData | None = None
        self._free: np.ndarray | None = None

    def make_robot(self, devices: list) -> Robot:
        return NavRobot(devices, name=self.robot, period=self.period, laser=self.laser)

    async def created(self) -> None:
        await super().created()
        if self.home is None:
            p = await self._pose(self.startup_timeout)
            if p is None:
                raise TimeoutError(f"robot {self.robot!r}: no localized pose for the home position")
            self.home = p
        await asyncio.to_thread(self._load_map, self.fabric)
        self.subscribe(COLLECT, self._on_collect, filter=match(to=self.id))
        self.cnp = Participant(self)

    async def _pose(self, timeout: float) -> Position | None:
        """The robot's first pose on the map (from its localizer, not its odometry)."""
        r: NavRobot = self.pioneer  # type: ignore[assignment]
        deadline = clock().now() + timeout
        while clock().now() < deadline:
            if r.localized is not None and r.localized.latest is not None:
                return r.localized.position
            if r.localize is not None and getattr(r.localize, "position", None) is not None:
                return r.localize.position
            await clock().asleep(0.1)
        return None

    # ------------------------------------------------------------------ tasks
    async def _on_collect(self, msg: Message) -> None:
        try:
            blob, x, y = get_str(msg.body, "blob"), get_float(msg.body, "x"), get_float(msg.body, "y")
        except MessageError as e:
            log.warning("%s: dropped a bad collect message from %s: %s", self.id, msg.sender, e)
            return
        if self.busy is not None:
            self._report(msg.sender, blob, FetchResult(False, f"busy with {self.busy}"))
            return
        self._report(msg.sender, blob, await self.fetch(blob, x, y))

    def bid(self, task: dict):
        """Contract net: the straight-line distance to the blob, or None (refuse) when busy."""
        now = clock().now()
        outstanding = self.cnp is not None and any(v == "proposed" for v in self.cnp.outcomes.values())
        if self.busy is not None or (outstanding and now - self._last_bid < 10.0):
            return None  # one blob at a time: no second offer while a proposal awaits its answer
        p = self.pioneer.position if self.pioneer is not None else None
        try:
            x, y = float(task["x"]), float(task["y"])
        except (KeyError, TypeError, ValueError):
            return None
        if p is None or not (math.isfinite(x) and math.isfinite(y)):
            return None
        self._last_bid = now
        return math.hypot(x - p.x, y - p.y)

    async def perform(self, task: dict) -> bool:
        self._last_bid = -math.inf
        blob = str(task.get("blob", "?"))
        if self.busy is not None:
            return False
        res = await self.fetch(blob, float(task["x"]), float(task["y"]))
        self._report(str(task.get("master", "")), blob, res)  # the reason and the spot, for the master
        return res.ok

    def _report(self, to: str, blob: str, res: FetchResult) -> None:
        body = {"to": to, "blob": blob, "ok": res.ok, "x": res.x, "y": res.y, "reason": res.reason}
        if not math.isfinite(res.x) or not math.isfinite(res.y):
            p = self.pioneer.position if self.pioneer is not None else None
            body["x"], body["y"] = (p.x, p.y) if p is not None else (0.0, 0.0)
        self.publish(COLLECTED, body)

    # ------------------------------------------------------------------ the fetch
    async def fetch(self, blob: str, x: float, y: float) -> FetchResult:
        """Fetch the blob at (``x``, ``y``) home; never raises for a failure, returns it."""
        if self.busy is not None:
            return FetchResult(False, f"busy with {self.busy}")
        self.busy = blob
        t0 = clock().now()
        try:
            res = await self._fetch(blob, Position(x, y))
        except Exception as e:  # a device vanished, an rpc failed: report, stay usable
            log.exception("%s: fetching %s failed", self.id, blob)
            res = FetchResult(False, f"{type(e).__name__}: {e}")
        finally:
            self.busy = None
            self.task_state = "idle"
        (self.delivered if res.ok else self.failed).append(blob)
        log.info(
            "%s: %s %s after %.0f s%s",
            self.id,
            blob,
            "delivered" if res.ok else "not delivered",
            clock().now() - t0,
            "" if res.ok else f": {res.reason}",
        )
        if not res.ok:
            await self._safe_stop()
        return res

    async def _fetch(self, blob: str, spot: Position) -> FetchResult:
        r: NavRobot = self.pioneer  # type: ignore[assignment]
        g = r.gripper
        # 1. to just before the blob, facing it
        self.task_state = f"to {blob}"
        err = await self._goto_near(spot)
        if err:
            return FetchResult(False, f"cannot reach {blob} at ({spot.x:.1f}, {spot.y:.1f}): {err}")
        # 2. gripper open and down, creep until the beams break
        self.task_state = f"approaching {blob}"
        await asyncio.gather(self._wait(g.open(), 10.0), self._wait(g.lift_down(), 10.0))
        if not await self._creep(spot):
            await asyncio.to_thread(r.position2d.stop)
            return FetchResult(False, f"{blob} not found at ({spot.x:.1f}, {spot.y:.1f})")
        # 3. grip and lift
        self.task_state = f"gripping {blob}"
        await self._wait(g.close(), 10.0)
        await self._until(lambda: g.carrying, 2.0)
        if not g.carrying:
            await self._wait(g.open(), 10.0)
            return FetchResult(False, f"{blob}: the gripper closed on nothing")
        await self._wait(g.lift_up(), 10.0)
        # 4. home
        self.task_state = f"carrying {blob} home"
        err = await self._goto(self.home)
        if err:
            err2 = await self._goto(self.home)  # once more: replans from where it stopped
            if err2:
                return FetchResult(False, f"cannot bring {blob} home: {err2}")
        # 5. put it down, back off
        self.task_state = f"dropping {blob}"
        await self._wait(g.lift_down(), 10.0)
        await self._wait(g.open(), 10.0)
        await self._until(lambda: not g.carrying, 2.0)
        here = r.position
        gp = g.describe().geometry.get("pose", [0.23, 0.0, 0.0])
        drop = Position(float(gp[0]), float(gp[1])).to_global(here) if here is not None else self.home
        await self._drive(-0.15, 0.0, 0.5)
        return FetchResult(True, "", drop.x, drop.y)

    def stand_offs(self, spot: Position, toward: Position) -> list[Position]:
        """Places ``approach`` m (then a little more) from ``spot``, facing it, nearest first to the
        side ``toward`` lies on; on a known map only those with ``clearance`` m of free space
        around them (a robot can turn there without its local planner shying from a wall)."""
        first = math.atan2(spot.y - toward.y, spot.x - toward.x)
        ks = sorted(range(-8, 8), key=abs)
        out = []
        for dist in (self.approach, self.approach + 0.3):
            for k in ks:
                a = first + k * math.pi / 8
                stand = Position(spot.x - dist * math.cos(a), spot.y - dist * math.sin(a), normalize_angle(a))
                if self._clear(stand):
                    out.append(stand)
        return out or [
            Position(spot.x - self.approach * math.cos(first), spot.y - self.approach * math.sin(first), first)
        ]

    def _clear(self, p: Position, clearance: float = 0.65) -> bool:
        m = self._map
        if m is None:
            return True
        res = m.resolution
        cx, cy = (p.x - m.origin[0]) / res, (p.y - m.origin[1]) / res
        r = int(math.ceil(clearance / res))
        i0, i1, j0, j1 = int(cy) - r, int(cy) + r + 1, int(cx) - r, int(cx) + r + 1
        if i0 < 0 or j0 < 0 or i1 > m.height or j1 > m.width:
            return False
        win = self._free[i0:i1, j0:j1]
        yy, xx = np.mgrid[i0:i1, j0:j1]
        disc = (xx + 0.5 - cx) ** 2 + (yy + 0.5 - cy) ** 2 <= (clearance / res) ** 2
        return bool(win[disc].all())

    def _load_map(self, fabric: Fabric) -> None:  # a worker thread
        node = fabric.node("*:map:*")
        try:
            found = node.wait_for("*:map:*", 1, 5.0)
            self._map = node.device(found[0]).get_map(timeout=10.0)
            self._free = self._map.cells == -1
        except Exception as e:  # no map: stand-off points are not checked
            log.info("%s: no map for choosing stand-off points (%s)", self.id, e)

    async def _goto_near(self, spot: Position) -> str:
        """Drive to ``approach`` m before ``spot``, facing it; try other sides when the planner
        refuses a stand-off point. Returns '' or the last error."""
        r: NavRobot = self.pioneer  # type: ignore[assignment]
        err = ""
        for stand in self.stand_offs(spot, r.position or self.home)[:6]:
            err = await self._goto(stand)
            if not err:
                return ""
            if "superseded" in err or "timed out" in err:
                return err
        return err

    async def _goto(self, goal: Position) -> str:
        """Drive to ``goal`` by the planner; '' when there (or settled within 0.5 m of it for 8 s,
        when the local planner dithers over the last centimetres), else the reason."""
        r: NavRobot = self.pioneer  # type: ignore[assignment]
        fut = asyncio.wrap_future(await asyncio.to_thread(r.goto, goal))
        deadline = clock().now() + self.goto_timeout
        near_since = None
        while not fut.done():
            now = clock().now()
            if now > deadline:
                await self._safe_stop()
                return f"goal ({goal.x:.1f}, {goal.y:.1f}) not reached: timed out after {self.goto_timeout:g} s"
            p = r.position
            if p is not None and p.distance_to(goal) < 0.5:
                near_since = near_since or now
                if now - near_since > 8.0:
                    await self._safe_stop()
                    return ""
            else:
                near_since = None
            await asyncio.wait([fut], timeout=clock().wall(0.2))
        try:
            fut.result()
        except RpcError as e:
            return str(e)
        return ""

    async def _creep(self, spot: Position) -> bool:
        """Creep toward the blob until the gripper's beams break (True) or it is clearly not there."""
        r: NavRobot = self.pioneer  # type: ignore[assignment]
        g = r.gripper
        base = r.position2d
        start = base.position
        limit = self.approach + 0.6
        deadline = clock().now() + 40.0
        while clock().now() < deadline:
            if g.beams:
                await asyncio.to_thread(base.stop)
                return True
            here, odo = r.position, base.position
            if here is None or odo is None:
                await clock().asleep(0.1)
                continue
            if start is not None and odo.distance_to(start) > limit:
                break
            bearing = self._bearing(here, spot)
            if abs(bearing) > 0.35:
                v, w = 0.0, math.copysign(min(0.6, 1.2 * abs(bearing)), bearing)
            else:
                v, w = self.creep_speed, max(-0.5, min(0.5, 1.5 * bearing))
            base.set_velocity(v, w, hold=False)  # refreshed by this 10 Hz loop
            await clock().asleep(0.1)
        await asyncio.to_thread(base.stop)
        return bool(g.beams)

    def _bearing(self, here: Position, spot: Position) -> float:
        """Bearing to the blob: the blobfinder's blob nearest to where the blob should be, else the map."""
        r = self.pioneer
        best, best_d = None, 1.0
        if r is not None and r.blobfinder is not None:
            for b in r.blobfinder.blobs:
                d = b.world_position(here).distance_to(spot)
                if d < best_d:
                    best, best_d = b, d
        if best is not None:
            return best.bearing
        return normalize_angle(math.atan2(spot.y - here.y, spot.x - here.x) - here.yaw)

    async def _drive(self, v: float, w: float, dist: float) -> None:
        base = self.pioneer.position2d
        start = base.position
        deadline = clock().now() + dist / max(abs(v), 0.05) + 3.0
        while clock().now() < deadline:
            p = base.position
            if start is not None and p is not None and p.distance_to(start) >= dist:
                break
            base.set_velocity(v, w, hold=False)  # refreshed by this 10 Hz loop
            await clock().asleep(0.1)
        await asyncio.to_thread(base.stop)

    async def _safe_stop(self) -> None:
        try:
            await asyncio.to_thread(self.pioneer.stop)
        except Exception as e:
            log.debug("%s: stop failed: %s", self.id, e)

    @staticmethod
    async def _wait(fut: Future, timeout: float) -> None:
        try:
            await wait_for(asyncio.wrap_future(fut), timeout)
        except TimeoutError:
            pass

    @staticmethod
    async def _until(cond, timeout: float) -> None:
        deadline = clock().now() + timeout
        while not cond() and clock().now() < deadline:
            await clock().asleep(0.05)

    def status(self) -> str:
        r = self.pioneer
        p = r.position if r is not None else None
        where = f"x={p.x:6.2f} y={p.y:6.2f} yaw={p.yaw:5.2f}" if p is not None else "no pose"
        return f"{where}  {self.task_state}  delivered {len(self.delivered)}, failed {len(self.failed)}"


# ============================================================================ master
@dataclass
class _BlobTask:
    """What the master knows of one blob (the ``data`` of its board note)."""

    id: str
    color: int
    reported_by: str
    found: float  # monotonic time of the first report
    spot: Position  # where it was reported
    reports: int = 1
    assignee: str = ""
    since: float = 0.0
    attempts: int = 0
    retry_at: float = 0.0
    failures: list[str] = field(default_factory=list)
    drop: Position | None = None  # where a collector put it down
    reason: str = ""  # why the last fetch failed


class MasterAgent(Agent):
    """Keeps the blackboard of participants and blobs and hands blobs to collectors (thesis 4.2.2).

    Participants are learned from ``hello`` (collectors offer ``collect``, explorers ``explore``);
    collectors' positions from ``send_position``. A ``blob`` report within ``merge_dist`` m of a known
    blob (also one already home) is the same blob; one within ``carry_dist`` m of a collector is a
    blob being carried and is ignored. Each new blob goes to the nearest free collector
    (``allocation: direct``, a ``collect`` message) or to the winner of a contract-net call
    (``allocation: contract_net``). A failed or timed-out fetch (``task_timeout`` s) is offered again
    after ``retry_after`` seconds. A blob brought home is published as ``Outcome("delivered")``.
    """

    capabilities = ("master",)

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str = "",
        period: float = 0.5,
        allocation: str = "direct",
        merge_dist: float = 0.8,
        carry_dist: float = 1.2,
        retry_after: float = 10.0,
        task_timeout: float = 600.0,
        bid_deadline: float = 1.0,
        discover_every: float = 2.0,
    ):
        super().__init__(agent_id, period=period, robot=robot)
        if allocation not in ALLOCATIONS:
            raise ValueError(f"agent {agent_id}: allocation {allocation!r} must be one of {', '.join(ALLOCATIONS)}")
        self.allocation = allocation
        self.merge_dist = _number(agent_id, "merge_dist", merge_dist, 0.0, 10.0)
        self.carry_dist = _number(agent_id, "carry_dist", carry_dist, 0.0, 10.0)
        self.retry_after = _number(agent_id, "retry_after", retry_after, 0.0, 3600.0)
        self.task_timeout = _number(agent_id, "task_timeout", task_timeout, 0.0, 86400.0)
        self.bid_deadline = _number(agent_id, "bid_deadline", bid_deadline, 0.0, 60.0)
        self.discover_every = _number(agent_id, "discover_every", discover_every, 0.0, 600.0)
        self.board = Board()
        self.duplicates = 0  # reports merged into a known blob
        self.ignored = 0  # reports of blobs being carried
        self.positions: dict[str, Position] = {}  # agent id -> latest send_position
        self.cnp: Initiator | None = None
        self._n = 0
        self._next_discovery = 0.0
        self._discovering = False
        self._bidding_until = 0.0

    # ------------------------------------------------------------------ blackboard views
    def blobs(self, state: str = "*") -> list[BoardObject]:
        """The blob notes in ``state`` (``new``, ``assigned``, ``delivered`` or ``*`` for all three),
        oldest first. (Sightings of carried blobs are kept under ``blob/carried``.)"""
        notes = self.board.values(f"blob/{state}")
        return sorted((n for n in notes if n.topic != "blob/carried" or state == "carried"), key=lambda o: o.data.found)

    def collectors(self) -> list[str]:
        return sorted(str(k[1]) for k, o in self.board.items("participant/collector"))

    def _set_state(self, note: BoardObject, state: str) -> None:
        note.topic = f"blob/{state}"
        self.board.put(("blob", note.data.id), note)

    # ------------------------------------------------------------------ lifecycle
    async def created(self) -> None:
        self.subscribe(BLOB, self.on_blob)
        self.subscribe(SendPosition.SERVICE, self.on_position)
        self.subscribe(COLLECTED, self.on_collected, filter=match(to=self.id))
        if self.allocation == "contract_net":
            self.cnp = Initiator(self)

    async def step(self) -> None:
        loop = asyncio.get_running_loop()
        now = clock().now()
        if now >= self._next_discovery and not self._discovering:
            self._next_discovery = now + self.discover_every
            self._discovering = True
            self._require_host().spawn(self._discover(), f"{self.id}: discovery")
        mono = clock().now()
        for note in self.blobs("assigned"):
            if mono - note.data.since > self.task_timeout:
                log.warning("%s: %s: no word from %s; offering it again", self.id, note.data.id, note.data.assignee)
                self._failed(note, "timed out")
        if self.allocation == "direct":
            self._assign_direct(mono)
        elif now >= self._bidding_until:
            self._assign_cnp(mono, loop)

    async def _discover(self) -> None:
        try:
            hellos = await self._require_host().who_is_there(timeout=min(1.0, self.discover_every))
        finally:
            self._discovering = False
        for h in hellos:
            self.on_hello(h)

    def on_hello(self, h: Hello) -> None:
        """Note a participant (its note lives a few discovery rounds)."""
        kind = "collector" if "collect" in h.capabilities else "explorer" if "explore" in h.capabilities else ""
        if kind:
            ttl = max(10.0, 3 * self.discover_every)
            self.board.put(("participant", h.id), BoardObject(f"participant/{kind}", data=h, timeout=ttl))

    # ------------------------------------------------------------------ inbound
    def on_position(self, msg: Message) -> None:
        b = msg.body
        if b.frame == "map":
            self.positions[msg.sender] = Position(b.x, b.y, b.yaw)

    def on_blob(self, msg: Message) -> None:
        try:
            rep = BlobReport.from_dict(msg.body)
        except MessageError as e:
            log.warning("%s: dropped a bad blob report from %s: %s", self.id, msg.sender, e)
            return
        self.report(rep, msg.sender)

    def report(self, rep: BlobReport, sender: str) -> str | None:
        """Take one blob report; returns the new blob's id, or None for a known or carried blob."""
        where = Position(rep.x, rep.y)
        for note in self.board.values("blob/*"):  # also one already home (there and where it was)
            if min(note.position.distance_to(where), note.data.spot.distance_to(where)) <= self.merge_dist:
                note.data.reports += 1
                self.duplicates += 1
                return None
        for cid in self.collectors():
            p = self.positions.get(cid)
            if p is not None and p.distance_to(where) <= self.carry_dist:
                # a blob in a gripper; remembered, so that the sighting's repeats are not taken as new
                self.ignored += 1
                data = _BlobTask(f"carried-{cid}", rep.color, sender, clock().now(), where)
                self.board.put(
                    ("carried", self.ignored), BoardObject("blob/carried", position=where, data=data, timeout=0)
                )
                return None
        blob_id = f"blob{self._n}"
        self._n += 1
        data = _BlobTask(blob_id, rep.color, sender, clock().now(), where)
        self.board.put(("blob", blob_id), BoardObject("blob/new", position=where, data=data, timeout=0))
        log.info("%s: %s at (%.2f, %.2f) reported by %s", self.id, blob_id, rep.x, rep.y, sender)
        return blob_id

    def on_collected(self, msg: Message) -> None:
        try:
            blob = get_str(msg.body, "blob")
            ok = bool(msg.body.get("ok", False))
            x, y = get_float(msg.body, "x"), get_float(msg.body, "y")
            reason = get_str(msg.body, "reason", "")
        except MessageError as e:
            log.warning("%s: dropped a bad collected message from %s: %s", self.id, msg.sender, e)
            return
        note = self.board.get(("blob", blob))
        if note is None:
            return
        if self.allocation == "contract_net" and ok and note.topic == "blob/delivered":  # after inform-done
            note.position = Position(x, y)
            return
        if note.topic != "blob/assigned":
            return
        if self.allocation == "contract_net":  # the contract says done or failure; this gives the spot
            note.data.assignee = msg.sender
            if ok:
                note.data.drop = Position(x, y)
            else:
                note.data.reason = reason
            return
        if note.data.assignee != msg.sender:
            return
        if ok:
            self._delivered(note, msg.sender, Position(x, y))
        else:
            self._failed(note, reason)

    # ------------------------------------------------------------------ allocation
    def _free_collectors(self) -> list[str]:
        busy = {n.data.assignee for n in self.blobs("assigned")}
        return [c for c in self.collectors() if c not in busy]

    def _assign_direct(self, now: float) -> None:
        free = self._free_collectors()
        for note in self.blobs("new"):
            if not free:
                return
            if note.data.retry_at > now:
                continue
            best = min(free, key=lambda c: (self._distance(c, note.position), c))
            free.remove(best)
            self._assign(note, best, now)
            self.publish(COLLECT, {"to": best, "blob": note.data.id, "x": note.position.x, "y": note.position.y})

    def _assign_cnp(self, now: float, loop: asyncio.AbstractEventLoop) -> None:
        if not self.collectors():
            return
        for note in self.blobs("new"):
            if note.data.retry_at > now:
                continue
            self._assign(note, "", now)
            self._bidding_until = clock().now() + self.bid_deadline + 0.5
            self._require_host().spawn(self._contract(note), f"{self.id}: contract for {note.data.id}")
            return  # one call in its bidding phase at a time

    async def _contract(self, note: BoardObject) -> None:
        d = note.data
        task = {"blob": d.id, "x": note.position.x, "y": note.position.y, "master": self.id}
        # every collector is asked; a busy one refuses
        res = await self.cnp.call(task, deadline=self.bid_deadline, done_deadline=self.task_timeout)
        if res.winner:
            d.assignee = res.winner
        if res.outcome == "done":
            self._delivered(note, res.winner or "?", d.drop or note.position)
        elif res.outcome == "no_bids":
            d.assignee = ""
            d.retry_at = clock().now() + min(self.retry_after, 3.0)
            self._set_state(note, "new")
        else:
            self._failed(note, res.reason or d.reason or res.outcome)

    def _assign(self, note: BoardObject, collector: str, now: float) -> None:
        d = note.data
        d.assignee, d.since = collector, now
        d.attempts += 1
        self._set_state(note, "assigned")
        if collector:
            log.info("%s: %s at (%.2f, %.2f) -> %s", self.id, d.id, note.position.x, note.position.y, collector)

    def _distance(self, collector: str, where: Position) -> float:
        p = self.positions.get(collector)
        return p.distance_to(where) if p is not None else math.inf

    def _delivered(self, note: BoardObject, by: str, drop: Position) -> None:
        d = note.data
        found_at = note.position
        note.position = drop
        d.assignee = by
        self._set_state(note, "delivered")
        took = clock().now() - d.found
        text = f"{d.id} at ({found_at.x:.1f}, {found_at.y:.1f}) delivered home by {by} after {took:.0f} s"
        log.info("%s: %s", self.id, text)
        self.publish(Outcome.SERVICE, Outcome("delivered", d.id, text))

    def _failed(self, note: BoardObject, reason: str) -> None:
        d = note.data
        d.failures.append(reason)
        log.info(
            "%s: %s not collected by %s (%s); offered again in %g s",
            self.id,
            d.id,
            d.assignee,
            reason,
            self.retry_after,
        )
        d.assignee = ""
        d.retry_at = clock().now() + self.retry_after
        self._set_state(note, "new")

    def status(self) -> str:
        return (
            f"{len(self.collectors())} collector(s)  blobs: {len(self.blobs('new'))} new, "
            f"{len(self.blobs('assigned'))} assigned, {len(self.blobs('delivered'))} delivered  "
            f"{self.duplicates} duplicate report(s)"
        )
