"""Ground-truth verdicts of ``rsal run``: what the agents claim, checked against the simulator.

The design's rule: verdicts come from ground truth or from authenticated peers, never from a message
any peer could have sent. An agent's ``outcome`` is a claim made from its own beliefs (an AMCL pose,
another agent's broadcast); when the application runs a simulator, :class:`GroundTruth` asks the
simulation device (``sim:simulation:0``, rpc ``get_pose``; the thesis's ``getPositionOf``) where
the robots really are at the moment a claim arrives, and the runner counts it only if the truth
agrees:

- ``caught`` (subject: the prey's robot; sender: a hunter agent with a robot): the hunter's robot
  truly within its ``capture_distance`` (the agent's argument, else its class's default) plus
  :data:`CATCH_SLACK` of the prey; for a prey that recharges (its class offers ``recharge``: Hunt and
  Prey with energy stations) the note adds its true distance to the nearest station (the
  simulation's ``describe`` ``chargers``; "at a station" within :data:`NEAR_STATION`), its true
  charge at the catch and whether it truly charged or ran flat before -- from its robot's
  ``power:0``, which the simulator's battery model drives (:class:`EnergyTruth`, every sample);
- ``arrived`` with a place (``Outcome.at``, the goal): the subject robot truly within
  :data:`ARRIVE_TOLERANCE` of it;
- an ok final ``verdict`` after ``assigned`` outcomes with places (Distribution, thesis 4.2.4):
  every assigned robot truly within :data:`ARRIVE_TOLERANCE` of its last assigned target;
- ``delivered`` (Find and Collect, thesis 4.2.2; subject: the master's blob id): one more object
  of a collector's world (not a robot, not a proxy) than there were deliveries before truly lies
  within :data:`DELIVER_TOLERANCE` of a collector's home -- its ``home`` argument, else where its
  robot truly stood when the agents were started (:meth:`GroundTruth.record_homes`); collectors
  that are no robot of any simulated world (real robots, of which the virtual world has a proxy at
  most) are not judged, and a delivery no collector can be judged for is let stand, with a note;
- a ``duration`` run with ``end.travel`` / ``end.clearance``: the true poses of every agent's robot,
  sampled every :data:`SAMPLE_PERIOD` seconds, must add up to at least ``travel`` metres each and
  keep the robot's centre at least ``clearance`` metres from every occupied cell of the map
  (``sim:map:0``, its Euclidean distance transform, ``scipy.ndimage.distance_transform_edt``);
- ``end.never_flat`` / ``end.charged`` (energy): the simulation's own battery record of every
  agent's robot (rpc ``batteries``: the lowest charge, the seconds spent empty and the joules
  gained while charging, kept on every simulation step, so no moment between samples is missed):
  no robot may ever have run empty, and at least ``charged`` robots must have truly charged
  (gained at least :data:`CHARGED_FRACTION` of their capacity docked at a charger).

A claim the truth contradicts counts as a failed outcome, with the reason in one line.

A robot rehearsed on emulated hardware (the application's ``rehearse`` section) lives in "the real
world", the rehearsal's world: its true pose, and the bins a collector of it fetches, are asked of
that world's simulation device (``<node>:simulation:0``), every other robot's of the simulator's.
"""

from __future__ import annotations

import inspect
import math

from .scenario import Application, Scenario

__all__ = [
    "ARRIVE_TOLERANCE",
    "CATCH_SLACK",
    "CHARGED_FRACTION",
    "DELIVER_TOLERANCE",
    "NEAR_STATION",
    "SAMPLE_PERIOD",
    "EnergyTruth",
    "GroundTruth",
]

#: m beyond the capture distance a true catch may lie: the hunter judges on its AMCL pose (the
#: thesis's 0.30 m) against the prey's last broadcast (2 Hz at 0.2 m/s: 0.1 m old at most), and the
#: fleeing prey moves on while the outcome travels (0.1 m)
CATCH_SLACK = 0.5
#: m between a robot that arrived and its goal: Wavefront's 0.4 m goal tolerance plus the thesis's
#: 0.30 m localization requirement
ARRIVE_TOLERANCE = 0.7
#: m between a delivered bin and its collector's home (the thesis's Find and Collect brings the
#: blob "home"; the collector stops within Wavefront's 0.4 m of it and puts the bin down in front)
DELIVER_TOLERANCE = 1.0
#: m between a caught prey and a station for the catch to count as "at a station": a hunter waiting
#: in ambush stands ``watch_distance`` (1.5 m) in front of it and catches within 1 m
NEAR_STATION = 2.5
#: seconds between true-pose samples of a duration run
SAMPLE_PERIOD = 0.5
#: fraction of its capacity a robot must have gained on chargers to count as truly charged (a robot
#: that only drove across a charger gains a trace)
CHARGED_FRACTION = 0.1
SIM_DEVICE = "sim:simulation:0"
MAP_DEVICE = "sim:map:0"


def _default(cls_name: str, arg: str) -> float | None:
    """The default of ``arg`` in the constructor of the agent class ``cls_name`` (None if it has none)."""
    from .registry import resolve

    try:
        p = inspect.signature(resolve(cls_name)).parameters.get(arg)
    except Exception:
        return None
    return None if p is None or p.default is inspect.Parameter.empty else p.default


class EnergyTruth:
    """The true battery record of one robot: every ``power:0`` sample the simulator publishes for it
    (the simulator's battery model, not the agent's belief) through ``device`` (a
    :class:`rsal.interfaces.power.Power`-like proxy: ``add_listener``, ``latest``)."""

    def __init__(self, device):
        self.device = device
        self.charged = False  # a sample said charging
        self.flat = False  # a sample said 0 %
        self.lowest = math.inf  # lowest percent seen
        device.add_listener(self._on_data)

    def _on_data(self, m) -> None:
        self.charged |= bool(m.charging)
        self.flat |= m.percent <= 0.0
        self.lowest = min(self.lowest, float(m.percent))

    def describe(self) -> str:
        m = self.device.latest
        if m is None:
            return "true battery unknown (no power:0 data)"
        seen = f"charged before: {'yes' if self.charged else 'no'}, ran flat: {'yes' if self.flat else 'no'}"
        return f"true battery {m.percent:.0f} %{' charging' if m.charging else ''} ({seen}, lowest {self.lowest:.0f} %)"


def _capabilities(cls_name: str) -> tuple:
    from .registry import resolve

    try:
        return tuple(getattr(resolve(cls_name), "capabilities", ()))
    except Exception:
        return ()


class GroundTruth:
    """Checks ``app``'s outcomes against the simulator on the runner's ``session``."""

    def __init__(self, session, sc: Scenario, app: Application, *, sim=None, get_map=None, real=None, power=None):
        """``sim`` (a :class:`rsal.interfaces.simulation.Simulation`-like ``get_pose``, ``models`` and
        ``describe``), ``real`` (the same for a rehearsal's world), ``get_map`` (returns a
        :class:`rsal.interfaces.map.MapData`) and ``power`` (robot -> a ``power:0``-like proxy)
        replace the devices on ``session`` (tests)."""
        self.fabric = None
        recharging = [a.robot for a in app.agents if a.robot and "recharge" in _capabilities(a.cls)]
        if (
            sim is None
            or get_map is None
            or (app.rehearse is not None and real is None)
            or (recharging and power is None)
        ):
            from rsal.client import Fabric

            self.fabric = Fabric(session, own_session=False)
        self.sim = sim or self.fabric.device(SIM_DEVICE)
        #: robot -> the simulation device of its world (a rehearsed robot's: the real world)
        self.world_of: dict[str, object] = {}
        if app.rehearse is not None:
            r = app.rehearse
            self.world_of[r.robot] = real or self.fabric.device(f"{r.node}:simulation:0")
        self.get_map = get_map or (lambda: self.fabric.device(MAP_DEVICE).get_map(timeout=10.0))
        self.sc, self.app, self.end = sc, app, app.end
        self.agents = {a.id: a for a in app.agents}
        self.robots = sorted({a.robot for a in app.agents if a.robot})
        self.assigned: dict[str, tuple[float, float]] = {}  # robot -> its last assigned target
        self.note = ""  # what the truth showed for the last confirmed verdict
        self.travelled: dict[str, float] = {}
        self.nearest_wall: dict[str, float] = {}
        self._last: dict[str, tuple[float, float]] = {}
        self._clear: tuple | None = None  # (distance grid m, origin, resolution)
        self.homes: dict[str, tuple[float, float]] = {}  # collector robot -> its home
        self.delivered = 0  # deliveries the truth confirmed
        get_power = power or (lambda robot: self.fabric.device(f"{robot}:power:0"))
        #: robot -> its true battery record, for the prey that recharge (subscribed from the start)
        self.energy: dict[str, EnergyTruth] = {r: EnergyTruth(get_power(r)) for r in recharging}
        self._stations: list[tuple[str, float, float]] | None = None
        self.batteries: dict[str, dict] = {}  # robot -> its latest battery record (energy ends)

    @property
    def samples(self) -> bool:
        """Whether the run samples the truth: poses (``end.travel``, ``end.clearance``) or batteries (energy)."""
        return self.poses or self.judges_energy

    @property
    def poses(self) -> bool:
        return self.end.travel is not None or self.end.clearance is not None

    @property
    def judges_energy(self) -> bool:
        return self.end.never_flat or self.end.charged > 0

    def _world(self, robot: str):
        return self.world_of.get(robot, self.sim)

    def _where(self, robot: str) -> tuple[float, float]:
        p = self._world(robot).get_pose(robot)
        return p.x, p.y

    def collectors(self) -> list:
        """The agents that fetch things home (their class offers ``collect``), with a robot."""
        from .registry import resolve

        out = []
        for a in self.app.agents:
            try:
                caps = getattr(resolve(a.cls), "capabilities", ())
            except Exception:
                continue
            if a.robot and "collect" in caps:
                out.append(a)
        return out

    def record_homes(self) -> None:
        """Each collector's home: its ``home`` argument, else its robot's true pose now (called
        before the agents start). A world that does not answer leaves that home unknown."""
        for a in self.collectors():
            home = a.args.get("home", self.sc.arguments.get("home"))
            try:
                self.homes[a.robot] = (float(home[0]), float(home[1])) if home else self._where(a.robot)
            except Exception:  # judged as unavailable when a delivery is claimed
                pass

    # ------------------------------------------------------------------ claims
    def check(self, sender: str, o) -> str | None:
        """Why the outcome ``o`` from ``sender`` is false by ground truth, or None (true, or not a
        claim the truth can judge); a confirmed verdict leaves what the truth showed in ``note``."""
        self.note = ""
        try:
            if o.event == "assigned" and o.at is not None:
                self.assigned[o.subject] = o.at
            elif o.event == "caught" and o.ok:
                return self._caught(sender, o)
            elif o.event == "delivered" and o.ok and self.collectors():
                return self._delivered(o)
            elif o.event == "arrived" and o.ok and o.at is not None:
                d = math.dist(self._where(o.subject), o.at)
                if d > ARRIVE_TOLERANCE:
                    where = f"{d:.2f} m from its goal {_xy(o.at)}"
                    return f"ground truth: {o.subject} is {where} (> {ARRIVE_TOLERANCE:g} m)"
            elif o.event == "verdict" and o.final and o.ok and self.assigned:
                far, seen = [], []
                for robot, at in sorted(self.assigned.items()):
                    d = math.dist(self._where(robot), at)
                    seen.append(f"{robot} {d:.2f} m")
                    if d > ARRIVE_TOLERANCE:
                        far.append(f"{robot} {d:.2f} m from {_xy(at)}")
                if far:
                    return f"ground truth: not at the assigned target (> {ARRIVE_TOLERANCE:g} m): {', '.join(far)}"
                self.note = f"ground truth: {', '.join(seen)} from the assigned targets"
        except Exception as e:  # the simulation did not answer: no verdict on beliefs either
            return f"ground truth unavailable for {o.event} {o.subject!r}: {type(e).__name__}: {e}"
        return None

    def _caught(self, sender: str, o) -> str | None:
        hunter = self.agents.get(sender)
        if hunter is None or not hunter.robot:
            return None
        cap = hunter.args.get("capture_distance", self.sc.arguments.get("capture_distance"))
        if cap is None:
            cap = _default(hunter.cls, "capture_distance")
        if cap is None:
            return None
        d = math.dist(self._where(hunter.robot), self._where(o.subject))
        if d > cap + CATCH_SLACK:
            return (
                f"ground truth: {hunter.robot} is {d:.2f} m from the prey {o.subject} "
                f"(capture distance {cap:g} m + {CATCH_SLACK:g} m)"
            )
        self.note = f"ground truth: {hunter.robot} {d:.2f} m from {o.subject} at the catch"
        if o.subject in self.energy:
            self.note += f"; {self._energy_note(o.subject)}"
        return None

    def _energy_note(self, prey: str) -> str:
        """Where the caught ``prey`` truly is against the stations, and its true battery."""
        if self._stations is None:
            geo = self.sim.describe(timeout=5.0).geometry
            self._stations = [(c["name"], float(c["pose"][0]), float(c["pose"][1])) for c in geo.get("chargers", [])]
        x, y = self._where(prey)
        near = min(((math.dist((x, y), (sx, sy)), n) for n, sx, sy in self._stations), default=None)
        if near is None:
            where = "no station in the world"
        else:
            at = "at" if near[0] <= NEAR_STATION else "away from"
            where = f"{at} a station ({near[0]:.1f} m from {near[1]})"
        return f"{prey} {where}, {self.energy[prey].describe()}"

    def _delivered(self, o) -> str | None:
        """One more bin than confirmed before must truly lie within DELIVER_TOLERANCE of a home."""
        robots = {a.robot for a in self.app.agents if a.robot}
        near, nearest, judged = set(), (math.inf, "", ""), 0
        for a in self.collectors():
            world = self._world(a.robot)
            models = world.models()
            if a.robot not in models.get("robots", []):  # a real robot (its proxy at most): no truth here
                continue
            if a.robot not in self.homes:
                return f"ground truth: {a.robot}'s home is unknown (its world did not answer at the start)"
            judged += 1
            home = self.homes[a.robot]
            for name in models.get("objects", []):
                if name in robots:  # a proxy of a real robot, not a bin
                    continue
                d = math.dist(self._where_in(world, name), home)
                if d <= DELIVER_TOLERANCE:
                    near.add((id(world), name))
                if d < nearest[0]:
                    nearest = (d, name, a.robot)
        if not judged:
            self.note = "ground truth: no collector lives in a simulated world; the delivery is not judged"
            return None
        if len(near) <= self.delivered:
            d, name, robot = nearest
            closest = f"; nearest: {name} {d:.2f} m from {robot}'s home {_xy(self.homes[robot])}" if name else ""
            return (
                f"ground truth: {len(near)} bin(s) within {DELIVER_TOLERANCE:g} m of a collector's home "
                f"for {self.delivered + 1} deliveries{closest}"
            )
        self.delivered += 1
        self.note = f"ground truth: {len(near)} bin(s) within {DELIVER_TOLERANCE:g} m of a collector's home"
        return None

    @staticmethod
    def _where_in(world, name: str) -> tuple[float, float]:
        p = world.get_pose(name)
        return p.x, p.y

    # ------------------------------------------------------------------ duration runs
    def _load_clearance(self) -> None:
        from scipy.ndimage import distance_transform_edt

        m = self.get_map()
        dist = distance_transform_edt(m.cells != 1) * m.resolution
        self._clear = (dist, m.origin, m.resolution)

    def wall_distance(self, x: float, y: float) -> float:
        """Metres from (x, y) to the nearest occupied cell of the map (0 outside the map)."""
        dist, (ox, oy), res = self._clear
        col, row = int(math.floor((x - ox) / res)), int(math.floor((y - oy) / res))
        if not (0 <= row < dist.shape[0] and 0 <= col < dist.shape[1]):
            return 0.0
        return float(dist[row, col])

    def sample(self) -> None:
        """One true pose per robot: distance travelled and the nearest wall so far; the batteries'
        record when the end judges energy."""
        if self.judges_energy:
            record = self.sim.batteries()
            self.batteries = {r: record[r] for r in self.robots if r in record and record[r].get("battery")}
        if not self.poses:
            return
        if self.end.clearance is not None and self._clear is None:
            self._load_clearance()
        for r in self.robots:
            x, y = self._where(r)
            if r in self._last:
                self.travelled[r] = self.travelled.get(r, 0.0) + math.dist(self._last[r], (x, y))
            self._last[r] = (x, y)
            if self._clear is not None:
                self.nearest_wall[r] = min(self.nearest_wall.get(r, math.inf), self.wall_distance(x, y))

    def flat_robots(self) -> list[str]:
        """The robots whose battery truly ran empty (one line each)."""
        return [
            f"{r}'s battery ran empty (the simulation's record: lowest {b['lowest']:.0%}, {b['flat']:.1f} s empty)"
            for r, b in sorted(self.batteries.items())
            if b["flat"] > 0.0 or b["lowest"] <= 0.0
        ]

    def problems(self) -> list[str]:
        """What the sampled truth says against the run's ``travel``, ``clearance`` and energy."""
        out = self.flat_robots() if self.end.never_flat else []
        charged = [r for r, b in self.batteries.items() if b["charged"] >= CHARGED_FRACTION * b["capacity"] > 0.0]
        if len(charged) < self.end.charged:
            out.append(f"{len(charged)} robot(s) truly charged (< charged {self.end.charged})")
        for r in self.robots:
            if self.end.travel is not None and self.travelled.get(r, 0.0) < self.end.travel:
                out.append(f"{r} travelled {self.travelled.get(r, 0.0):.2f} m (< travel {self.end.travel:g} m)")
            if self.end.clearance is not None and self.nearest_wall.get(r, 0.0) < self.end.clearance:
                out.append(
                    f"{r} came {self.nearest_wall.get(r, 0.0):.2f} m from a wall (< clearance {self.end.clearance:g} m)"
                )
        return out

    def summary(self) -> str:
        parts = []
        for r in self.robots:
            bits = []
            if r in self.travelled:
                bits.append(f"travelled {self.travelled[r]:.1f} m")
            if r in self.nearest_wall:
                bits.append(f"nearest wall {self.nearest_wall[r]:.2f} m")
            b = self.batteries.get(r)
            if b is not None:
                bits.append(f"battery lowest {b['lowest']:.0%}, {b['flat']:.0f} s flat, charged {b['charged']:.0f} J")
            if bits:
                parts.append(f"{r} {', '.join(bits)}")
        return "; ".join(parts)

    def close(self) -> None:
        if self.fabric is not None:
            self.fabric.close()


def _xy(at) -> str:
    return f"({at[0]:.2f}, {at[1]:.2f})"
