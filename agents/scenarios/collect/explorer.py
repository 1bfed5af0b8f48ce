"""The explorers of Find and Collect (thesis 4.2.2): wall-following robots that report blobs.

:class:`ExploreAgent` wall-follows with an :class:`rsal.robot.ExploreRobot` (a blobfinder, the
colour camera) and reports every newly seen blob with its map position on ``blob``
(:mod:`.messages`), repeating its blobs every ``repeat_every`` seconds.
"""

from __future__ import annotations

import asyncio
import logging

from agents.classes import WallfollowAgent
from agents.registry import agent_class
from agents.services import SendPosition
from rsal.client import Fabric
from rsal.clock import clock
from rsal.data import BlobfinderBlob, Position
from rsal.devices import Simulation
from rsal.interfaces.position2d import Position2d
from rsal.robot import ExploreRobot, Robot, RobotError

from .messages import BLOB, BlobReport
from .messages import check_number as _number

__all__ = ["ExploreAgent"]

log = logging.getLogger(__name__)


class _Explorer(ExploreRobot):
    """An ExploreRobot whose map pose comes from its localizer: ``localized``, the localizer's
    position2d (amcl's position2d:2: the estimate moved on by odometry at the odometry's rate), else
    the localize device's own estimate (only as fresh as the filter's last update, every 0.2 m or
    30 degrees: a blob 3 m away seen 30 degrees off would land 1.5 m astray). With a localizer and
    no estimate yet the pose is unknown: no blob is placed in the odometry's frame. Without a
    localizer, ``truth`` set to the simulation device makes it read its true pose each cycle
    (thesis 3.6.2.2: a robot aware of its simulation), else the odometry is used."""

    truth: Simulation | None = None
    _truth_pose: Position | None = None
    localized: Position2d | None = None

    @property
    def position(self) -> Position | None:
        if self.localize is not None:
            if self.localized is not None and self.localized.latest is not None:
                return self.localized.position
            return getattr(self.localize, "position", None)
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


@agent_class("ExploreAgent")
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
        base = [d for d in devices if d.interface == "position2d" and d.index == self.index]
        if not base:
            raise RobotError(f"robot {self.robot!r}: no position2d:{self.index} device (its base) yet")
        rest = [d for d in devices if d.interface != "position2d"]
        robot = _Explorer(
            base + rest, name=self.robot, period=self.period, laser=self.laser, merge_dist=self.merge_dist
        )
        if robot.localize is not None:  # the localizer's own position2d (frame map), as NavRobot finds it
            for d in devices:
                if d.interface != "position2d" or d is base[0]:
                    continue
                try:
                    if d.describe(timeout=5.0).geometry.get("frame") == "map":
                        robot.localized = d
                        break
                except Exception as e:  # a silent device is simply not used
                    log.debug("%s: no describe: %s", d.addr, e)
        return robot

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
