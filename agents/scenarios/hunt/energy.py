"""Hunt and Prey with energy stations (thesis 4.2.1, "An Advanced Hunt and Prey Scenario").

The thesis proposes the extension in one sentence: the prey's "main goal would be exploration; a
second goal might be gathering beneficial objects such as energy stations to regain battery life".
This module holds that prey and the pieces the hunters' ambush shares with it:

* :func:`recharge_mode` -- the prey's recharge decision, a pure function of its mode and its battery
  (``power:0``): ``flee`` (wall-following) until the charge falls below ``threshold``, then ``seek``
  (drive to the nearest station), ``charge`` once the station charges it, and ``flee`` again at
  ``target``. Pushed off a station before ``target`` it seeks again.
* :func:`nearest_station`, :func:`steer` -- where the prey goes and how: straight for the station on
  its odometry (anchored in the map frame, as the thesis's EscapeAgent, without planner or
  localization), with the Pioneer's obstacle avoidance still acting on the command.
* :func:`watch_station`, :func:`watch_point` -- the hunters' ambush (used by
  :class:`~agents.scenarios.hunt.agents.FollowAgent` with a finite ``sight``): the stations ordered
  by their distance to where the prey was last seen, hunter *k* (by id) watches the *k*-th, from
  ``watch_distance`` in front of it (a charger's yaw points away from its wall, into the room).
* :func:`stations_from_simulation` -- the stations as the simulation's ``describe`` gives them
  (``chargers``), for agents "aware of a simulation environment" (thesis 3.6.2.2).

Stations are :class:`agents.dispatch.Charger` records, given as ``[{name, pose: [x, y, degrees]}]``
(:func:`agents.dispatch.parse_chargers`) like the dispatcher's. Notes:
``docs/scenarios/hunt_prey.md``, "With energy stations".
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Sequence

from agents.dispatch import Charger
from agents.dispatch.agent import parse_chargers
from agents.navigation import number_arg as _number
from agents.registry import agent_class
from rsal.data import Position

from .agents import EscapeAgent

__all__ = [
    "EnergyEscapeAgent",
    "nearest_station",
    "recharge_mode",
    "stations_from_simulation",
    "steer",
    "watch_point",
    "watch_station",
]

log = logging.getLogger(__name__)

MODES = ("flee", "seek", "charge")


def recharge_mode(mode: str, fraction: float, charging: bool, threshold: float, target: float) -> str:
    """The prey's next mode from ``mode`` and its battery: ``fraction`` (0..1) and ``charging``."""
    if mode == "flee":
        return "seek" if fraction < threshold else "flee"
    if mode == "seek":
        return "charge" if charging else "seek"
    # charging: done at target; pushed off the station (no longer charging) before it: seek again
    if fraction >= target:
        return "flee"
    return "charge" if charging else "seek"


def nearest_station(stations: Sequence[Charger], x: float, y: float) -> Charger | None:
    """The station nearest (straight line) to ``(x, y)``; ties: the smaller name."""
    return min(stations, key=lambda s: (math.hypot(s.x - x, s.y - y), s.name), default=None)


def steer(pose: Position, x: float, y: float, speed: float, *, turn: float = 0.8) -> tuple[float, float]:
    """A (v m/s, w rad/s) command that drives from ``pose`` onto ``(x, y)``: turn towards it at up to
    ``turn`` rad/s, go forward only while roughly facing it, slowing down over the last metre."""
    dist = math.hypot(x - pose.x, y - pose.y)
    err = math.remainder(math.atan2(y - pose.y, x - pose.x) - pose.yaw, math.tau)
    w = max(-turn, min(turn, 2.0 * err))
    v = speed * max(0.0, math.cos(err)) ** 2 * min(1.0, dist)
    return v, w


def watch_station(
    stations: Sequence[Charger], last_seen: tuple[float, float] | None, hunters: Sequence[str], me: str
) -> Charger | None:
    """The station hunter ``me`` watches: the stations ordered by distance to where the prey was
    ``last_seen`` (by name while it was never seen), the hunters by id; the *k*-th hunter takes
    the *k*-th station (round robin when there are more hunters than stations). A hunter that is
    not in ``hunters`` counts as the first."""
    if not stations:
        return None
    if last_seen is None:
        order = sorted(stations, key=lambda s: s.name)
    else:
        order = sorted(stations, key=lambda s: (math.hypot(s.x - last_seen[0], s.y - last_seen[1]), s.name))
    ids = sorted(set(hunters) | {me})
    return order[ids.index(me) % len(order)]


def watch_point(station: Charger, distance: float) -> Position:
    """Where a hunter waits for the prey at ``station``: ``distance`` m in front of it (along its
    yaw, away from the wall), facing the station."""
    x = station.x + distance * math.cos(station.yaw)
    y = station.y + distance * math.sin(station.yaw)
    return Position(x, y, math.remainder(station.yaw + math.pi, math.tau))


def stations_from_simulation(fabric, timeout: float = 10.0) -> list[Charger]:
    """The world's charging stations from the simulation's ``describe`` (``chargers``; a worker
    thread). Raises TimeoutError when no simulation device appears within ``timeout``."""
    node = fabric.node("*:simulation:0")
    found = node.wait_for("*:simulation:0", 1, timeout)
    geo = node.device(found[0]).describe(timeout=timeout).geometry
    return [Charger(str(c["name"]), *(float(v) for v in c["pose"][:3])) for c in geo.get("chargers", [])]


def station_arg(agent_id: str, stations) -> list[Charger]:
    """The ``stations`` argument: ``[{name, pose: [x, y, degrees]}]``; ValueError in one line."""
    if not isinstance(stations, list | tuple):
        raise ValueError(f"agent {agent_id}: stations {stations!r} must be a list of {{name, pose: [x, y, degrees]}}")
    return parse_chargers(stations, f"agent {agent_id}")


@agent_class("EnergyEscapeAgent")
class EnergyEscapeAgent(EscapeAgent):
    """The prey with a battery (thesis 4.2.1's advanced form): flees as :class:`EscapeAgent`, but
    below ``threshold`` (charge fraction) drives to the nearest energy station, charges there up to
    ``target`` and flees on. Stations: ``stations`` ``[{name, pose: [x, y, degrees]}]``, else the
    simulation's (``simulation: true``). It reads its charge from its robot's ``power:0``."""

    capabilities = ("send_position", "prey", "recharge")  # recharge: rsal run reports its true battery

    def __init__(
        self,
        agent_id: str,
        *,
        threshold: float = 0.5,
        target: float = 0.9,
        stations: Sequence | None = None,
        **kw,
    ):
        super().__init__(agent_id, **kw)
        self.threshold = _number(agent_id, "threshold", threshold, 0.0, 1.0)
        self.target = _number(agent_id, "target", target, 0.0, 1.0)
        if self.target <= self.threshold:
            raise ValueError(
                f"agent {agent_id}: target {target!r} must be above threshold {threshold!r} (e.g. 0.5 and 0.9)"
            )
        self.stations: list[Charger] = station_arg(agent_id, stations) if stations is not None else []
        if stations is None and not self.simulation:
            raise ValueError(f"agent {agent_id}: give the energy stations as stations: [...] or simulation: true")
        self.mode = "flee"
        self.station: Charger | None = None  # the station it is driving to or charging at
        self.charges = 0  # times it started charging
        self.power = None  # its robot's power:0 proxy

    async def created(self) -> None:
        await super().created()
        self.power = self.fabric.device(f"{self.robot}:power:0")
        if not self.stations:
            try:
                self.stations = await asyncio.to_thread(stations_from_simulation, self.fabric, self.startup_timeout)
            except TimeoutError:
                raise TimeoutError(
                    f"agent {self.id}: no simulation device appeared within {self.startup_timeout:g} s "
                    "to tell the energy stations; give them as stations: [{name, pose: [x, y, degrees]}]"
                ) from None
        if not self.stations:
            log.warning("%s: the world has no energy stations; fleeing until the battery runs flat", self.id)
        log.info("%s: %d energy station(s): %s", self.id, len(self.stations), ", ".join(s.name for s in self.stations))

    async def step(self) -> None:
        await super().step()
        r, p = self.pioneer, self.power
        if r is None or p is None or p.latest is None or self.caught_by is not None or not self.stations:
            return
        pose = r.position
        if pose is None:
            return
        new = recharge_mode(self.mode, p.fraction, bool(p.charging), self.threshold, self.target)
        if new != self.mode:
            self._enter(new, pose, p.fraction)
        if self.mode == "seek":
            s = self.station
            r.set_command(*steer(pose, s.x, s.y, self.speed or r.behaviour.p.cruise_speed))
        elif self.mode == "charge":
            r.set_command(0.0, 0.0)

    def _enter(self, mode: str, pose: Position, fraction: float) -> None:
        if mode == "seek":
            self.station = nearest_station(self.stations, pose.x, pose.y)
            log.info("%s: battery at %.0f %%; heading for station %s", self.id, 100 * fraction, self.station.name)
        elif mode == "charge":
            self.charges += 1
            log.info(
                "%s: charging at %s from %.0f %%", self.id, self.station.name if self.station else "?", 100 * fraction
            )
        else:
            log.info("%s: charged to %.0f %%; fleeing again", self.id, 100 * fraction)
            self.station = None
            self.pioneer.set_wallfollow(True, side=self.side)
        self.mode = mode

    def status(self) -> str:
        line = super().status()
        p = self.power
        battery = f"{p.percent:.0f} %" if p is not None and p.latest is not None else "battery ?"
        at = f" {self.station.name}" if self.station is not None else ""
        return f"{line}  {battery} {self.mode}{at}, charged {self.charges}x"
