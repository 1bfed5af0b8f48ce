"""The hunters and the prey of Hunt and Prey (thesis 4.2.1).

:class:`FollowAgent` is the hunter: a :class:`agents.navigation.NavAgent` that listens to
``send_position`` and navigates to where its prey is now -- the prey's broadcast positions tracked
between messages by a Kalman filter (:mod:`rsal.tracking`) -- planning again when the prey has
moved more than ``replan_distance`` from the current goal (at most once per ``replan_interval``).
When its localized pose comes within ``capture_distance`` of the prey it publishes ``outcome``
``caught`` (subject: the prey's robot) and stops; the prey (:class:`EscapeAgent`) then spins in
place. A hunter claims a catch only while it is sure where it is: the position standard deviation of
its localizer's covariance (the larger axis of the x-y ellipse) must be at most ``max_pose_sd``;
otherwise it keeps chasing (and says so, once per minute) until its localization has settled.

In the advanced form (``allocation="contract_net"``) the hunters share out the prey themselves with
the contract net of :mod:`agents.contractnet`: the hunter with the lowest id is the auctioneer. Every
``replan_interval`` seconds it looks at the prey that are not caught (agents whose ``hello`` offers
the capability ``prey``, located by their ``send_position``), gives each an equal share of the
hunters (``ceil(hunters / prey)``), takes the nearest prey short of hunters for itself when it is free,
and announces the other places one ``cfp`` at a time (task: the prey and where it is). A free hunter
bids its straight-line distance to the prey, a busy one refuses, so the nearest free hunter wins
("nearest first"); the auctioneer allocates once every hunter it knows has broadcast a map position
(it could not bid before it is localized), or after ``ALLOCATION_GRACE`` seconds, and once it has
seen every hunter and prey on ``SEEN_ROUNDS`` looks around (so the others, who look around as often,
know them too); a call stays open ``BID_WINDOW`` seconds at most. The winner chases
until the prey is caught, by anyone, and then answers ``inform-done``; nobody chases a caught prey.

A hunter answers only the auctioneer's calls and bids only for prey it knows (offered ``prey`` on
``hello`` and broadcast a position), so a forged call for an unknown prey (a "ghost") commits nobody
(``docs/security.md``, "Open fabric").

With energy stations (thesis 4.2.1: the prey must regain battery life there; :mod:`.energy`,
:mod:`.stations`) a hunter may be given a finite ``sight``: it sees its prey only while the prey's
broadcast position is within ``sight`` metres of its own (the broadcast stands in for the camera
the thesis suggests). While the prey is out of sight the hunter waits in ambush at a station -- the
stations ordered by distance to where it last saw the prey, hunter *k* by id watching the *k*-th
(:func:`.stations.watch_station`), ``watch_distance`` in front of it -- and chases again as soon as
the prey comes into sight. The stations come from ``stations`` or, with ``simulation: true``, from
the simulation's ``describe``. With the default infinite ``sight`` nothing changes.
"""

from __future__ import annotations

import asyncio
import logging
import math

import numpy as np

from agents.classes import WallfollowAgent
from agents.contractnet import Initiator, Participant
from agents.navigation import NavAgent
from agents.navigation import number_arg as _number
from agents.registry import agent_class
from agents.services import Hello, Message, Outcome, SendPosition, match
from rsal.clock import clock
from rsal.data import Position
from rsal.robot import Pioneer
from rsal.tracking import Tracks

from .messages import HUNT_SERVICE
from .stations import station_arg, stations_from_simulation, watch_point, watch_station

__all__ = ["EscapeAgent", "FollowAgent"]

log = logging.getLogger(__name__)

#: seconds the auctioneer waits for every hunter's first map position before it allocates anyway
ALLOCATION_GRACE = 10.0
#: looks around (``hello``) in which the auctioneer must have seen a hunter or a prey before it
#: allocates: every hunter looks around as often, so by then each knows the prey and its auctioneer
#: (a hunter that missed a ``hello`` would refuse or ignore the call and lose its place to a farther one)
SEEN_ROUNDS = 2
#: seconds a call for proposals stays open (it closes at once when every hunter asked has answered)
BID_WINDOW = 2.0


@agent_class("FollowAgent")
class FollowAgent(NavAgent):
    """A hunter (thesis 4.2.1): chases its ``prey`` (a robot id) by navigating to the prey's latest
    broadcast position until within ``capture_distance`` metres, then publishes ``caught``. With
    ``allocation="contract_net"`` and no ``prey`` the hunters allocate the prey among themselves."""

    capabilities = ("send_position", "new_goal", "hunter")

    def __init__(
        self,
        agent_id: str,
        *,
        prey: str = "",
        allocation: str = "fixed",
        capture_distance: float = 1.0,
        replan_distance: float = 0.75,
        replan_interval: float = 1.0,
        max_pose_sd: float = 0.3,
        sight: float = math.inf,
        stations: list | None = None,
        watch_distance: float = 1.5,
        **kw,
    ):
        super().__init__(agent_id, **kw)
        self.sight = _number(agent_id, "sight", sight, 0.0)
        self.watch_distance = _number(agent_id, "watch_distance", watch_distance, 0.0, 20.0)
        self.stations = station_arg(agent_id, stations) if stations is not None else []
        if math.isfinite(self.sight) and stations is None and not self.simulation:
            raise ValueError(
                f"agent {agent_id}: a finite sight needs the energy stations to wait at: "
                "stations: [{name, pose: [x, y, degrees]}] or simulation: true"
            )
        self.seen: dict[str, tuple[float, float]] = {}  # prey robot -> where this hunter last saw it
        self.watching = None  # the station (agents.dispatch.Charger) waited at while the prey is unseen
        self._watch_sent = False  # the goal to the watching station's watch point was sent
        self._looked = False  # the first hello round is done (the ambush splits the stations by it)
        if allocation not in ("fixed", "contract_net"):
            raise ValueError(f"agent {agent_id}: allocation {allocation!r} must be 'fixed' or 'contract_net'")
        if not isinstance(prey, str):
            raise ValueError(f"agent {agent_id}: prey {prey!r} must be a robot id")
        if allocation == "fixed" and not prey:
            raise ValueError(f"agent {agent_id}: a prey robot id is required (or allocation: contract_net)")
        self.allocation = allocation
        self.prey = prey  # the prey chased now ("" for none)
        self.capture_distance = _number(agent_id, "capture_distance", capture_distance, 0.0, 20.0)
        self.replan_distance = _number(agent_id, "replan_distance", replan_distance, 0.0, 20.0)
        self.replan_interval = _number(agent_id, "replan_interval", replan_interval, 0.0, 60.0)
        self.max_pose_sd = _number(agent_id, "max_pose_sd", max_pose_sd, 0.0, 20.0)
        self._unsure_said = -math.inf  # when the hunter last said it is too unsure to claim a catch
        self.positions: dict[str, SendPosition] = {}  # robot id -> latest broadcast position
        self.tracks = Tracks()  # robot id -> Kalman track of its broadcasts (where it is between them)
        self.caught: dict[str, str] = {}  # prey robot -> the outcome text
        self.catches = 0  # prey this hunter caught
        self.prey_robots: set[str] = {prey} if prey else set()
        self.hunters: list[str] = []  # hunter agent ids seen on hello (contract net)
        self.hunter_robots: dict[str, str] = {}  # hunter agent id -> its robot (hello)
        self._waiting_since: float | None = None  # auctioneer: since when a hunter has no position yet
        self._chase_goal: Position | None = None
        self._last_plan = -math.inf
        self._backoff = 0  # chase goals refused in a row
        self._hunt_start = 0.0
        self._cnp: Participant | None = None
        self._initiator: Initiator | None = None
        self._assigned: dict[str, set[str]] = {}  # auctioneer: prey -> hunters chasing it
        self._auctioning: set[str] = set()  # auctioneer: prey with a cfp under way
        self._allocation_task: asyncio.Task | None = None
        self._rounds_seen: dict[str, int] = {}  # auctioneer: agent/robot -> look-arounds it was seen in

    async def created(self) -> None:
        await super().created()
        self._hunt_start = clock().now()
        self.subscribe(SendPosition.SERVICE, self._on_position)
        self.subscribe(Outcome.SERVICE, self._on_caught, filter=match(event="caught"))
        if self.allocation == "contract_net":
            self._cnp = Participant(
                self, bid=self._bid, perform=self._perform, service=HUNT_SERVICE, initiators=self._is_auctioneer
            )
            self._initiator = Initiator(self, service=HUNT_SERVICE)
        if self.allocation == "contract_net" or math.isfinite(self.sight):  # who hunts: allocation, ambush
            self._allocation_task = self.host.spawn(self._allocation_loop(), f"{self.id}: allocation")
        if math.isfinite(self.sight) and not self.stations:
            self.stations = await asyncio.to_thread(stations_from_simulation, self.fabric, self.startup_timeout)
            if not self.stations:
                log.warning("%s: the world has no energy stations; waiting where the prey was last seen", self.id)

    async def killed(self) -> None:
        if self._allocation_task is not None:
            self._allocation_task.cancel()
        await super().killed()

    # ------------------------------------------------------------------ messages
    def _on_position(self, msg: Message) -> None:
        p: SendPosition = msg.body
        if p.frame == "map":
            self.positions[p.robot] = p
            self.tracks.update(p.robot, p.x, p.y, p.yaw, clock().now())

    def _on_caught(self, msg: Message) -> None:
        o: Outcome = msg.body
        if o.subject in self.caught:
            return
        self.caught[o.subject] = o.text
        if o.subject == self.prey and msg.sender != self.id:
            log.info("%s: my prey %s was caught by %s; stopping the chase", self.id, o.subject, msg.sender)
            self._end_chase()

    def _end_chase(self) -> None:
        self.prey = ""
        self._chase_goal = None
        self.host.spawn(self.stop_robot(), f"{self.id}: stop")

    # ------------------------------------------------------------------ contract net
    def _is_auctioneer(self, sender: str) -> bool:
        """Whose calls this hunter answers: the lowest-id hunter seen on ``hello``."""
        return bool(self.hunters) and sender == self.hunters[0]

    def _known_prey(self, prey) -> bool:
        return isinstance(prey, str) and prey in self.prey_robots and prey in self.positions

    def _bid(self, task: dict):
        prey = task.get("prey")
        if self.prey or not self._known_prey(prey) or prey in self.caught:
            return None  # busy, an unknown prey (a forged call), or nothing to chase
        me = self.nav.position if self.nav is not None else None
        if me is None:
            return None
        return math.hypot(float(task.get("x", 0.0)) - me.x, float(task.get("y", 0.0)) - me.y)

    async def _perform(self, task: dict) -> bool:
        """Take on the prey (done at once: the chase itself ends with the prey's ``caught``)."""
        prey = task.get("prey")
        if self.prey or not self._known_prey(prey) or prey in self.caught:
            return False
        self._chase(prey)
        return True

    def _chase(self, prey: str) -> None:
        log.info("%s: chasing %s", self.id, prey)
        self.prey = prey
        self.prey_robots.add(prey)
        self._chase_goal = None
        self._last_plan = -math.inf

    async def _look_around(self) -> None:
        """Who hunts and what is prey (hello), for the allocation."""
        hellos: list[Hello] = await self.host.who_is_there(timeout=0.5)
        self.hunters = sorted(h.id for h in hellos if "hunter" in h.capabilities)
        self._looked = True
        self.hunter_robots = {h.id: h.robot for h in hellos if "hunter" in h.capabilities}
        self.prey_robots |= {h.robot for h in hellos if "prey" in h.capabilities and h.robot}
        for name in {*self.hunters, *(h.robot for h in hellos if "prey" in h.capabilities and h.robot)}:
            self._rounds_seen[name] = self._rounds_seen.get(name, 0) + 1

    async def _allocation_loop(self) -> None:
        """Look around every ``replan_interval`` (at least 1 s); the lowest-id hunter allocates."""
        while self.state == "running":
            await self._look_around()
            if self.allocation == "contract_net" and self.hunters and self.hunters[0] == self.id:
                await self._allocate()
            await clock().asleep(max(1.0, self.replan_interval))

    async def _allocate(self) -> None:
        """The auctioneer's round: share the uncaught prey among the hunters, nearest first."""
        for p in [p for p in self._assigned if p in self.caught]:
            del self._assigned[p]
        prey = sorted(p for p in self.prey_robots if p not in self.caught and p in self.positions)
        if not prey or not self.hunters:
            return
        new = [x for x in (*self.hunters, *prey) if self._rounds_seen.get(x, 0) < SEEN_ROUNDS]
        if new:  # the other hunters may not have seen them yet: nearest first needs every bid
            log.debug("%s: seen only just now: %s", self.id, ", ".join(new))
            return
        # Nearest first needs every hunter's bid, and a hunter bids only once it is localized: wait
        # until each known hunter has broadcast a map position (at most ALLOCATION_GRACE seconds,
        # so a hunter that never localizes does not stop the hunt).
        unplaced = [h for h, r in self.hunter_robots.items() if r and r not in self.positions]
        if unplaced:
            now = clock().now()
            self._waiting_since = now if self._waiting_since is None else self._waiting_since
            if now - self._waiting_since < ALLOCATION_GRACE:
                log.debug("%s: waiting for the positions of %s", self.id, ", ".join(unplaced))
                return
        share = math.ceil(len(self.hunters) / len(prey))
        if not self.prey:  # the auctioneer hunts too: the nearest prey short of hunters
            me = self.nav.position
            open_ = [p for p in prey if len(self._assigned.get(p, ())) < share]
            if me is not None and open_:
                mine = min(open_, key=lambda p: (math.hypot(self.positions[p].x - me.x, self.positions[p].y - me.y), p))
                self._assigned.setdefault(mine, set()).add(self.id)
                self._chase(mine)
        for p in sorted(prey, key=lambda p: (len(self._assigned.get(p, ())), p)):
            if p not in self._auctioning and len(self._assigned.get(p, ())) < share:
                self._auctioning.add(p)
                self.host.spawn(self._auction(p), f"{self.id}: cfp {p}")

    async def _auction(self, prey: str) -> None:
        """One cfp for one place on ``prey`` among the hunters not yet given a prey."""
        try:
            busy = set().union(*self._assigned.values())
            others = [h for h in self.hunters if h != self.id and h not in busy]
            pos = self.positions.get(prey)
            if not others or pos is None:
                return
            res = await self._initiator.call(
                {"prey": prey, "x": pos.x, "y": pos.y}, deadline=BID_WINDOW, participants=others, done_deadline=5.0
            )
            if res.ok and prey not in self.caught:
                log.info("%s: %s goes after %s (%.1f m away)", self.id, res.winner, prey, res.cost)
                self._assigned.setdefault(prey, set()).add(res.winner)
        finally:
            self._auctioning.discard(prey)

    # ------------------------------------------------------------------ the chase
    async def step(self) -> None:
        await super().step()
        now = clock().now()
        prey = self.prey
        if not prey or prey in self.caught or self.nav is None:
            return
        target = self.positions.get(prey)
        me = self.nav.position
        if target is None or me is None:
            return
        d = math.hypot(target.x - me.x, target.y - me.y)
        if d > self.sight:  # out of sight: wait for it at a station
            self._ambush(prey, me, now)
            return
        self.seen[prey] = (target.x, target.y)
        if self.watching is not None:
            log.info("%s: %s in sight (%.1f m); chasing", self.id, prey, d)
            self.watching = None
            self._watch_sent = False
            self._chase_goal = None
            self._last_plan = -math.inf
        if d <= self.capture_distance and self._sure_where(now):
            text = f"prey {prey} caught by {self.robot} after {now - self._hunt_start:.1f} s"
            log.info("%s: %s", self.id, text)
            self.caught[prey] = text
            self.catches += 1
            self.publish(Outcome.SERVICE, Outcome("caught", prey, text))
            self._end_chase()
            return
        # plan for where the prey is now (its track between broadcasts), not where it last said it was
        target = self.tracks.predict(prey, now) or target
        d = math.hypot(target.x - me.x, target.y - me.y)
        g = self._chase_goal  # the prey's position the current goal was made from
        moved = g is None or math.hypot(target.x - g.x, target.y - g.y) > self.replan_distance
        idle = self.goal_state != "driving"
        if (moved or idle) and now - self._last_plan >= self.replan_interval:
            self._last_plan = now
            # The prey's own spot may be refused (too close to a wall for the planner's clearance):
            # then aim 0.4 m nearer to the hunter per refusal in a row, up to 1.6 m.
            if self.goal_state == "unreachable":
                self._backoff = min(self._backoff + 1, 4)
            elif self.goal_state in ("driving", "done"):
                self._backoff = 0
            back = min(0.4 * self._backoff, max(0.0, d - 0.3))
            heading = math.atan2(target.y - me.y, target.x - me.x)
            goal = Position(target.x - back * math.cos(heading), target.y - back * math.sin(heading), heading)
            self._chase_goal = Position(target.x, target.y, heading)
            self._goal_task = self.start_goal(goal, report=False)

    def _ambush(self, prey: str, me: Position, now: float) -> None:
        """The prey is out of sight: go and wait in front of the station it is likeliest to visit."""
        if not self._looked:
            return  # who else hunts decides which station is this hunter's: wait for the first hello round
        station = watch_station(self.stations, self.seen.get(prey), self.hunters, self.id)
        if station is None:
            return
        if station != self.watching:
            log.info("%s: %s out of sight; waiting at station %s", self.id, prey, station.name)
            self.watching = station
            self._watch_sent = False
            self._last_plan = -math.inf
        if self._watch_sent and self.goal_state in ("driving", "done"):
            return  # on the way, or there: wait
        if now - self._last_plan < self.replan_interval:
            return  # a refused or aborted watch goal is tried again once per interval
        self._last_plan = now
        self._chase_goal = None  # the goal is the watch point, not a prey position
        self._watch_sent = True
        self._goal_task = self.start_goal(watch_point(station, self.watch_distance), report=False)

    def pose_sd(self) -> float | None:
        """The localizer's position standard deviation (m): the square root of the larger eigenvalue
        of the covariance's x-y block; None while there is no localize device or no estimate."""
        loc = self.nav.localize if self.nav is not None else None
        cov = loc.covariance() if loc is not None else None
        if cov is None:
            return None
        xy = cov[:2, :2]
        if not np.all(np.isfinite(xy)):
            return math.inf
        return math.sqrt(max(float(np.linalg.eigvalsh(0.5 * (xy + xy.T))[-1]), 0.0))

    def _sure_where(self, now: float) -> bool:
        """Whether the hunter's localization is certain enough to claim a catch (``max_pose_sd``)."""
        sd = self.pose_sd()
        if sd is None or sd <= self.max_pose_sd:
            return True
        if now - self._unsure_said >= 60.0:
            self._unsure_said = now
            log.warning(
                "%s: within %.1f m of %s, but not claiming the catch: localization standard deviation "
                "%.2f m is above max_pose_sd %.2f m; chasing on until it settles",
                self.id,
                self.capture_distance,
                self.prey,
                sd,
                self.max_pose_sd,
            )
        return False

    def status(self) -> str:
        line = super().status()
        if self.prey and self.watching is not None:
            chase = f"waiting for {self.prey} at station {self.watching.name}"
        elif self.prey:
            chase = f"chasing {self.prey}"
        elif self.allocation == "fixed":
            chase = f"hunt over ({self.caught.get(next(iter(self.prey_robots)), 'prey gone')})"
        else:
            chase = "free"
        return f"{line}  {chase}, caught {self.catches}"


@agent_class("EscapeAgent")
class EscapeAgent(WallfollowAgent):
    """The prey of the hunting scenario (thesis 4.2.1): wall-follows, keeping the wall on its right,
    and broadcasts its position so that hunters can chase it. ``speed`` (m/s) is its cruise speed
    (default: the Pioneer behaviour's, 0.4 m/s). When an ``outcome`` ``caught`` about its robot
    arrives it stops wall-following and spins in place at ``spin_rate`` rad/s ("the prey spins")."""

    side = "right"
    capabilities = ("send_position", "prey")

    def __init__(
        self,
        agent_id: str,
        *,
        speed: float | None = None,
        spin_rate: float = 0.8,
        **kw,
    ):
        super().__init__(agent_id, **kw)
        if speed is not None and (isinstance(speed, bool) or not isinstance(speed, int | float) or not 0 < speed <= 2):
            raise ValueError(f"agent {agent_id}: speed {speed!r} must be a number in (0, 2] m/s")
        if isinstance(spin_rate, bool) or not isinstance(spin_rate, int | float) or not 0 < spin_rate <= 3:
            raise ValueError(f"agent {agent_id}: spin_rate {spin_rate!r} must be a number in (0, 3] rad/s")
        self.speed = None if speed is None else float(speed)
        self.spin_rate = float(spin_rate)
        self.caught_by: str | None = None  # the agent that reported the catch

    def configure(self, robot: Pioneer) -> None:
        if self.speed is not None:
            robot.behaviour.p.cruise_speed = min(robot.behaviour.p.cruise_speed, self.speed)
        super().configure(robot)

    async def created(self) -> None:
        await super().created()
        self.subscribe(Outcome.SERVICE, self._on_caught, filter=match(event="caught", subject=self.robot))

    def _on_caught(self, msg) -> None:
        if self.caught_by is not None or self.pioneer is None:
            return
        self.caught_by = msg.sender
        log.info("%s: %s; spinning", self.id, msg.body.text)
        self.pioneer.set_command(0.0, self.spin_rate)  # also ends the wall-following

    def status(self) -> str:
        line = super().status()
        return f"{line}  caught by {self.caught_by}, spinning" if self.caught_by else line
