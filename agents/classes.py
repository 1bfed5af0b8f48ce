"""Ready-made agent classes that ``rsal agent CLASS`` starts (thesis 3.5, 3.6.1, 4.2.1).

Each class controls one robot: it finds the robot's devices through a DeviceNode (thesis 3.6.2.1),
builds a :class:`rsal.robot.Pioneer` from them (the laser on or off, the thesis's "Laser" argument
of 3.5), lets it wall-follow with the subsumption behaviour (3.6.2.4) and publishes the robot's pose
on the ``send_position`` service (3.6.1, fig. 3.10) every ``report_every`` seconds.

A robot without a localize device reports in its odometry frame, which starts at (0, 0, 0) where the
robot was created; given a start ``pose`` ([x, y, degrees], thesis 3.5) or ``simulation`` true (the
true start pose read from the simulation device), the agent sets the odometry to it and reports in
the ``map`` frame. Subclasses that drive another kind of robot override ``make_robot`` and ``needs``
(e.g. :class:`agents.navigation.NavAgent`); scenarios subclass these (the prey of Hunt and Prey,
:class:`agents.scenarios.hunt.EscapeAgent`, is a :class:`WallfollowAgent`).

Device discovery and ``describe`` block; they run in a worker thread with ``asyncio.to_thread`` so
the host's loop keeps serving its other agents. The robot's own 100 ms control cycle runs on the
robot's thread (3.6.2.2); the agent's steps only read its pose and publish.

:func:`agents.registry.agent_class` registers the classes that scenario files and ``rsal agent`` name.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Sequence

from rsal.client import Fabric
from rsal.clock import clock
from rsal.data import Position
from rsal.msgs import RpcError
from rsal.robot import Pioneer, Robot, RobotError, robot_devices

from .registry import agent_class
from .runtime import Agent
from .services import SendPosition

__all__ = ["RobotAgent", "WallfollowAgent"]

log = logging.getLogger(__name__)


class RobotAgent(Agent):
    """An agent that drives one Pioneer (thesis 3.6.1 with 3.6.2.2): the robot is found and built
    in :meth:`find_robot` (called by ``created()`` unless done before), started in ``created()`` and
    stopped in ``killed()``. Subclasses set the robot's behaviour in :meth:`configure`; one that
    drives another kind of robot overrides :meth:`make_robot` and names the device interfaces it
    needs besides position2d and a ranger in ``needs``."""

    capabilities = ("send_position",)
    #: device interfaces the robot needs besides position2d and a ranger (e.g. ``("planner",)``)
    needs: tuple[str, ...] = ()

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str,
        period: float = 0.1,
        laser: bool = True,
        report_every: float = 1.0,
        startup_timeout: float = 30.0,
        simulation: bool = False,
        pose: Sequence[float] | None = None,
        index: int = 0,
    ):
        if not robot:
            raise ValueError(f"agent {agent_id}: a robot id is required")
        super().__init__(agent_id, period=period, robot=robot)
        self.laser = bool(laser)
        self.report_every = float(report_every)
        self.startup_timeout = float(startup_timeout)
        self.simulation = bool(simulation)
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise ValueError(f"agent {agent_id}: index {index!r} must be a device index (an integer >= 0)")
        self.index = index  # the robot's base: position2d:<index> (thesis 3.5's device index)
        try:
            self.start_pose = Position.from_degrees(*pose) if pose is not None else None
        except (TypeError, ValueError):
            raise ValueError(f"agent {agent_id}: pose {pose!r} must be [x, y, degrees]") from None
        self.frame = "odom"  # of the odometry; "map" once anchored to pose or the simulation's true pose
        self.pioneer: Robot | None = None  # the robot built from the devices (a Pioneer unless overridden)
        self.fabric: Fabric | None = None
        self.sent = 0  # send_position messages published
        self._next_report = 0.0
        self._abort = threading.Event()

    # ------------------------------------------------------------------ robot
    async def find_robot(self, fabric: Fabric) -> Robot:
        """Find the robot's devices and build its Pioneer, off the loop. Raises :class:`TimeoutError`
        when its devices (position2d and the rangers it needs) do not appear within
        ``startup_timeout`` seconds, or :class:`RobotError` when they cannot make a robot."""
        self.fabric = fabric
        self.pioneer = await asyncio.to_thread(self._build, fabric)
        return self.pioneer

    def abort(self) -> None:
        """Make a running :meth:`find_robot` give up soon with :class:`InterruptedError`."""
        self._abort.set()

    def make_robot(self, devices: list) -> Robot:
        """Build the robot from its device proxies (a worker thread); raise :class:`RobotError` while
        a device it needs is missing (the search goes on until ``startup_timeout``)."""
        base = [d for d in devices if d.interface == "position2d" and d.index == self.index]
        if not base:
            raise RobotError(f"robot {self.robot!r}: no position2d:{self.index} device (its base) yet")
        rest = [d for d in devices if d.interface != "position2d"]
        return Pioneer(base + rest, name=self.robot, period=self.period, laser=self.laser)

    def _build(self, fabric: Fabric) -> Robot:  # a worker thread
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
                have = {d.interface for d in devs}
                missing = [i for i in self.needs if i not in have]
                if missing:
                    raise RobotError(
                        f"robot {name!r}: no {' or '.join(missing)} device appeared within {self.startup_timeout:g} s "
                        f"(a {type(self).__name__} needs them; e.g. 'rsal sim WORLD --nav vfh')"
                    )
                robot = self.make_robot(devs)
                break
            except RobotError:
                if time.monotonic() >= deadline or self._abort.is_set():
                    raise
                try:  # for one more device, briefly; the loop decides when to give up
                    node.wait_for(f"{name}:*:*", len(devs) + 1, max(0.05, min(0.5, deadline - time.monotonic())))
                except TimeoutError:
                    pass
        try:
            robot.position2d.wait_for_data(max(0.1, deadline - time.monotonic()))
        except TimeoutError:
            raise TimeoutError(
                f"robot {name!r}: its position2d sent no data within {self.startup_timeout:g} s"
            ) from None
        if robot.localize is None:
            self._anchor(fabric, robot, deadline)
        return robot

    def _anchor(self, fabric: Fabric, robot: Robot, deadline: float) -> None:  # a worker thread
        """Set the odometry to ``pose`` or, with ``simulation``, to the robot's true pose in the
        simulation, so that the agent reports in the map frame (thesis 3.5's initial pose)."""
        start = self.start_pose
        try:
            if start is None and self.simulation:
                sn = fabric.node("*:simulation:0")
                try:
                    found = sn.wait_for("*:simulation:0", 1, max(0.1, deadline - time.monotonic()))
                except TimeoutError:
                    raise TimeoutError(
                        f"robot {self.robot!r}: no simulation device appeared within {self.startup_timeout:g} s "
                        "(simulation=true needs a simulator; give the start pose as pose: [x, y, degrees] instead)"
                    ) from None
                start = sn.device(found[0]).get_pose(self.robot)
            if start is not None:
                n = robot.position2d.count
                robot.position2d.set_odometry(start)
                robot.position2d.wait_for_data(max(0.5, deadline - time.monotonic()), newer_than=n + 1)
                self.frame = "map"
        except RpcError as e:
            raise RobotError(f"robot {self.robot!r}: cannot set its start pose: {e}") from None

    def configure(self, robot: Robot) -> None:
        """Set the robot's behaviour before it starts (override)."""

    def pose_message(self) -> SendPosition | None:
        """The robot's current pose as a ``send_position`` body (``map`` frame when localized)."""
        r = self.pioneer
        if r is None:
            return None
        pose = r.position
        if pose is None:
            return None
        localized = r.localize is not None and getattr(r.localize, "position", None) is not None
        frame = "map" if localized else self.frame
        return SendPosition(self.robot, pose.x, pose.y, pose.yaw, frame)

    # ------------------------------------------------------------------ lifecycle
    async def created(self) -> None:
        if self.pioneer is None:
            await self.find_robot(Fabric(self._require_host().session, own_session=False))
        self.configure(self.pioneer)
        self.pioneer.start()
        self._next_report = clock().now()

    async def step(self) -> None:
        now = clock().now()  # report_every counts the process's clock (simulated seconds in simulation)
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


@agent_class("WallfollowAgent")
class WallfollowAgent(RobotAgent):
    """Wall-follows with its robot and publishes the robot's position every second (thesis 3.6.2.4)."""

    side = "left"

    def configure(self, robot: Pioneer) -> None:
        robot.set_wallfollow(True, side=self.side)


def __getattr__(name: str):
    # EscapeAgent moved to its scenario; ``agents.classes:EscapeAgent`` in scenario files and old
    # imports still find it (imported only when asked for, so this module imports no scenario).
    if name == "EscapeAgent":
        from agents.scenarios.hunt import EscapeAgent

        return EscapeAgent
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
