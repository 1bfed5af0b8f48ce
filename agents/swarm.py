"""The Swarm scenario (thesis 4.2.3): a crowd of wall-following robots that broadcast their positions.

"It includes 100 robots that spread out from their closely spaced starting positions and explore the
map by wall-following. Low-level obstacle avoidance guides each robot to avoid collisions. In order
to stress the MAS layer, each robot subscribes to the SendPositionService, broadcasts its own
position and reads other position values."

:class:`SwarmAgent` drives one Pioneer with the subsumption behaviour of 3.6.2.4 (wall-following,
avoid, escape), publishes its pose on ``send_position`` every ``report_every`` seconds (2 Hz by
default) and keeps every other robot's latest pose on a :class:`rsal.data.Board`. It measures what
it receives: each broadcast's conversation id is ``p<sequence number>``, so a receiver counts the
gaps per sender (delivery ratio), and the receive wall time minus the message's ``time`` is the
latency (a log-scale histogram). It publishes these figures on the ``swarm_stats`` service.
Periods (control cycle, broadcasts, the monitor's samples) count the process's clock
(:mod:`rsal.clock`: simulated seconds under a simulator's clock); latency stays wall time.

Agents of one host share the costly parts (the scaling the thesis's Jadex platform did not have):
one Fabric and one DeviceNode to find all robots, one control loop on the host's asyncio loop that
runs every robot's behaviour cycle in turn (in slices, serving messages in between) instead of a
thread per robot, and one Zenoh subscriber on ``send_position`` whose messages are decoded once, put
once on the host's blackboard (all its agents receive the same messages) and handed to each agent
on the loop for its own accounting (SPADE's local delivery short-cut). ``shared=False`` gives an
agent its own subscription and blackboard instead. The shared Fabric runs its device callbacks on
Zenoh's network threads (``direct_callbacks``), not on a Python thread per subscription: with 200
robots that is 800 fewer threads contending for the GIL with the control loop.

:class:`SwarmMonitor` judges a run from the simulation's ground truth: every ``sample_every``
seconds it asks the ``simulation`` device for every robot's true pose, checks that no two robots
overlap, follows the spread (mean nearest-neighbour distance), merges the agents' ``swarm_stats``
and after ``duration`` simulated seconds publishes the verdict as an ``outcome``.

:func:`crowd_world` writes the Stage world of such a crowd (``maps/swarm.world`` is its output for
100 robots).
"""

from __future__ import annotations

import asyncio
import logging
import math
import random
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rsal.behaviours import SECTOR_COUNT, Sectors, Subsumption, beam_points, fuse
from rsal.client import HOLD_REFRESH, Fabric
from rsal.clock import clock
from rsal.data import Board, BoardObject, Position, normalize_angle
from rsal.msgs import RpcError
from rsal.robot import Pioneer, RobotError

from .classes import RobotAgent
from .runtime import Agent, AgentHost
from .services import Message, Outcome, SendPosition, Subscription

__all__ = [
    "LATENCY_EDGES",
    "STATS_SERVICE",
    "LatencyHistogram",
    "SwarmAgent",
    "SwarmMonitor",
    "crowd_world",
]

log = logging.getLogger(__name__)

STATS_SERVICE = "swarm_stats"

#: latency histogram bin edges in seconds: 10 µs .. 100 s, 10 bins per decade (bin i is [e_i, e_i+1))
LATENCY_EDGES = 10.0 ** (np.arange(71) / 10.0 - 5.0)
_NBINS = LATENCY_EDGES.size - 1


def latency_bin(latency: float) -> int:
    """The bin of :data:`LATENCY_EDGES` that ``latency`` (seconds) falls in (clamped)."""
    if latency <= 1e-5:
        return 0
    i = int((math.log10(latency) + 5.0) * 10.0)
    return i if i < _NBINS else _NBINS - 1


def sequence(conversation: str) -> int | None:
    """The sequence number of a swarm broadcast's conversation id ``p<n>``, else None."""
    if len(conversation) > 1 and conversation[0] == "p" and conversation[1:].isdigit():
        return int(conversation[1:])
    return None


class LatencyHistogram:
    """Counts of latencies in the bins of :data:`LATENCY_EDGES`, mergeable across agents."""

    def __init__(self, counts: Sequence[int] | None = None, *, max_s: float = 0.0, sum_s: float = 0.0):
        self.counts = np.zeros(_NBINS, dtype=np.int64) if counts is None else np.asarray(counts, dtype=np.int64)
        if self.counts.shape != (_NBINS,):
            raise ValueError(f"a latency histogram has {_NBINS} bins, got {self.counts.shape}")
        self.max_s = float(max_s)
        self.sum_s = float(sum_s)
        self._pending = [0] * _NBINS  # counts not yet in ``counts`` (a list is faster to bump)
        self._npending = 0

    def add(self, latency: float) -> None:
        self.add_bin(latency_bin(latency), latency)

    def add_bin(self, i: int, latency: float) -> None:
        """Count a latency whose bin :func:`latency_bin` gave (shared by the agents of a host)."""
        self._pending[i] += 1
        self._npending += 1
        if latency > self.max_s:
            self.max_s = latency
        self.sum_s += latency

    def _flush(self) -> None:
        if self._npending:
            self.counts += np.asarray(self._pending, dtype=np.int64)
            self._pending = [0] * _NBINS
            self._npending = 0

    def merge(self, other: LatencyHistogram) -> None:
        self._flush()
        other._flush()
        self.counts += other.counts
        self.max_s = max(self.max_s, other.max_s)
        self.sum_s += other.sum_s

    @property
    def n(self) -> int:
        self._flush()
        return int(self.counts.sum())

    def quantile(self, q: float) -> float:
        """The upper edge of the bin holding quantile ``q`` (seconds; an upper bound within 26 %)."""
        n = self.n
        if n == 0:
            return math.nan
        self._flush()
        i = int(np.searchsorted(np.cumsum(self.counts), q * n, side="left"))
        return min(float(LATENCY_EDGES[min(i, _NBINS - 1) + 1]), self.max_s)

    def to_dict(self) -> dict:
        self._flush()
        nz = np.nonzero(self.counts)[0]
        return {"bins": nz.tolist(), "counts": self.counts[nz].tolist(), "max": self.max_s, "sum": self.sum_s}

    @classmethod
    def from_dict(cls, d: dict) -> LatencyHistogram:
        h = cls(max_s=float(d.get("max", 0.0)), sum_s=float(d.get("sum", 0.0)))
        bins, counts = d.get("bins", []), d.get("counts", [])
        if len(bins) != len(counts):
            raise ValueError("latency histogram: 'bins' and 'counts' differ in length")
        for i, c in zip(bins, counts, strict=True):
            if not (isinstance(i, int) and 0 <= i < _NBINS and isinstance(c, int) and c >= 0):
                raise ValueError(f"latency histogram: bad bin {i!r} or count {c!r}")
            h.counts[i] += c
        return h


# ---------------------------------------------------------------------------- behaviour
class Disperse(Subsumption):
    """The subsumption behaviour of thesis 3.6.2.4 with one more layer for a crowd in open space.

    Plain wall-following curves towards its side while no wall is in sight, which in an open arena
    keeps a robot circling where it started. Here, while wall-following sees no wall, the robot
    instead steers to :attr:`heading` (radians, world frame; set from the neighbours' broadcast
    positions) or, without one, drives straight on, so the crowd spreads out "towards a wall"
    (thesis fig. 4.7); once a wall is in sight wall-following takes over. Escape and avoid still
    override it. :attr:`yaw` is the robot's current heading, set every cycle by its robot.
    """

    def __init__(self, params=None):
        super().__init__(params)
        self.heading: float | None = None
        self.yaw: float = 0.0

    def step(self, s: Sectors, now: float, stalled: bool = False) -> tuple[float, float]:
        v, w = super().step(s, now, stalled)
        if self.state != "wallfollow":
            return v, w
        p = self.p
        sign = 1.0 if p.side == "left" else -1.0
        side_d = s.min_between(60, 120) if sign > 0 else s.min_between(-120, -60)
        diag = s.min_between(30, 60) if sign > 0 else s.min_between(-60, -30)
        if min(side_d, diag) <= 2.5 * p.wall_dist:
            return v, w  # a wall to follow
        self.state = "disperse"
        if self.heading is None:
            return p.cruise_speed, 0.0
        err = normalize_angle(self.heading - self.yaw)
        w = max(-p.turn_rate, min(p.turn_rate, 1.5 * err))
        return p.cruise_speed * (1.0 if abs(err) < 0.8 else 0.4), w


class ListSectors(Sectors):
    """:class:`rsal.behaviours.Sectors` over a plain list: for a handful of beams, Python's own
    arithmetic beats numpy's per-call overhead (the behaviour reads a sector range 7 times a cycle)."""

    def __init__(self, dist: list[float]):
        self.dist = dist  # a list here, not an array

    def min_between(self, a0_deg: float, a1_deg: float) -> float:
        i0 = math.floor((a0_deg + _HALF_SECTOR) / _SECTOR)
        n = math.floor((a1_deg + _HALF_SECTOR) / _SECTOR) - i0 + 1
        v = self.dist
        if n >= SECTOR_COUNT:
            return min(v)
        i0 %= SECTOR_COUNT
        if i0 + n <= SECTOR_COUNT:
            return min(v[i0 : i0 + n])
        return min(min(v[i0:]), min(v[: i0 + n - SECTOR_COUNT]))


_SECTOR = 360.0 / SECTOR_COUNT
_HALF_SECTOR = _SECTOR / 2


def fuse_beams(beams: list[tuple[float, float, float, float]], ranges, range_max: float) -> list[float]:
    """:func:`rsal.behaviours.fuse` of :func:`~rsal.behaviours.beam_points` for few beams, in plain
    Python: ``beams`` are (x, y, cos yaw, sin yaw) of each beam's origin in the robot frame; a beam
    counts when its range is finite and below ``range_max`` (the nearest point per sector)."""
    d = [math.inf] * SECTOR_COUNT
    lim = range_max * 0.999
    for (bx, by, c, sn), r in zip(beams, ranges.tolist(), strict=False):
        if not r < lim:  # also NaN
            continue
        x, y = bx + r * c, by + r * sn
        i = math.floor((math.degrees(math.atan2(y, x)) + _HALF_SECTOR) / _SECTOR) % SECTOR_COUNT
        dist = math.hypot(x, y)
        if dist < d[i]:
            d[i] = dist
    return d


class SwarmPioneer(Pioneer):
    """A Pioneer with the :class:`Disperse` behaviour, its cycle made lean for a crowd: each ranger's
    beam geometry is computed once, and rangers of up to ``fast_beams`` beams (the sonar ring) are
    fused in plain Python (:func:`fuse_beams`, :class:`ListSectors`) instead of numpy. The behaviour
    and its outputs are those of :meth:`rsal.robot.Pioneer.update`."""

    fast_beams = 32

    def __init__(self, devices, **kw):
        super().__init__(devices, **kw)
        old = self.behaviour
        self.behaviour = Disperse(old.p)
        self._poses: dict = {}  # ranger address -> its beams' poses (fixed geometry, computed once)
        self._beams: dict = {}  # ranger address -> [(x, y, cos, sin)] for the plain-Python fusion
        self._last_xy: tuple[float, float] | None = None

    def _geometry(self, r, n: int):
        poses = self._poses.get(r.addr)
        if poses is None or len(poses) != n:
            poses = self._poses[r.addr] = r.sensor_poses()
            self._beams[r.addr] = [(x, y, math.cos(a), math.sin(a)) for x, y, a in poses.tolist()]
        return poses

    def obstacle_points(self) -> list[np.ndarray]:
        """As :meth:`Robot.obstacle_points`, with each ranger's beam poses computed once."""
        out = []
        for r in (self.lasers if self.laser_enabled else []) + self.sonars:
            m = r.latest
            if m is None or not r.alive:
                continue
            try:
                poses = self._geometry(r, len(m.ranges))
            except Exception as e:  # describe not answered yet
                log.debug("%s: no geometry yet: %s", r.addr, e)
                continue
            out.append(beam_points(poses, m.ranges, m.range_max or float(np.max(m.ranges))))
        return out

    def sectors(self) -> Sectors:
        """The fused sectors of the enabled rangers."""
        rangers = (self.lasers if self.laser_enabled else []) + self.sonars
        if any(r.latest is not None and len(r.latest.ranges) > self.fast_beams for r in rangers):
            return fuse(self.obstacle_points())
        d: list[float] | None = None
        for r in rangers:
            m = r.latest
            if m is None or not r.alive:
                continue
            try:
                self._geometry(r, len(m.ranges))
            except Exception as e:  # describe not answered yet
                log.debug("%s: no geometry yet: %s", r.addr, e)
                continue
            f = fuse_beams(self._beams[r.addr], m.ranges, m.range_max or float(np.max(m.ranges)))
            d = f if d is None else [min(a, b) for a, b in zip(d, f, strict=True)]
        return ListSectors(d if d is not None else [math.inf] * SECTOR_COUNT)

    def update(self) -> None:
        pos = self.position2d
        m = pos.latest
        if m is None or not pos.alive:
            return
        x, y, yaw = m.pose
        if self._last_xy is not None:
            self.distance += math.hypot(x - self._last_xy[0], y - self._last_xy[1])
        self._last_xy = (x, y)
        b = self.behaviour
        b.yaw = yaw
        before = b.state
        v, w = b.step(self.sectors(), clock().now(), bool(m.stall))
        if b.state != before:
            for fn in self._state_listeners:
                fn(b.state)
        cmd = (round(v, 3), round(w, 3))
        if cmd != self._last_cmd or cmd != (0.0, 0.0):  # re-sent while moving, a stop once
            pos.set_velocity(*cmd, hold=self.period > HOLD_REFRESH)  # see Pioneer.update
            self._last_cmd = cmd


def away_from(me: Position, others: Sequence[Position], radius: float) -> float | None:
    """The heading (rad) away from the neighbours within ``radius`` m, each pushing with 1/d;
    None when none is that close."""
    if not others:
        return None
    xy = np.array([(o.x, o.y) for o in others], dtype=float)
    d = np.array([me.x, me.y]) - xy
    r2 = np.einsum("ij,ij->i", d, d)
    near = (r2 < radius * radius) & (r2 > 1e-6)
    if not near.any():
        return None
    v = (d[near] / r2[near, None]).sum(axis=0)
    if not np.any(v):
        return None
    return math.atan2(v[1], v[0])


# ---------------------------------------------------------------------------- the per-host hub
class _Hub:
    """What the swarm agents of one host share: a Fabric with one DeviceNode, one control loop
    running every robot's behaviour cycle, one ``send_position`` subscription fanned out on the loop."""

    _hubs: dict[int, _Hub] = {}

    def __init__(self, host: AgentHost, period: float):
        self.host = host
        self.period = period
        self.fabric = Fabric(host.session, own_session=False, direct_callbacks=True)  # no thread per device
        self.node = self.fabric.node("*:position2d:0", "*:sonar:0", "*:laser:0", "*:simulation:0")
        self.agents: dict[str, SwarmAgent] = {}
        self.robots: dict[str, Pioneer] = {}
        #: the latest pose of every robot, shared by the host's agents (they all receive the same messages)
        self.board = Board()
        self.board_timeout = 5.0
        self.slice_size = 10
        self._task: asyncio.Task | None = None
        self._sub: Subscription | None = None
        self.cycles = 0
        self.overruns = 0
        self.busy_s = 0.0
        self.max_cycle_s = 0.0

    @classmethod
    def attach(cls, host: AgentHost, agent: SwarmAgent) -> _Hub:
        hub = cls._hubs.get(id(host))
        if hub is None or hub.host is not host:
            hub = cls._hubs[id(host)] = cls(host, agent.period)
        hub.agents[agent.id] = agent
        hub.board_timeout = max(hub.board_timeout, agent.board_timeout)
        return hub

    def listen(self) -> None:
        """Subscribe to ``send_position`` once for all agents of the host."""
        if self._sub is None:
            self._sub = self.host.services.subscribe(SendPosition.SERVICE, self._on_position, owner="swarm-hub")

    def _on_position(self, msg: Message) -> None:  # the host's loop
        now = time.time()
        lat = max(0.0, now - msg.time)
        b = msg.body
        pose = Position(b.x, b.y, b.yaw)
        seq = sequence(msg.conversation)
        i = latency_bin(lat)
        self.board.put(b.robot, BoardObject(topic="position", position=pose, timeout=self.board_timeout))
        for a in self.agents.values():
            if a.shared and a.id != msg.sender:
                a._account(msg.sender, seq, i, lat)

    def add_robot(self, name: str, robot: Pioneer) -> None:
        self.robots[name] = robot
        if self._task is None:
            self._task = self.host.spawn(self._control(), "swarm control loop")

    def remove_robot(self, name: str) -> Pioneer | None:
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

    def detach(self, agent: SwarmAgent) -> None:
        self.agents.pop(agent.id, None)
        if self.agents:
            return
        if self._task is not None:
            self._task.cancel()
        if self._sub is not None:
            self._sub.close()
        self.node.close()
        self.fabric.close()
        if _Hub._hubs.get(id(self.host)) is self:
            del _Hub._hubs[id(self.host)]

    def load(self) -> float:
        """Share of the control period the control loop was busy (1.0 = saturated)."""
        return self.busy_s / (self.cycles * self.period) if self.cycles else 0.0


# ---------------------------------------------------------------------------- agents
class SwarmAgent(RobotAgent):
    """One robot of the swarm (thesis 4.2.3): wall-follows with obstacle avoidance, broadcasts its
    pose on ``send_position`` every ``report_every`` seconds and keeps the others' latest poses on
    :attr:`board`; counts per sender what it received (:meth:`stats`).

    ``laser`` false (the default) drives with the sonar ring only, as the thesis's swarm did.
    Odometry starts at (0, 0, 0) on every robot; to share one frame the agent sets it to ``pose``
    ([x, y, degrees], thesis 3.5) or, with ``simulation`` true and no ``pose``, to the robot's true
    start pose read from the simulation device, and then reports in the ``map`` frame (odometry,
    drifting). While it sees no wall it steers away from the neighbours within ``disperse_radius``
    m (:class:`Disperse`). ``stats_every`` is the period of its ``swarm_stats`` messages (0: none);
    ``board_timeout`` how long a pose stays on the board; ``side`` the wall to follow; ``shared``
    false gives the agent its own ``send_position`` subscription instead of the host's shared one.
    """

    capabilities = ("send_position", STATS_SERVICE)

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str,
        period: float = 0.1,
        laser: bool = False,
        report_every: float = 0.5,
        startup_timeout: float = 60.0,
        stats_every: float = 2.0,
        board_timeout: float = 5.0,
        side: str = "left",
        shared: bool = True,
        simulation: bool = True,
        pose: Sequence[float] | None = None,
        disperse_radius: float = 4.0,
    ):
        super().__init__(
            agent_id,
            robot=robot,
            period=period,
            laser=laser,
            report_every=report_every,
            startup_timeout=startup_timeout,
            simulation=simulation,
            pose=pose,
        )
        if not self.report_every > 0:
            raise ValueError(f"agent {agent_id}: report_every {report_every!r} must be a positive number of seconds")
        if side not in ("left", "right"):
            raise ValueError(f"agent {agent_id}: side {side!r} must be 'left' or 'right'")
        self.stats_every = float(stats_every)
        self.board_timeout = float(board_timeout)
        self.side = side
        self.shared = bool(shared)
        self.disperse_radius = float(disperse_radius)
        self._board = Board()  # its own, when it has its own subscription
        self.broadcasting = True
        #: sender id -> [first sequence seen, last sequence seen, messages received]
        self.senders: dict[str, list[int]] = {}
        self.latency = LatencyHistogram()
        self.received = 0
        self.unnumbered = 0  # send_position messages without a sequence number (other agents)
        self._hub: _Hub | None = None
        self._next_stats = 0.0

    # ------------------------------------------------------------------ receiving
    def receive(self, msg: Message, now: float | None = None) -> None:
        """Account one ``send_position`` message and put its pose on the board (the host's loop)."""
        if msg.sender == self.id:
            return
        lat = max(0.0, (time.time() if now is None else now) - msg.time)
        b = msg.body
        pose = Position(b.x, b.y, b.yaw)
        self._board.put(b.robot, BoardObject(topic="position", position=pose, timeout=self.board_timeout))
        self._account(msg.sender, sequence(msg.conversation), latency_bin(lat), lat)

    def _account(self, sender: str, seq: int | None, lat_bin: int, lat: float) -> None:
        self.received += 1
        self.latency.add_bin(lat_bin, lat)
        if seq is None:
            self.unnumbered += 1
            return
        s = self.senders.get(sender)
        if s is None:
            self.senders[sender] = [seq, seq, 1]
            return
        if seq > s[1]:
            s[1] = seq
        elif seq < s[0]:
            s[0] = seq
        s[2] += 1

    @property
    def board(self) -> Board:
        """The blackboard with the other robots' latest poses (thesis fig. 3.14): the host's shared
        one when the agent uses the shared subscription, else its own."""
        return self._hub.board if self.shared and self._hub is not None else self._board

    def positions(self) -> dict[str, Position]:
        """The latest pose of every other robot still on the board."""
        return {k: o.position for k, o in self.board.items("position") if o.position is not None and k != self.robot}

    def delivery(self) -> tuple[int, int]:
        """(received, expected) numbered messages: expected counts every sequence number from the
        first to the last one seen per sender, so the gaps are the losses."""
        got = sum(s[2] for s in self.senders.values())
        want = sum(s[1] - s[0] + 1 for s in self.senders.values())
        return got, want

    def stats(self) -> dict:
        """The figures of the ``swarm_stats`` service."""
        got, want = self.delivery()
        return {
            "robot": self.robot,
            "sent": self.sent,
            "received": got,
            "expected": want,
            "senders": len(self.senders),
            "board": len(self.board),
            "latency": self.latency.to_dict(),
        }

    # ------------------------------------------------------------------ lifecycle
    def configure(self, robot: Pioneer) -> None:
        robot.set_wallfollow(True, side=self.side)

    def stop_broadcast(self) -> None:
        """Stop publishing positions (the robot keeps driving); used to count the last messages."""
        self.broadcasting = False

    async def created(self) -> None:
        host = self._require_host()
        self._hub = _Hub.attach(host, self)
        if self.shared:
            self._hub.listen()
        else:
            self.subscribe(SendPosition.SERVICE, self.receive)
        try:
            self.pioneer = await asyncio.to_thread(self._build_shared, self._hub)
        except BaseException:
            self._hub.detach(self)
            self._hub = None
            raise
        self.configure(self.pioneer)
        self._hub.add_robot(self.robot, self.pioneer)
        now = clock().now()
        # Spread the broadcasts of a crowd started at once over the reporting period.
        self._next_report = now + random.Random(self.id).uniform(0.0, self.report_every)
        self._next_stats = now + self.stats_every

    def _build_shared(self, hub: _Hub) -> Pioneer:  # a worker thread
        name = self.robot
        deadline = time.monotonic() + self.startup_timeout
        ranger = "laser" if self.laser else "sonar"

        def wait(template: str, what: str) -> None:
            while True:
                if self._abort.is_set():
                    raise InterruptedError(f"robot {name!r}: the search for its devices was aborted")
                left = deadline - time.monotonic()
                try:
                    hub.node.wait_for(template, 1, max(0.01, min(0.2, left)))
                    return
                except TimeoutError:
                    if left <= 0.2:
                        raise TimeoutError(
                            f"robot {name!r}: no {what} appeared within {self.startup_timeout:g} s "
                            "(is its device server running and reachable?)"
                        ) from None

        wait(f"{name}:position2d:0", "position2d:0 device")
        wait(f"{name}:{ranger}:0", f"{ranger}:0 device (laser={self.laser}; does the robot have one?)")
        devs = [hub.node.device(f"{name}:position2d:0"), hub.node.device(f"{name}:{ranger}:0")]
        robot = SwarmPioneer(devs, name=name, period=self.period, laser=self.laser)
        left = max(0.5, deadline - time.monotonic())
        try:
            devs[1].describe(timeout=min(5.0, left))  # the beam geometry, before the first cycle
            robot.position2d.wait_for_data(left)
            start = self.start_pose
            if start is None and self.simulation:
                wait("*:simulation:0", "simulation device (simulation=true; is this a simulated robot?)")
                sim = hub.node.device(hub.node.matches("*:simulation:0")[0])
                start = sim.get_pose(name)
            if start is not None:
                n = robot.position2d.count
                robot.position2d.set_odometry(start)
                robot.position2d.wait_for_data(max(0.5, deadline - time.monotonic()), newer_than=n + 1)
                self.frame = "map"
        except (TimeoutError, RobotError, RpcError) as e:
            raise TimeoutError(f"robot {name!r}: its devices did not answer in time ({e})") from None
        return robot

    def pose_message(self) -> SendPosition | None:
        r = self.pioneer
        pose = r.position2d.position if r is not None else None
        if pose is None:
            return None
        return SendPosition(self.robot, pose.x, pose.y, pose.yaw, self.frame)

    async def body(self) -> None:
        """``step()`` when a broadcast or a stats message is due (not every control period: the
        robot's cycle runs in the host's shared control loop)."""
        while True:
            await self.step()
            due = self._next_report
            if self.stats_every > 0:
                due = min(due, self._next_stats)
            await clock().asleep_until(due)

    async def step(self) -> None:
        now = clock().now()
        if now >= self._next_report:
            self._next_report = max(self._next_report + self.report_every, now)
            msg = self.pose_message() if self.broadcasting else None
            if msg is not None and self.frame == "map" and self.pioneer is not None:
                me = Position(msg.x, msg.y, msg.yaw)
                self.pioneer.behaviour.heading = away_from(me, list(self.positions().values()), self.disperse_radius)
            if msg is not None:
                self.publish(SendPosition.SERVICE, msg, conversation=f"p{self.sent}")
                self.sent += 1
        if self.stats_every > 0 and now >= self._next_stats:
            self._next_stats = max(self._next_stats + self.stats_every, now)
            self.publish(STATS_SERVICE, self.stats())

    async def killed(self) -> None:
        hub, self._hub = self._hub, None
        if hub is None:
            return
        robot = hub.remove_robot(self.robot)
        if robot is not None:
            robot.stop()  # a put: does not block
        hub.detach(self)

    def status(self) -> str:
        got, want = self.delivery()
        pct = 100.0 * got / want if want else 100.0
        return (
            f"{super().status()}  received {self.received} from {len(self.senders)} sender(s), "
            f"delivery {pct:.1f} %, p99 {1000 * self.latency.quantile(0.99):.1f} ms"
        )


class SwarmMonitor(Agent):
    """Judges a swarm run from the simulation's ground truth (thesis 4.2.3).

    Every ``sample_every`` seconds it reads the true pose of each robot from the ``simulation``
    device of node ``simulation``, counts overlaps (two centres closer than ``2 * radius -
    tolerance``; ``radius`` is the robot's inscribed radius, so a count is a certain overlap) and the
    mean nearest-neighbour distance (the spread); it merges the ``swarm_stats`` of the agents. After
    ``duration`` simulated seconds it publishes ``Outcome("verdict", "swarm", ok=..., final=True)``:
    ok when there was no overlap, the delivery ratio is at least ``min_delivery`` percent, the p99
    latency at most ``max_p99_ms`` and every robot's agent reported. ``robots`` is a count (robots
    ``<prefix>0`` .. ``<prefix>N-1``) or a list of robot ids.
    """

    capabilities = ("outcome",)

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str = "",
        robots: int | Sequence[str] = 100,
        prefix: str = "r",
        duration: float = 60.0,
        sample_every: float = 0.5,
        radius: float = 0.19,
        tolerance: float = 0.02,
        min_delivery: float = 100.0,
        max_p99_ms: float = 50.0,
        simulation: str = "sim",
        startup_timeout: float = 60.0,
        report_every: float = 10.0,
    ):
        super().__init__(agent_id, period=sample_every, robot=robot)
        if isinstance(robots, bool) or not isinstance(robots, (int, list, tuple)):
            raise ValueError(f"agent {agent_id}: robots {robots!r} must be a count or a list of robot ids")
        if isinstance(robots, int):
            if robots < 1:
                raise ValueError(f"agent {agent_id}: robots {robots!r} must be at least 1")
            robots = [f"{prefix}{i}" for i in range(robots)]
        if not robots or not all(isinstance(r, str) and r for r in robots):
            raise ValueError(f"agent {agent_id}: robots must name at least one robot id")
        if not duration > 0:
            raise ValueError(f"agent {agent_id}: duration {duration!r} must be a positive number of seconds")
        self.robots = list(robots)
        self.duration = float(duration)
        self.sample_every = float(sample_every)
        self.min_dist = 2.0 * float(radius) - float(tolerance)
        self.min_delivery = float(min_delivery)
        self.max_p99_ms = float(max_p99_ms)
        self.sim_node = simulation
        self.startup_timeout = float(startup_timeout)
        self.report_every = float(report_every)
        self.stats: dict[str, dict] = {}  # sender -> its latest swarm_stats body
        self.samples = 0
        self.overlaps = 0  # pairs found overlapping, summed over samples
        self.closest = math.inf  # smallest centre distance seen, m
        self.spread: list[tuple[float, float]] = []  # (sim time, mean nearest-neighbour distance)
        self.verdict: Outcome | None = None
        self.fabric: Fabric | None = None

    async def created(self) -> None:
        self.subscribe(STATS_SERVICE, self._on_stats)

    def _on_stats(self, msg: Message) -> None:
        if isinstance(msg.body, dict) and isinstance(msg.body.get("latency"), dict):
            self.stats[msg.sender] = msg.body

    def _simulation(self):  # a worker thread
        self.fabric = Fabric(self._require_host().session, own_session=False)
        node = self.fabric.node(f"{self.sim_node}:simulation:0")
        try:
            node.wait_for(f"{self.sim_node}:simulation:0", 1, self.startup_timeout)
            sim = node.device(f"{self.sim_node}:simulation:0")
            sim.wait_for_data(self.startup_timeout)
        except TimeoutError:
            raise TimeoutError(
                f"{self.id}: no simulation device {self.sim_node}:simulation:0 within {self.startup_timeout:g} s "
                "(is 'rsal sim' running and reachable?)"
            ) from None
        finally:
            node.close()
        return sim

    async def poses(self, sim) -> np.ndarray:
        """(n, 2) true positions of the watched robots (one concurrent get_pose per robot)."""
        futs = [asyncio.wrap_future(sim.rpc_async("get_pose", name=r)) for r in self.robots]
        replies = await asyncio.gather(*futs)
        return np.array([r["pose"][:2] for r in replies], dtype=float)

    def check(self, xy: np.ndarray, t: float) -> None:
        """Account one ground-truth sample: overlaps, closest pair, spread."""
        from scipy.spatial import cKDTree

        self.samples += 1
        if len(xy) < 2:
            return
        tree = cKDTree(xy)
        self.overlaps += len(tree.query_pairs(self.min_dist))
        d, _ = tree.query(xy, k=2)
        nn = d[:, 1]
        self.closest = min(self.closest, float(nn.min()))
        self.spread.append((t, float(nn.mean())))

    def merged(self) -> tuple[int, int, LatencyHistogram, int]:
        """(received, expected, latency histogram, reporting agents) over the latest stats."""
        got = want = 0
        hist = LatencyHistogram()
        for s in self.stats.values():
            try:
                got += int(s.get("received", 0))
                want += int(s.get("expected", 0))
                hist.merge(LatencyHistogram.from_dict(s["latency"]))
            except (TypeError, ValueError) as e:
                log.warning("%s: ignored bad swarm_stats: %s", self.id, e)
        return got, want, hist, len(self.stats)

    def judge(self, elapsed: float) -> Outcome:
        got, want, hist, reporting = self.merged()
        delivery = 100.0 * got / want if want else 0.0
        p99 = 1000.0 * hist.quantile(0.99) if hist.n else math.inf
        n = len(self.robots)
        problems = []
        if self.overlaps:
            problems.append(f"{self.overlaps} overlap(s), closest {self.closest:.2f} m")
        if delivery < self.min_delivery:
            problems.append(f"delivery {delivery:.2f} % < {self.min_delivery:g} %")
        if not p99 <= self.max_p99_ms:
            problems.append(f"p99 latency {p99:.0f} ms > {self.max_p99_ms:g} ms")
        if reporting < n:
            problems.append(f"stats from {reporting} of {n} agents")
        s0 = self.spread[0][1] if self.spread else math.nan
        s1 = self.spread[-1][1] if self.spread else math.nan
        text = (
            f"{n} robots {elapsed:.0f} s: {'no overlap' if not self.overlaps else f'{self.overlaps} overlap(s)'}, "
            f"delivery {delivery:.1f} % ({got}/{want}), p99 latency {p99:.0f} ms, spread {s0:.1f} -> {s1:.1f} m"
        )
        if problems:
            text += " -- " + "; ".join(problems)
        return Outcome("verdict", "swarm", text, ok=not problems, final=True)

    async def body(self) -> None:
        sim = await asyncio.to_thread(self._simulation)
        t0 = sim.latest.t
        next_report = clock().now() + self.report_every
        while True:
            started = clock().now()
            t = sim.latest.t
            try:
                xy = await self.poses(sim)
            except Exception as e:  # a slow or restarting simulator: skip this sample
                log.warning("%s: ground-truth sample failed: %s", self.id, e)
            else:
                self.check(xy, t)
            if t - t0 >= self.duration:
                self.verdict = self.judge(t - t0)
                self.publish(Outcome.SERVICE, self.verdict)
                log.info("%s: %s", self.id, self.verdict.text)
                return
            if clock().now() >= next_report:
                next_report += self.report_every
                log.info("%s: %s", self.id, self.judge(t - t0).text)
            await clock().asleep_until(started + self.sample_every)

    async def killed(self) -> None:
        if self.fabric is not None:
            self.fabric.close()


# ---------------------------------------------------------------------------- worlds
def crowd_world(
    n: int,
    *,
    spacing: float = 1.2,
    seed: int = 0,
    bitmap: str = "arena.png",
    model: str = "pioneer2dx",
    name: str = "r",
) -> str:
    """The Stage world text of ``n`` robots (``<name>0`` ..) on a square grid ``spacing`` m apart,
    centred on the 128 m arena's free middle, each facing a random direction (``seed``).
    ``bitmap`` is the arena's floorplan, relative to where the world file is written."""
    if n < 1:
        raise ValueError(f"a crowd needs at least one robot, got {n}")
    side = math.ceil(math.sqrt(n))
    half = (side - 1) * spacing / 2.0
    if half > 19.0:
        raise ValueError(f"{n} robots {spacing:g} m apart do not fit the arena's free square (|x|, |y| < 20 m)")
    rng = random.Random(seed)
    colors = ("red", "blue", "yellow", "green", "orange", "cyan", "magenta", "gray")
    lines = [
        f"# RSAL fabric -- a crowd of {n} Pioneers for the Swarm scenario (thesis 4.2.3), written by",
        "# agents.swarm.crowd_world: the 128 m arena, robots on a square grid around its free centre,",
        f"# {spacing:g} m apart, random headings (seed {seed}). Each is a Pioneer 2DX with its 8-sonar ring",
        "# (the light sensor model: no laser). Stage 4 syntax; original to this project.",
        "",
        'include "pioneer.inc"',
        'include "map.inc"',
        "",
        "resolution 0.02",
        "interval_sim 100",
        "speedup 1.000",
        "paused 0",
        "",
        "floorplan",
        "(",
        '  name "arena"',
        f'  bitmap "{bitmap}"',
        "  size [ 128.0 128.0 0.8 ]",
        "  pose [ 0 0 0 0 ]",
        ")",
        "",
    ]
    for i in range(n):
        row, col = divmod(i, side)
        x, y = -half + col * spacing, -half + row * spacing
        yaw = rng.uniform(-180.0, 180.0)
        lines.append(
            f'{model}( name "{name}{i}" pose [ {x:.2f} {y:.2f} 0 {yaw:.0f} ] color "{colors[row % len(colors)]}" )'
        )
    return "\n".join(lines) + "\n"


def write_crowd_world(path: str | Path, n: int, **kw) -> Path:
    """Write :func:`crowd_world` to ``path`` with the arena bitmap referenced by absolute path."""
    p = Path(path)
    arena = Path(__file__).resolve().parent.parent / "maps" / "arena.png"
    p.write_text(crowd_world(n, bitmap=str(arena), **kw))
    return p
