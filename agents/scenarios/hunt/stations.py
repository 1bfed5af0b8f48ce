"""The energy stations of Hunt and Prey (thesis 4.2.1, "An Advanced Hunt and Prey Scenario"): where
they are and which one a robot goes to.

Stations are :class:`agents.dispatch.Charger` records (name and map pose), given as
``[{name, pose: [x, y, degrees]}]`` (:func:`station_arg`, the dispatcher's
:func:`agents.dispatch.agent.parse_chargers`) or read from the simulation's ``describe``
``chargers`` (:func:`stations_from_simulation`) by agents "aware of a simulation environment"
(thesis 3.6.2.2). The prey goes to the :func:`nearest_station`; a hunter whose prey is out of sight
waits at the station :func:`watch_station` gives it -- the stations ordered by their distance to
where the prey was last seen, hunter *k* (by id) watching the *k*-th -- at :func:`watch_point`,
``watch_distance`` in front of it (a charger's yaw points away from its wall, into the room).
Notes: ``docs/scenarios/hunt_prey.md``, "With energy stations".
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from agents.dispatch import Charger
from agents.dispatch.agent import parse_chargers
from rsal.data import Position

__all__ = ["nearest_station", "station_arg", "stations_from_simulation", "watch_point", "watch_station"]


def nearest_station(stations: Sequence[Charger], x: float, y: float) -> Charger | None:
    """The station nearest (straight line) to ``(x, y)``; ties: the smaller name."""
    return min(stations, key=lambda s: (math.hypot(s.x - x, s.y - y), s.name), default=None)


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
