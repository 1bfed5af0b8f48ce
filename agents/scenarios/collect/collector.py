"""The collectors of Find and Collect (thesis 4.2.2): navigating robots with a gripper.

Two groups of robots work together. *Explorers* (:mod:`.explorer`) wall-follow with a blobfinder
and report every newly seen blob with its map position; *collectors* (:class:`CollectAgent`, here)
have a gripper and the navigation stack (amcl, wavefront, vfh) and fetch blobs to their home
position (by default where they start) when the *master* (:mod:`.master`) hands them one on
``collect``; they answer on ``collected`` (:mod:`.messages`).
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Sequence
from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np

from agents.classes import RobotAgent
from agents.contractnet import Participant
from agents.registry import agent_class
from agents.services import Message, match
from rsal.client import Fabric
from rsal.clock import clock, wait_for
from rsal.data import Position, normalize_angle
from rsal.msgs import MapData, MessageError, RpcError, get_float, get_str
from rsal.robot import NavRobot, Robot

from .messages import COLLECT, COLLECTED
from .messages import check_number as _number
from .messages import check_point as _point

__all__ = ["CollectAgent", "FetchResult"]

log = logging.getLogger(__name__)


@dataclass
class FetchResult:
    """What became of one fetch: ``ok``, ``reason`` when not, and where the blob was left."""

    ok: bool
    reason: str = ""
    x: float = math.nan
    y: float = math.nan


@agent_class("CollectAgent")
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
    async def fetch(self, blob: str, x: float, y: float, home: Position | None = None) -> FetchResult:
        """Fetch the blob at (``x``, ``y``) to ``home`` (default: this collector's home); never
        raises for a failure, returns it."""
        if self.busy is not None:
            return FetchResult(False, f"busy with {self.busy}")
        self.busy = blob
        t0 = clock().now()
        try:
            res = await self._fetch(blob, Position(x, y), home or self.home)
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

    async def _fetch(self, blob: str, spot: Position, home: Position) -> FetchResult:
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
        err = await self._goto(home)
        if err:
            err2 = await self._goto(home)  # once more: replans from where it stopped
            if err2:
                return FetchResult(False, f"cannot bring {blob} home: {err2}")
        # 5. put it down, back off
        self.task_state = f"dropping {blob}"
        await self._wait(g.lift_down(), 10.0)
        await self._wait(g.open(), 10.0)
        await self._until(lambda: not g.carrying, 2.0)
        here = r.position
        gp = g.describe().geometry.get("pose", [0.23, 0.0, 0.0])
        drop = Position(float(gp[0]), float(gp[1])).to_global(here) if here is not None else home
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
