"""Ready-made agent classes that ``rsal agent CLASS`` starts (thesis 3.5, 3.6.1, 4.2.1).

Each class controls one robot: it finds the robot's devices through a DeviceNode (thesis 3.6.2.1),
builds a :class:`rsal.robot.Pioneer` from them (the laser on or off, the thesis's "Laser" argument
of 3.5), lets it wall-follow with the subsumption behaviour (3.6.2.4) and publishes the robot's pose
on the ``send_position`` service (3.6.1, fig. 3.10) every ``report_every`` seconds.

Device discovery and ``describe`` block; they run in a worker thread with ``asyncio.to_thread`` so
the host's loop keeps serving its other agents. The robot's own 100 ms control cycle runs on the
robot's thread (3.6.2.2); the agent's steps only read its pose and publish.

:data:`AGENT_CLASSES` names the classes the command line knows.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time

from rsal.client import Fabric
from rsal.robot import Pioneer, RobotError, robot_devices

from .runtime import Agent
from .services import SendPosition

__all__ = ["AGENT_CLASSES", "EscapeAgent", "RobotAgent", "WallfollowAgent"]

log = logging.getLogger(__name__)


class RobotAgent(Agent):
    """An agent that drives one Pioneer (thesis 3.6.1 with 3.6.2.2): the robot is found and built
    in :meth:`find_robot` (called by ``created()`` unless done before), started in ``created()`` and
    stopped in ``killed()``. Subclasses set the robot's behaviour in :meth:`configure`."""

    capabilities = ("send_position",)

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str,
        period: float = 0.1,
        laser: bool = True,
        report_every: float = 1.0,
        startup_timeout: float = 30.0,
    ):
        if not robot:
            raise ValueError(f"agent {agent_id}: a robot id is required")
        super().__init__(agent_id, period=period, robot=robot)
        self.laser = bool(laser)
        self.report_every = float(report_every)
        self.startup_timeout = float(startup_timeout)
        self.pioneer: Pioneer | None = None
        self.fabric: Fabric | None = None
        self.sent = 0  # send_position messages published
        self._next_report = 0.0
        self._abort = threading.Event()

    # ------------------------------------------------------------------ robot
    async def find_robot(self, fabric: Fabric) -> Pioneer:
        """Find the robot's devices and build its Pioneer, off the loop. Raises :class:`TimeoutError`
        when its devices (position2d and the rangers it needs) do not appear within
        ``startup_timeout`` seconds, or :class:`RobotError` when they cannot make a robot."""
        self.fabric = fabric
        self.pioneer = await asyncio.to_thread(self._build, fabric)
        return self.pioneer

    def abort(self) -> None:
        """Make a running :meth:`find_robot` give up soon with :class:`InterruptedError`."""
        self._abort.set()

    def _build(self, fabric: Fabric) -> Pioneer:  # a worker thread
        name = self.robot
        deadline = time.monotonic() + self.startup_timeout
        node = fabric.node(f"{name}:*:*")
        while True:  # in short slices, so that abort() is seen
            if self._abort.is_set():
                raise InterruptedError(f"robot {name!r}: the search for its devices was aborted")
            try:
                robot_devices(node, name, timeout=max(0.01, min(0.2, deadline - time.monotonic())))
                break
            except TimeoutError:
                if time.monotonic() >= deadline:
                    raise TimeoutError(
                        f"robot {name!r}: no position2d device appeared within {self.startup_timeout:g} s "
                        "(is its device server running and reachable?)"
                    ) from None
        # Liveliness may announce the rangers a moment after the position2d: retry until they are in.
        while True:
            devs = [node.device(a) for a in node.search(node=name)]
            try:
                robot = Pioneer(devs, name=name, period=self.period, laser=self.laser)
                break
            except RobotError:
                if time.monotonic() >= deadline or self._abort.is_set():
                    raise
                node.wait_for(f"{name}:*:*", len(devs) + 1, max(0.05, min(0.5, deadline - time.monotonic())))
        try:
            robot.position2d.wait_for_data(max(0.1, deadline - time.monotonic()))
        except TimeoutError:
            raise TimeoutError(
                f"robot {name!r}: its position2d sent no data within {self.startup_timeout:g} s"
            ) from None
        return robot

    def configure(self, robot: Pioneer) -> None:
        """Set the robot's behaviour before it starts (override)."""

    def pose_message(self) -> SendPosition | None:
        """The robot's current pose as a ``send_position`` body (``map`` frame when localized)."""
        r = self.pioneer
        if r is None:
            return None
        pose = r.position
        if pose is None:
            return None
        frame = "map" if r.localize is not None and getattr(r.localize, "position", None) is not None else "odom"
        return SendPosition(self.robot, pose.x, pose.y, pose.yaw, frame)

    # ------------------------------------------------------------------ lifecycle
    async def created(self) -> None:
        if self.pioneer is None:
            await self.find_robot(Fabric(self._require_host().session, own_session=False))
        self.configure(self.pioneer)
        self.pioneer.start()
        self._next_report = asyncio.get_running_loop().time()

    async def step(self) -> None:
        now = asyncio.get_running_loop().time()
        if now < self._next_report:
            return
        self._next_report = max(self._next_report + self.report_every, now)
        msg = self.pose_message()
        if msg is not None:
            self.publish(SendPosition.SERVICE, msg)
            self.sent += 1

    async def killed(self) -> None:
        if self.pioneer is not None:
            await asyncio.to_thread(self.pioneer.shutdown)  # joins its thread, then stops the motors
        if self.fabric is not None:
            self.fabric.close()  # the proxies only; the host owns the session

    def status(self) -> str:
        """One progress line: pose, distance travelled, behaviour state, positions sent."""
        r = self.pioneer
        if r is None:
            return "no robot yet"
        p = r.position
        where = f"x={p.x:6.2f} y={p.y:6.2f} yaw={p.yaw:5.2f}" if p is not None else "no pose"
        return f"{where}  travelled {r.distance:5.1f} m  {r.state}  sent {self.sent} position(s)"


class WallfollowAgent(RobotAgent):
    """Wall-follows with its robot and publishes the robot's position every second (thesis 3.6.2.4)."""

    side = "left"

    def configure(self, robot: Pioneer) -> None:
        robot.set_wallfollow(True, side=self.side)


class EscapeAgent(WallfollowAgent):
    """The prey of the hunting scenario (thesis 4.2.1): wall-follows, keeping the wall on its right,
    and broadcasts its position so that hunters can chase it."""

    side = "right"
    capabilities = ("send_position", "prey")


AGENT_CLASSES: dict[str, type[RobotAgent]] = {c.__name__: c for c in (WallfollowAgent, EscapeAgent)}
