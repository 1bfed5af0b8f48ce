"""The Swarm scenario's robots (thesis 4.2.3): wall-following Pioneers that broadcast their positions.

"It includes 100 robots that spread out from their closely spaced starting positions and explore the
map by wall-following. Low-level obstacle avoidance guides each robot to avoid collisions. In order
to stress the MAS layer, each robot subscribes to the SendPositionService, broadcasts its own
position and reads other position values."

:class:`SwarmAgent` drives one Pioneer with the subsumption behaviour of 3.6.2.4 (wall-following,
avoid, escape) and one more layer for open space (:class:`Disperse`), publishes its pose on
``send_position`` every ``report_every`` seconds (2 Hz by default) and keeps every other robot's
latest pose on a :class:`rsal.data.Board`. It measures what it receives (:mod:`.metrics`: delivery
per sender from the broadcasts' sequence numbers, latency histogram) and publishes these figures on
the ``swarm_stats`` service (:mod:`.messages`). Periods (control cycle, broadcasts, the monitor's
samples) count the process's clock (:mod:`rsal.clock`: simulated seconds under a simulator's
clock); latency stays wall time.

Agents of one host share the costly parts through the host's :class:`agents.hub.RobotHub`: one
Fabric and one DeviceNode to find all robots, one control loop on the host's asyncio loop that runs
every robot's behaviour cycle in turn instead of a thread per robot, and one Zenoh subscriber on
``send_position`` whose messages are decoded once, put once on the host's blackboard and accounted
for each agent on the loop. ``shared=False`` gives an agent its own subscription and blackboard.
The run's judge is :class:`.monitor.SwarmMonitor`, its world :func:`.world.crowd_world`.

With ``neighbourhood`` R > 0 (neighbourhood-scoped broadcasts, the thesis's
"information-hiding", 5.3) an agent publishes in the cell of its pose
(``svc/send_position/<cell>/<sender>``, :mod:`agents.cells`) and the host's hub listens only to the
cells within R plus a margin of its robots (:meth:`agents.hub.RobotHub.listen_near`); a message is
accounted only for the agents whose own cells hold the sender's cell, in batches per hub (:mod:`.ledger`, :mod:`.near`),
and each agent reports the
sequence numbers it received per sender as ranges (``ranges`` in ``swarm_stats``), which the monitor
checks against the ground truth (every receiver within R of the sender at send time).
"""

from __future__ import annotations

import asyncio
import logging
import os
import random
import socket
import time
from collections.abc import Sequence

from agents.cells import cell_of
from agents.cells import margin as cell_margin
from agents.cellsub import DEFAULT_WILDCARD_ABOVE
from agents.classes import RobotAgent
from agents.hub import RobotHub
from agents.registry import agent_class
from agents.services import Message, SendPosition
from rsal.clock import clock
from rsal.data import Board, BoardObject, Position
from rsal.keys import DeviceAddr
from rsal.msgs import ErrorCode, RpcError
from rsal.robot import Pioneer, RobotError

from .behaviour import SwarmPioneer, away_from
from .crowd import CrowdRobot, CrowdStep, drop_link, link_of
from .ledger import NearLedger, Received
from .messages import STATS_SERVICE
from .metrics import LatencyHistogram, latency_bin, sequence
from .near import Headings, near_hooks
from .vector import HostStep

__all__ = ["SwarmAgent"]

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------- agents
@agent_class("SwarmAgent")
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

    ``neighbourhood`` R (m; 0, the default: all-to-all) scopes the broadcasts: the agent publishes
    in the cell of its pose on a grid of ``cell_size`` m (default R) and hears the cells within
    R + ``margin`` of its robot (default :func:`agents.cells.margin` of ``max_speed`` m/s over one
    ``report_every``), re-watched every ``report_every`` seconds by the host's hub; it needs the
    shared subscription, and every agent of a swarm the same R and cell size. A host that watches
    more than ``wildcard_cells`` cells (default 64; 0: never) holds one subscriber on every cell
    and drops the messages of the cells it does not watch itself (:mod:`agents.cellsub`).
    ``bundle`` (default false; with a neighbourhood): the host puts its agents' broadcasts of each
    ~10 ms as one sample (:mod:`agents.services`, "Bundles"), which every hub takes apart; for
    crowds on an open fabric.

    ``vector`` (default true): with the shared subscription, the host's hub runs one vectorised
    behaviour step for all its swarm robots per control cycle (:class:`.vector.HostStep`, the same
    behaviour on arrays); false: this robot runs its own cycle.

    ``crowd`` (default false): the host reads and commands its robots through the simulator's
    ``crowd`` device (:mod:`.crowd`: one describe, one message per simulation step in, one command
    message per control cycle out) instead of two device proxies per robot; it needs the shared
    subscription and the vectorised step.
    """

    capabilities = ("send_position", STATS_SERVICE)
    pioneer_class: type[SwarmPioneer] = SwarmPioneer  # the robot it builds (a subclass may use its own)

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
        neighbourhood: float = 0.0,
        cell_size: float = 0.0,
        margin: float | None = None,
        max_speed: float = 0.5,
        vector: bool = True,
        crowd: bool = False,
        wildcard_cells: int = DEFAULT_WILDCARD_ABOVE,
        bundle: bool = False,
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
        if not isinstance(vector, bool):
            raise ValueError(f"agent {agent_id}: vector {vector!r} must be true or false")
        self.vector = vector
        if not isinstance(crowd, bool):
            raise ValueError(f"agent {agent_id}: crowd {crowd!r} must be true or false")
        if crowd and not (vector and shared):
            raise ValueError(
                f"agent {agent_id}: crowd: true needs vector: true and shared: true (the host's batch step)"
            )
        self.crowd = crowd
        for name, v in (("neighbourhood", neighbourhood), ("cell_size", cell_size), ("max_speed", max_speed)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0:
                raise ValueError(f"agent {agent_id}: {name} {v!r} must be a number of metres (per second) >= 0")
        self.neighbourhood = float(neighbourhood)
        self.cell_size = float(cell_size) or self.neighbourhood
        if margin is not None and (isinstance(margin, bool) or not isinstance(margin, (int, float)) or margin < 0):
            raise ValueError(f"agent {agent_id}: margin {margin!r} must be a number of metres >= 0")
        self.margin = cell_margin(max_speed, self.report_every) if margin is None else float(margin)
        if isinstance(wildcard_cells, bool) or not isinstance(wildcard_cells, int) or wildcard_cells < 0:
            raise ValueError(
                f"agent {agent_id}: wildcard_cells {wildcard_cells!r} must be a whole number >= 0 (0: never)"
            )
        self.wildcard_cells = wildcard_cells
        if not isinstance(bundle, bool):
            raise ValueError(f"agent {agent_id}: bundle {bundle!r} must be true or false")
        if bundle and not self.neighbourhood:
            raise ValueError(f"agent {agent_id}: bundle: true bundles cell broadcasts; give a neighbourhood radius too")
        self.bundle = bundle
        if self.neighbourhood and not self.shared:
            raise ValueError(f"agent {agent_id}: a neighbourhood needs the host's shared subscription (shared: true)")
        #: neighbourhood: the (sender, sequence number) pairs received (:mod:`.ledger`)
        self.got = Received()
        self._ledger: NearLedger | None = None
        self._headings: Headings | None = None
        self.since: float | None = None  # wall time its reception began (neighbourhood: its cells watched)
        self._board = Board()  # its own, when it has its own subscription
        self.broadcasting = True
        #: sender id -> [first sequence seen, last sequence seen, messages received]
        self.senders: dict[str, list[int]] = {}
        self._latency = LatencyHistogram()
        self._received = 0
        self.unnumbered = 0  # send_position messages without a sequence number (other agents)
        self._hub: RobotHub | None = None
        self._next_stats = 0.0
        self._part = 0  # the next swarm_stats part's number

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
        self._received += 1
        self._latency.add_bin(lat_bin, lat)
        if seq is None:
            self.unnumbered += 1
            return
        if self.neighbourhood:
            self.got.add(sender, seq)
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

    def join_ledger(self, ledger: NearLedger) -> None:
        """Have ``ledger`` (its hub's) account the neighbourhood messages owed to this agent."""
        self._ledger = ledger
        ledger.join(self)

    def _settle(self) -> None:
        """Take what the hub's ledger accounted for this agent since it last asked (its keys, its
        latency histogram's row, its count): the per-agent split happens only here, when the
        agent's figures are read, not at every flush."""
        t = self._ledger.take(self) if self._ledger is not None else None
        if t is None or not t.n:
            return
        for k in t.keys:
            self.got.add_keys(k)
        self._received += t.n
        self._latency.add_counts(t.counts, t.max_s, t.sum_s)

    @property
    def received(self) -> int:
        """Messages received (accounted), its own not counted."""
        self._settle()
        return self._received

    @property
    def latency(self) -> LatencyHistogram:
        """The latency histogram of the messages received."""
        self._settle()
        return self._latency

    @latency.setter
    def latency(self, hist: LatencyHistogram) -> None:  # e.g. a benchmark's fresh one for its window
        self._settle()
        self._latency = hist

    @property
    def ranges(self) -> dict[str, list[int]]:
        """Neighbourhood: sender id -> the sequence numbers received, flat ``[first0, last0, ...]``."""
        self._settle()
        return self.got.ranges()

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

    def listening_since(self) -> float | None:
        """Wall time its reception began: with a neighbourhood, when the hub first watched its
        robot's cells (a robot whose pose came late listened to nothing before), else when it
        started; None before either."""
        hub = self._hub
        watched = hub.watched_since.get(self.id) if hub is not None and self.neighbourhood else None
        if watched is None or self.since is None:
            return self.since
        return max(self.since, watched)

    def stats(self, *, part: bool = False) -> dict:
        """The figures of the ``swarm_stats`` service (with a neighbourhood also ``since`` and
        ``t``: wall times its reception began and of these figures, and ``ranges``: sender -> flat
        sequence ranges received). ``part``: instead of ``ranges``, ``new_ranges``, only what came
        since the previous part, numbered by ``part`` from 0 (what the agent publishes: a report
        costs what is new, not the whole run; the judge adds the parts up)."""
        got, want = self.delivery()
        extra = {}
        if self.neighbourhood:
            t = self._ledger.flushed_at if self._ledger is not None else time.time()  # complete up to t
            extra = {"since": self.listening_since(), "t": t}
            if part:
                self._settle()
                extra |= {"part": self._part, "new_ranges": self.got.take_new()}
                self._part += 1
            else:
                extra["ranges"] = self.ranges
        return {
            **extra,
            "robot": self.robot,
            "sent": self.sent,
            "received": got,
            "expected": want,
            "senders": len(self.senders),
            "board": len(self.board),
            "latency": self.latency.to_dict(),
            **self._loop_figures(),
        }

    def _loop_figures(self) -> dict:
        """``loop``: its host's shared control loop (one per process): ``id``, ``cycles`` run and
        ``overruns`` (cycles that ended after their period), for the judge's overrun share."""
        hub = self._hub
        if hub is None:
            return {}
        return {"loop": {"id": _LOOP_ID, "cycles": hub.cycles, "overruns": hub.overruns}}

    # ------------------------------------------------------------------ lifecycle
    def configure(self, robot: Pioneer) -> None:
        robot.set_wallfollow(True, side=self.side)

    def stop_broadcast(self) -> None:
        """Stop publishing positions (the robot keeps driving); used to count the last messages."""
        self.broadcasting = False

    #: its robot is built in :meth:`created` through the host's hub (one device node for the host's
    #: robots, or the crowd device), not by :meth:`find_robot`'s device search per robot, which an
    #: agent host process (agents.hostproc) would otherwise run first: a thousand per-robot searches
    #: subscribe every robot's devices and held a 1000-robot simulator at 0.19 x real time
    robot_built_by_host = True

    async def created(self) -> None:
        self._join_hub()
        if not self.shared:
            self.subscribe(SendPosition.SERVICE, self.receive)
        try:
            if self.crowd:
                self.pioneer = await asyncio.to_thread(self._build_crowd, self._hub)
                if not isinstance(self._hub.batch, CrowdStep):
                    self._hub.batch = CrowdStep(self.pioneer.link, lambda: clock().now())
            else:
                self.pioneer = await asyncio.to_thread(self._build_shared, self._hub)
        except BaseException:
            self._hub.detach(self)
            self._hub = None
            raise
        self.configure(self.pioneer)
        if not self.vector:
            self.pioneer.vectorised = False
        self._hub.add_robot(self.robot, self.pioneer)  # neighbourhood: its cells are watched from now on
        self.since = time.time()
        now = clock().now()
        self._next_report, self._next_stats = first_due(self.id, now, self.report_every, self.stats_every)

    def _join_hub(self) -> RobotHub:
        """Attach to the host's :class:`agents.hub.RobotHub` and, when ``shared``, to its
        ``send_position`` subscription (:func:`_account_shared` accounts each message for us)."""
        self._hub = RobotHub.attach(self._require_host(), self, period=self.period, board_timeout=self.board_timeout)
        try:
            if self.neighbourhood:
                ledger, self._headings = near_hooks(self._hub, SwarmAgent)
                self.join_ledger(ledger)
                self._hub.listen_near(
                    self.neighbourhood,
                    self.cell_size,
                    self.margin,
                    self.report_every,
                    ledger.on_message,
                    wildcard_above=self.wildcard_cells,
                    bundle=self.bundle,
                )
            elif self.shared:
                self._hub.listen(_account_shared)
            if self.vector and self.shared and not self.crowd and self._hub.batch is None:
                self._hub.batch = HostStep(lambda: clock().now())  # one step for all the host's swarm robots
        except ValueError as e:
            self._hub.detach(self)
            self._hub = None
            raise ValueError(f"agent {self.id}: {e}") from None
        return self._hub

    def _build_shared(self, hub: RobotHub) -> Pioneer:  # a worker thread
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

        def patient(call):
            """``call()``, again after a pause while the server answers busy (a crowd's start-up
            fills a simulator's inbox), until the start-up deadline."""
            pause = 0.1
            while True:
                try:
                    return call()
                except RpcError as e:
                    if e.code != ErrorCode.BUSY or time.monotonic() + pause > deadline or self._abort.is_set():
                        raise
                time.sleep(pause * random.uniform(1.0, 2.0))
                pause = min(2.0, 2 * pause)

        wait(f"{name}:position2d:0", "position2d:0 device")
        wait(f"{name}:{ranger}:0", f"{ranger}:0 device (laser={self.laser}; does the robot have one?)")
        devs = [hub.node.device(f"{name}:position2d:0"), hub.node.device(f"{name}:{ranger}:0")]
        robot = self.pioneer_class(devs, name=name, period=self.period, laser=self.laser)
        left = max(0.5, deadline - time.monotonic())
        try:
            patient(lambda: devs[1].describe(timeout=min(5.0, left)))  # the beam geometry, before the first cycle
            robot.position2d.wait_for_data(left)
            start = self.start_pose
            if start is None and self.simulation:
                wait("*:simulation:0", "simulation device (simulation=true; is this a simulated robot?)")
                sim = hub.node.device(hub.node.matches("*:simulation:0")[0])
                start = patient(lambda: sim.get_pose(name))
            if start is not None:
                n = robot.position2d.count
                patient(lambda: robot.position2d.set_odometry(start))
                robot.position2d.wait_for_data(max(0.5, deadline - time.monotonic()), newer_than=n + 1)
                self.frame = "map"
        except (TimeoutError, RobotError, RpcError) as e:
            raise TimeoutError(f"robot {name!r}: its devices did not answer in time ({e})") from None
        return robot

    def _build_crowd(self, hub: RobotHub) -> CrowdRobot:  # a worker thread
        """The robot as a row of the simulator's crowd device (:mod:`.crowd`); the host's first agent
        fetches the layout, the others find their row in it."""
        name = self.robot
        deadline = time.monotonic() + self.startup_timeout
        try:
            link = link_of(hub, self.startup_timeout)
            robot = CrowdRobot(link, name, period=self.period)
        except TimeoutError:
            raise TimeoutError(
                f"robot {name!r}: no crowd device appeared within {self.startup_timeout:g} s "
                "(crowd: true needs a simulator that serves <simnode>:crowd:0)"
            ) from None
        except LookupError as e:
            raise TimeoutError(f"robot {name!r}: {e}") from None
        if link.layout.frames[robot.row] == "gps":
            self.frame = "map"  # its position2d reports ground truth: the shared frame already
        else:
            start = self.start_pose
            if start is None and self.simulation:
                sim = hub.fabric.device(hub.node.wait_for("*:simulation:0", 1, self.startup_timeout)[0])
                start = sim.get_pose(name)
            if start is not None:
                addr = DeviceAddr(name, "position2d", 0)
                hub.fabric.rpc(addr, "set_odom", {"pose": list(start.as_tuple())}, timeout=self.startup_timeout)
                self.frame = "map"
        while robot.position is None:  # its first row
            if self._abort.is_set():
                raise InterruptedError(f"robot {name!r}: the wait for its crowd data was aborted")
            if time.monotonic() > deadline:
                raise TimeoutError(f"robot {name!r}: no crowd data within {self.startup_timeout:g} s")
            time.sleep(0.05)
        return robot

    def pose_message(self) -> SendPosition | None:
        r = self.pioneer
        pose = r.position if r is not None else None
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
            if msg is not None and self.frame == "map" and self.pioneer is not None and self._headings is not None:
                self.pioneer.behaviour.heading = self._headings.of.get(self.robot)  # the hub's, all at once
            elif msg is not None and self.frame == "map" and self.pioneer is not None:
                me = Position(msg.x, msg.y, msg.yaw)
                if self.shared and self._hub is not None:  # the host's latest poses, as arrays
                    r = min(self.disperse_radius, self.neighbourhood or self.disperse_radius)
                    others = self._hub.near(msg.x, msg.y, r, exclude=self.robot)
                else:
                    others = list(self.positions().values())
                self.pioneer.behaviour.heading = away_from(me, others, self.disperse_radius)
            if msg is not None:
                cell = cell_of(msg.x, msg.y, self.cell_size) if self.neighbourhood else None
                self.publish(SendPosition.SERVICE, msg, conversation=f"p{self.sent}", cell=cell)
                self.sent += 1
        if self.stats_every > 0 and now >= self._next_stats:
            self._next_stats = max(self._next_stats + self.stats_every, now)
            self.publish(STATS_SERVICE, self.stats(part=True))

    async def killed(self) -> None:
        hub, self._hub = self._hub, None
        if self._ledger is not None:
            self._settle()  # its figures stay readable
            self._ledger.leave(self)
            self._ledger = None
        if hub is None:
            return
        robot = hub.remove_robot(self.robot)
        if robot is not None:
            robot.stop()  # a put: does not block
        hub.detach(self)
        if not hub.agents:
            drop_link(hub)

    def status(self) -> str:
        if self.neighbourhood:  # delivery within the radius is judged on ground truth, by the monitor
            heard = f"received {self.received} from {self.got.senders()} sender(s) within {self.neighbourhood:g} m"
        else:
            got, want = self.delivery()
            pct = 100.0 * got / want if want else 100.0
            heard = f"received {self.received} from {len(self.senders)} sender(s), delivery {pct:.1f} %"
        return f"{super().status()}  {heard}, p99 {1000 * self.latency.quantile(0.99):.1f} ms"


#: this process's control loop, as swarm_stats name it (one hub per host process)
_LOOP_ID = f"{socket.gethostname()}:{os.getpid()}"


def first_due(agent_id: str, now: float, report_every: float, stats_every: float) -> tuple[float, float]:
    """When an agent started at ``now`` first broadcasts and first reports its stats: spread over
    their periods by its id, so that a crowd started at once does not do either all at once (500
    agents' stats at once held their host's loop for over half a second every period)."""
    rng = random.Random(agent_id)
    return now + rng.uniform(0.0, report_every), now + rng.uniform(0.0, stats_every)


def _account_shared(hub: RobotHub, msg: Message, now: float) -> None:
    """The hub's ``send_position`` listener: the sequence number and latency bin of a message are
    worked out once and accounted by every swarm agent of the host that shares the subscription
    (a neighbourhood's messages go through the hub's :class:`.ledger.NearLedger` instead)."""
    lat = max(0.0, now - msg.time)
    seq = sequence(msg.conversation)
    i = latency_bin(lat)
    for a in hub.agents.values():
        if isinstance(a, SwarmAgent) and a.shared and a.id != msg.sender:
            a._account(msg.sender, seq, i, lat)
