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
  behind a whole cycle (:meth:`add_robot`, :meth:`remove_robot`); or, where :attr:`RobotHub.batch`
  is set, one call for all the robots it takes (the swarm's vectorised step,
  :mod:`agents.scenarios.swarm.vector`) and ``update()`` for the others;
- one ``send_position`` subscription (:meth:`listen`) whose messages are decoded once, put once on
  the host's blackboard :attr:`RobotHub.board` (every agent of the host receives the same messages)
  and handed to the listeners once per message, on the loop (SPADE's local delivery short-cut);
- or, neighbourhood-scoped (:meth:`listen_near`, :mod:`agents.cells`): one
  :class:`agents.cellsub.CellSubscription` over the union of the cells within ``radius + margin``
  of each of its robots (a subscriber per cell, or one wildcard subscriber filtered by cell above
  ``wildcard_above`` cells), re-watched every ``refresh`` seconds from the robots' own poses; each agent's
  own cells are kept (:meth:`receivers` names the agents whose cells hold a message's cell), and the
  latest poses received are also kept as arrays (:meth:`near`: the poses within a distance, one
  numpy expression instead of a walk over the board).

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
import math
import time
from collections.abc import Callable

import numpy as np

from rsal.client import Fabric
from rsal.clock import clock
from rsal.data import Board, BoardObject, Position
from rsal.robot import Robot

from .cells import cell_of, cells_near, cells_near_many
from .cellsub import DEFAULT_WILDCARD_ABOVE, CellSubscription
from .runtime import Agent, AgentHost
from .services import Message, SendPosition, Subscription

__all__ = ["DEFAULT_TEMPLATES", "Listener", "RobotHub"]

log = logging.getLogger(__name__)

#: the devices a hub's DeviceNode follows unless told otherwise: bases, rangers, the simulation
DEFAULT_TEMPLATES = ("*:position2d:0", "*:sonar:0", "*:laser:0", "*:simulation:0")

#: a ``send_position`` listener: called once per message with the hub, the message and its receive
#: wall time (``time.time()``, comparable with the message's own ``time``), on the host's loop
Listener = Callable[["RobotHub", Message, float], None]


def robot_xy(robot) -> tuple[float, float] | None:
    """A robot's latest ``(x, y)`` in its base's frame: its position2d's latest sample, or, for a
    robot without device proxies (a row of the simulator's crowd device), its ``position``."""
    pos = getattr(robot, "position2d", None)
    if pos is not None:
        m = pos.latest
        return None if m is None else (m.pose[0], m.pose[1])
    xy = getattr(robot, "xy", None)
    if xy is not None:
        return xy()
    p = robot.position
    return None if p is None else (p.x, p.y)


class RobotHub:
    """What the robot agents of one host share: a Fabric with one DeviceNode, one control loop
    running every robot's cycle, one ``send_position`` subscription fanned out on the loop."""

    _hubs: dict[int, RobotHub] = {}
    #: the neighbourhood subscription gets the host's own agents' broadcasts in process
    #: (agents.cellsub, ``loopback``); False: through Zenoh like any other
    loopback = True

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
        # neighbourhood scope (listen_near): radius, cell size, margin (m), refresh period (s)
        self.radius = 0.0
        self.cell_size = 0.0
        self.margin = 0.0
        self.refresh = 0.5
        self._cells: CellSubscription | None = None
        self._watch_task: asyncio.Task | None = None
        self.agent_cells: dict[str, frozenset[str]] = {}  # agent id -> the cells it listens to
        #: agent id -> wall time its robot's cells were first watched: its reception began (its robot's
        #: pose may come later than the robot itself, and before it no cell of its is listened to)
        self.watched_since: dict[str, float] = {}
        self._by_cell: dict[str, list[Agent]] = {}  # cell -> the agents listening to it
        self.rewatches = 0
        #: called (no arguments) just before the agents' cells change: to account what came under the old ones
        self.before_rewatch: list[Callable[[], None]] = []
        # the latest pose received per robot, as arrays (near())
        self._index: dict[str, int] = {}
        self._xy = np.zeros((0, 2))
        self._stamp = np.zeros(0)
        self.cycles = 0
        self.overruns = 0
        self.busy_s = 0.0
        self.busy_cpu_s = 0.0  # CPU time of the robots' updates (the loop thread's), load-independent
        self.updates = 0  # robot updates run
        self.max_cycle_s = 0.0
        #: optional one-call step for many robots at once (e.g. the swarm's vectorised step):
        #: fn(robots) runs the cycle of those it takes and returns the others, which run their own update()
        self.batch: Callable[[list[Robot]], list[Robot]] | None = None

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
        if self._cells is not None:
            raise ValueError(
                "this host's agents listen in a neighbourhood; give all of them the same "
                "neighbourhood radius (0: all-to-all)"
            )
        if self._sub is None:
            self._sub = self.host.services.subscribe(SendPosition.SERVICE, self._on_position, owner="robot-hub")

    def listen_near(
        self,
        radius: float,
        cell_size: float,
        margin: float,
        refresh: float,
        listener: Listener | None = None,
        *,
        wildcard_above: int = DEFAULT_WILDCARD_ABOVE,
        bundle: bool = False,
    ) -> None:
        """Subscribe to ``send_position`` in the cells (:mod:`agents.cells`, squares of ``cell_size``
        m) within ``radius + margin`` m of any of the host's robots, re-watched every ``refresh``
        seconds as they move, and call ``listener`` once per message. Every agent of the host that
        listens near shares one radius and cell size (the first one asked for). Above
        ``wildcard_above`` cells (0: never) the hub holds one subscriber on every cell and drops the
        others' messages itself (:mod:`agents.cellsub`). The hub always takes other hosts' bundles
        (:mod:`agents.services`); ``bundle``: the host's own broadcasts go out bundled too."""
        if not (radius > 0 and cell_size > 0 and margin >= 0 and refresh > 0):
            raise ValueError(
                f"neighbourhood radius {radius!r}, cell size {cell_size!r}, margin {margin!r} and refresh "
                f"{refresh!r} must be positive (margin may be 0)"
            )
        if self._sub is not None:
            raise ValueError(
                "this host's agents already listen to every send_position (all-to-all); give all "
                "of them the same neighbourhood radius"
            )
        if self._cells is not None and (radius, cell_size) != (self.radius, self.cell_size):
            raise ValueError(
                f"this host's agents listen within {self.radius:g} m in cells of {self.cell_size:g} m; give all of "
                f"them the same neighbourhood and cell_size (asked: {radius:g} m, {cell_size:g} m)"
            )
        if listener is not None and listener not in self._listeners:
            self._listeners.append(listener)
        if self._cells is None:
            self.radius, self.cell_size = float(radius), float(cell_size)
            self.margin, self.refresh = float(margin), float(refresh)
            self._cells = self.host.services.subscribe_cells(
                SendPosition.SERVICE,
                self._on_position,
                owner="robot-hub",
                wildcard_above=wildcard_above,
                loopback=self.loopback,
                bundles=True,
            )
            self._watch_task = self.host.spawn(self._rewatch_loop(), "robot hub cell watch")
        else:
            self.margin = max(self.margin, float(margin))
            self.refresh = min(self.refresh, float(refresh))
        if bundle:
            self.host.services.bundle(SendPosition.SERVICE)

    def rewatch(self, hooks: bool = True) -> set[str]:
        """Re-compute every agent's cells from its robot's latest pose and watch their union (new
        cells are declared before the old ones go); returns the union. ``hooks``: run
        :attr:`before_rewatch` first (the periodic re-watch runs them in turns of their own)."""
        if hooks:
            for fn in self.before_rewatch:
                fn()
        reach = self.radius + self.margin
        moved, xy = [], []
        for aid, a in self.agents.items():
            robot = self.robots.get(getattr(a, "robot", ""))
            p = robot_xy(robot) if robot is not None else None
            if p is not None:
                moved.append((aid, a))
                xy.append(p)
        rows, cell, names = cells_near_many(np.array(xy, dtype=float).reshape(-1, 2), reach, self.cell_size)
        mine: list[list[str]] = [[] for _ in moved]
        by_cell: dict[str, list[Agent]] = {}
        bounds = np.searchsorted(cell, np.arange(len(names) + 1)).tolist()  # each cell's pairs
        for name, lo, hi in zip(names, bounds[:-1], bounds[1:], strict=True):  # one pass per cell, not per pair
            idx = rows[lo:hi].tolist()
            by_cell[name] = [moved[i][1] for i in idx]
            for i in idx:
                mine[i].append(name)
        for (aid, _a), cells in zip(moved, mine, strict=True):
            self.agent_cells[aid] = frozenset(cells)
        union: set[str] = set(names)
        placed = {aid for aid, _a in moved}
        for aid, a in self.agents.items():  # no pose (yet): the cells it had
            if aid not in placed:
                cells = self.agent_cells.get(aid, frozenset())
                for c in cells:
                    by_cell.setdefault(c, []).append(a)
                union |= cells
        self._by_cell = by_cell
        if self._cells is not None:
            self._cells.watch(union)
        now = time.time()
        for aid, _a in moved:
            self.watched_since.setdefault(aid, now)
        self.rewatches += 1
        return union

    def _watch_new(self, robot: str) -> None:
        """Watch the cells of the agents of a robot just added, at once (the whole set is re-computed
        at the next :meth:`rewatch`; one robot at a time keeps a crowd's start-up linear)."""
        xy = robot_xy(self.robots[robot])
        if xy is None or self._cells is None:
            return
        cells = frozenset(cells_near(xy[0], xy[1], self.radius + self.margin, self.cell_size))
        for fn in self.before_rewatch:
            fn()
        for aid, a in self.agents.items():
            if getattr(a, "robot", None) == robot:
                self.agent_cells[aid] = cells
                for c in cells:
                    self._by_cell.setdefault(c, []).append(a)
        if not cells <= self._cells.cells:
            self._cells.watch(self._cells.cells | cells)
        now = time.time()
        for aid, a in self.agents.items():
            if getattr(a, "robot", None) == robot:
                self.watched_since.setdefault(aid, now)

    async def _rewatch_loop(self) -> None:
        next_t = clock().now()
        while True:
            # Each hook (a 500-agent host: the ledger's flush, the batched headings) and the cells
            # in a turn of the loop's own, so the messages waiting meanwhile are served between
            # them: one block of the three held a host's receiving back by 22-35 ms every period.
            # What arrives between the flush and the new cells is accounted at the next flush, by
            # cells that differ from these only beyond the radius (the margin covers the motion).
            for fn in tuple(self.before_rewatch):
                fn()
                await asyncio.sleep(0)
            self.rewatch(hooks=False)
            next_t = max(next_t + self.refresh, clock().now())
            await clock().asleep_until(next_t)

    def agents_in(self, cell: str) -> list[Agent]:
        """The agents of the host whose cells (as last watched) hold ``cell``."""
        return self._by_cell.get(cell, [])

    def receivers(self, msg: Message) -> list[Agent]:
        """The agents of the host whose cells hold the cell ``msg`` was published in (its pose's)."""
        b = msg.body
        return self._by_cell.get(cell_of(b.x, b.y, self.cell_size), [])

    def near(self, x: float, y: float, radius: float, exclude: str = "") -> np.ndarray:
        """(k, 2) positions of the robots received within ``radius`` m of (x, y) and newer than the
        board's timeout, without robot ``exclude``."""
        if not len(self._stamp):
            return np.zeros((0, 2))
        d = self._xy - (x, y)
        ok = np.einsum("ij,ij->i", d, d) <= radius * radius
        ok &= self._stamp >= time.monotonic() - self.board_timeout
        i = self._index.get(exclude)
        if i is not None:
            ok[i] = False
        return self._xy[ok]

    def received_positions(self) -> tuple[np.ndarray, dict[str, int]]:
        """The latest position received of every robot as an (m, 2) array (rows older than the
        board's timeout are NaN) and the row of each robot id."""
        xy = self._xy[: len(self._index)].copy()
        xy[self._stamp[: len(self._index)] < time.monotonic() - self.board_timeout] = np.nan
        return xy, self._index

    def _remember(self, robot: str, x: float, y: float) -> None:
        i = self._index.get(robot)
        if i is None:
            i = self._index[robot] = len(self._index)
            if i >= len(self._stamp):
                grow = max(64, 2 * len(self._stamp))
                self._xy = np.concatenate([self._xy, np.zeros((grow, 2))])
                self._stamp = np.concatenate([self._stamp, np.full(grow, -math.inf)])
        self._xy[i] = (x, y)
        self._stamp[i] = time.monotonic()

    def _on_position(self, msg: Message) -> None:  # the host's loop
        now = time.time()
        b = msg.body
        pose = Position(b.x, b.y, b.yaw)
        self.board.put(b.robot, BoardObject(topic="position", position=pose, timeout=self.board_timeout))
        self._remember(b.robot, b.x, b.y)
        for fn in self._listeners:
            fn(self, msg, now)

    def add_robot(self, name: str, robot: Robot) -> None:
        """Run ``robot.update()`` in the shared control loop from now on (the loop starts with the first)."""
        self.robots[name] = robot
        if self._cells is not None:
            self._watch_new(name)
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
            if self.batch is not None and robots:
                t0 = time.perf_counter()
                c0 = time.thread_time()
                try:
                    rest = self.batch(robots)
                except Exception:
                    log.exception("the batched robot step failed; the robots run their own cycles")
                    self.batch, rest = None, robots
                taken = {id(r) for r in rest}
                for r in robots:
                    if id(r) not in taken:
                        r.updates += 1
                self.updates += len(robots) - len(rest)
                busy += time.perf_counter() - t0
                self.busy_cpu_s += time.thread_time() - c0
                robots = rest
                await asyncio.sleep(0)
            for k in range(0, len(robots), self.slice_size):
                t0 = time.perf_counter()
                c0 = time.thread_time()
                for r in robots[k : k + self.slice_size]:
                    if r.name not in self.robots:
                        continue  # removed meanwhile
                    try:
                        r.update()
                        r.updates += 1
                    except Exception:
                        log.exception("%s: update failed", r.name)
                busy += time.perf_counter() - t0
                self.busy_cpu_s += time.thread_time() - c0
                self.updates += min(self.slice_size, len(robots) - k)
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
        self.agent_cells.pop(agent.id, None)
        self.watched_since.pop(agent.id, None)
        if self.agents:
            return
        if self._task is not None:
            self._task.cancel()
        if self._sub is not None:
            self._sub.close()
        if self._watch_task is not None:
            self._watch_task.cancel()
        if self._cells is not None:
            self._cells.close()
        self.node.close()
        self.fabric.close()
        if RobotHub._hubs.get(id(self.host)) is self:
            del RobotHub._hubs[id(self.host)]

    def load(self) -> float:
        """Share of the control period the control loop was busy (1.0 = saturated)."""
        return self.busy_s / (self.cycles * self.period) if self.cycles else 0.0
