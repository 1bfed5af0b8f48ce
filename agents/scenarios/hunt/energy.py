"""Hunt and Prey with energy stations (thesis 4.2.1, "An Advanced Hunt and Prey Scenario").

The thesis proposes the extension in one sentence: the prey's "main goal would be exploration; a
second goal might be gathering beneficial objects such as energy stations to regain battery life".
This module holds that prey:

* :func:`recharge_mode` -- the prey's recharge decision, a pure function of its mode and its battery
  (``power:0``): ``flee`` (wall-following) until the charge falls below ``threshold``, then ``seek``
  (drive to the nearest station), ``charge`` once the station charges it, and ``flee`` again at
  ``target``. Pushed off a station before ``target`` it seeks again.
* :func:`steer` -- how the prey gets to the nearest station (:func:`.stations.nearest_station`):
  straight for it on its odometry (anchored in the map frame, as the thesis's EscapeAgent, without
  planner or localization), with the Pioneer's obstacle avoidance still acting on the command.

The hunters' side -- waiting at the stations while the prey is out of sight -- is
:class:`~agents.scenarios.hunt.agents.FollowAgent`'s ``sight`` with :mod:`.stations`. Notes:
``docs/scenarios/hunt_prey.md``, "With energy stations".
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Sequence

from agents.dispatch import Charger
from agents.navigation import number_arg as _number
from agents.registry import agent_class
from rsal.data import Position

from .agents import EscapeAgent
from .stations import nearest_station, station_arg, stations_from_simulation

__all__ = ["EnergyEscapeAgent", "recharge_mode", "steer"]

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


def steer(pose: Position, x: float, y: float, speed: float, *, turn: float = 0.8) -> tuple[float, float]:
    """A (v m/s, w rad/s) command that drives from ``pose`` onto ``(x, y)``: turn towards it at up to
    ``turn`` rad/s, go forward only while roughly facing it, slowing down over the last metre."""
    dist = math.hypot(x - pose.x, y - pose.y)
    err = math.remainder(math.atan2(y - pose.y, x - pose.x) - pose.yaw, math.tau)
    w = max(-turn, min(turn, 2.0 * err))
    v = speed * max(0.0, math.cos(err)) ** 2 * min(1.0, dist)
    return v, w


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
