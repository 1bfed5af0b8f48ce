"""The per-host robot hub: many robot agents of one agent host sharing one control loop.

The thesis's Jadex platform ran one thread per robot (the 100 ms cycle of 3.6.2.2) and one
subscription per agent; with a hundred robots on one host (the Swarm scenario, thesis 4.2.3) that is
a hundred threads contending for the GIL and a hundred decodings of every broadcast. A
:class:`RobotHub` is what the robot agents of one :class:`agents.runtime.AgentHost` share instead:

- one :class:`rsal.client.Fabric` on the host's session with one DeviceNode that finds every robot's
  devices (``templates``), its device callbacks run on Zenoh's network threads
  (``direct_callbacks``), not on a Python thread per subscription;
- one control loop on the host's asyncio loop that runs every added robot's ``update()`` in turn, in
  slices of :attr:`RobotHub.slice_size` robots with the loop served in between, so no message waits
  behind a whole cycle (:meth:`add_robot`, :meth:`remove_robot`);
- one ``send_position`` subscription (:meth:`listen`) whose messages are decoded once, put once on
  the host's blackboard :attr:`RobotHub.board` (every agent of the host receives the same messages)
  and handed to the listeners once per message, on the loop (SPADE's local delivery short-cut).

Use it from an agent's ``created()``::

    hub = RobotHub.attach(self._require_host(), self, period=self.period)
    hub.listen(my_listener)                    # optional: fn(hub, msg, now) once per message
    robot = await asyncio.to_thread(build, hub.node)   # find devices through the shared node
    hub.add_robot(self.robot, robot)           # its update() now runs in the shared loop

and in ``killed()``: ``hub.remove_robot(self.robot)`` then ``hub.detach(self)``; the last agent to
detach closes the hub. The robot's own thread is never started (do not call ``robot.start()``).
:attr:`cycles`, :attr:`overruns`, :attr:`max_cycle_s` and :meth:`load` tell how the loop keeps up.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from rsal.client import Fabric
from rsal.clock import clock
from rsal.data import Board, BoardObject, Position
from rsal.robot import Robot

from .runtime import Agent, AgentHost
from .services import Message, SendPosition, Subscription

__all__ = ["DEFAULT_TEMPLATES", "Listener", "RobotHub"]

log = logging.getLogger(__name__)

#: the devices a hub's DeviceNode follows unless told otherwise: bases, rangers, the simulation
DEFAULT_TEMPLATES = ("*:position2d:0", "*:sonar:0", "*:laser:0", "*:simulation:0")

#: a ``send_position`` listener: called once per message with the hub, the message and its receive
#: wall time (``time.time()``, comparable with the message's own ``time``), on the host's loop
Listener = Callable[["RobotHub", Message, float], None]


class RobotHub:
    """What the robot agents of one host share: a Fabric with one DeviceNode, one control loop
    running every robot's cycle, one ``send_position`` subscription fanned out on the loop."""

    _hubs: dict[int, RobotHub] = {}

    def __init__(self, host: AgentHost, period: float, templates: tuple[str, ...] = DEFAULT_TEMPLATES):
        self.host = host
        self.period = period
        self.fabric = Fabric(host.session, own_session=False, direct_callbacks=True)  # no thread per device
        self.node = self.fabric.node(*templates)
        self.agents: dict[str, Agent] = {}
        self.robots: dict[str, Robot] = {}
        #: the latest pose of every robot, shared by the host's agents (they all receive the same messages)
        self.board = Board()
        self.board_timeout = 5.0
        self.slice_size = 10
        self._task: asyncio.Task | None = None
        self._sub: Subscription | None = None
        self._listeners: list[Listener] = []
        self.cycles = 0
        self.overruns = 0
        self.busy_s = 0.0
        self.max_cycle_s = 0.0

    @classmethod
    def attach(cls, host: AgentHost, agent: Agent, *, period: float, board_timeout: float = 5.0) -> RobotHub:
        """The hub of ``host`` (made on first use with the control ``period`` in seconds), with
        ``agent`` attached; a pose stays on the board for the longest ``board_timeout`` asked for."""
        hub = cls._hubs.get(id(host))
        if hub is None or hub.host is not host:
            hub = cls._hubs[id(host)] = cls(host, period)
        hub.agents[agent.id] = agent
        hub.board_timeout = max(hub.board_timeout, board_timeout)
        return hub

    def listen(self, listener: Listener | None = None) -> None:
        """Subscribe to ``send_position`` once for all agents of the host (the board fills from then
        on) and call ``listener`` once per message (a listener given twice is called once)."""
        if listener is not None and listener not in self._listeners:
            self._listeners.append(listener)
        if self._sub is None:
            self._sub = self.host.services.subscribe(SendPosition.SERVICE, self._on_position, owner="robot-hub")

    def _on_position(self, msg: Message) -> None:  # the host's loop
        now = time.time()
        b = msg.body
        pose = Position(b.x, b.y, b.yaw)
        self.board.put(b.robot, BoardObject(topic="position", position=pose, timeout=self.board_timeout))
        for fn in self._listeners:
            fn(self, msg, now)

    def add_robot(self, name: str, robot: Robot) -> None:
        """Run ``robot.update()`` in the shared control loop from now on (the loop starts with the first)."""
        self.robots[name] = robot
        if self._task is None:
            self._task = self.host.spawn(self._control(), "robot hub control loop")

    def remove_robot(self, name: str) -> Robot | None:
        """Take the robot out of the loop; returns it (to stop its motors) or None."""
        return self.robots.pop(name, None)

    async def _control(self) -> None:
        """Every robot's 100 ms behaviour cycle (thesis 3.6.2.2), in turn, on the host's loop: in
        slices of :attr:`slice_size` robots with the loop served in between, so that no message waits
        behind a whole cycle, and with no thread per robot (nor the GIL hand-overs between them)."""
        loop = asyncio.get_running_loop()
        next_t = clock().now()  # the cycle counts the process's clock; its busy figures wall time
        while True:
            start = loop.time()
            busy = 0.0
            robots = list(self.robots.values())
            for k in range(0, len(robots), self.slice_size):
                t0 = time.perf_counter()
                for r in robots[k : k + self.slice_size]:
                    if r.name not in self.robots:
                        continue  # removed meanwhile
                    try:
                        r.update()
                        r.updates += 1
                    except Exception:
                        log.exception("%s: update failed", r.name)
                busy += time.perf_counter() - t0
                await asyncio.sleep(0)
            self.cycles += 1
            self.busy_s += busy  # the robots' updates only, not the messages served in between
            self.max_cycle_s = max(self.max_cycle_s, loop.time() - start)
            next_t += self.period
            now = clock().now()
            if next_t < now:
                self.overruns += 1
                next_t = now
            await clock().asleep_until(next_t)

    def detach(self, agent: Agent) -> None:
        """Detach ``agent``; the last one closes the hub (loop, subscription, node, fabric)."""
        self.agents.pop(agent.id, None)
        if self.agents:
            return
        if self._task is not None:
            self._task.cancel()
        if self._sub is not None:
            self._sub.close()
        self.node.close()
        self.fabric.close()
        if RobotHub._hubs.get(id(self.host)) is self:
            del RobotHub._hubs[id(self.host)]

    def load(self) -> float:
        """Share of the control period the control loop was busy (1.0 = saturated)."""
        return self.busy_s / (self.cycles * self.period) if self.cycles else 0.0
