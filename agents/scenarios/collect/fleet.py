"""Find and Collect with energy: collectors that work for the fleet dispatcher (thesis 4.2.2 with
the energy of 4.2 and 5.4; docs/scenarios/find_collect.md, "With energy").

:class:`FleetCollectAgent` is a :class:`~agents.scenarios.collect.collector.CollectAgent` (the
gripper fetch of the thesis's collectors) and a :class:`~agents.dispatch.agent.FleetWorker` (bids,
queue, status with its battery): the master submits every blob as a ``fetch`` task to the
dispatcher (:mod:`agents.dispatch`, ``allocation: dispatch`` of
:class:`~agents.scenarios.collect.master.MasterAgent`), the dispatcher awards it to the cheapest
collector and sends collectors whose charge fell below its threshold to a charger until they reach
its target. Charging is the dispatcher's (its ``charge`` tasks, :meth:`FleetWorker.wait_charged`);
nothing of it is repeated here.
"""

from __future__ import annotations

import asyncio
import logging
import math

from agents.dispatch.agent import FleetWorker
from agents.dispatch.tasks import Task, task_places
from agents.registry import agent_class
from rsal.clock import clock
from rsal.data import Position

from .collector import CollectAgent

__all__ = ["FleetCollectAgent"]

log = logging.getLogger(__name__)


@agent_class("FleetCollectAgent")
class FleetCollectAgent(FleetWorker, CollectAgent):
    """A collector that bids for and performs dispatcher tasks: ``fetch`` grips the object at
    ``at`` and puts it down at ``to`` (:meth:`CollectAgent.fetch`), ``charge`` drives onto the
    charger and waits until the battery reaches the task's target, ``go_to``/``patrol``/``custom``
    drive to their places. ``speed`` m/s for its bids; ``threshold``/``target``: the dispatcher's
    charging policy, for its bids; ``status_every`` s between ``fleet`` status reports;
    ``charge_timeout`` s it waits on a charger."""

    capabilities = ("send_position", "collect", "fleet")

    speed_default = 0.3
    charge_timeout_default = 3600.0

    async def created(self) -> None:
        await CollectAgent.created(self)
        await asyncio.to_thread(self.find_power)
        self.start_worker()

    def where(self) -> tuple[float, float] | None:
        p = self.pioneer.position if self.pioneer is not None else None
        return (p.x, p.y) if p is not None else None

    def places_left(self) -> list[tuple[float, float]]:
        """A fetch not yet gripped still visits the object, then its destination."""
        t = self.active
        if t is not None and t.kind == "fetch" and not (self.pioneer is not None and self.pioneer.gripper.carrying):
            return [tuple(t.args["at"]), tuple(t.args["to"])]
        return FleetWorker.places_left(self)

    async def step(self) -> None:
        await CollectAgent.step(self)
        if self._wake is not None:  # its battery looked up and working: reports say so
            self.report_status()

    async def killed(self) -> None:
        self.stop_worker()
        await CollectAgent.killed(self)

    async def abandon(self, task: Task) -> None:
        await self._safe_stop()

    async def perform(self, task: Task) -> str:
        """Do ``task``; returns ``""`` when done, else why not."""
        a = task.args
        if task.kind == "fetch":
            (x, y), (hx, hy) = a["at"], a["to"]
            res = await self.fetch(str(a["object"]), float(x), float(y), home=Position(float(hx), float(hy)))
            return "" if res.ok else res.reason
        for x, y in task_places(task):
            yaw = float(a.get("yaw", 0.0)) if task.kind in ("go_to", "charge") else 0.0
            self.task_state = f"{task.kind} to ({x:.1f}, {y:.1f})"
            err = await self._goto(Position(x, y, yaw))
            if err:
                return err
        if task.kind == "custom":
            await clock().asleep(float(a.get("duration", 0.0)))
        elif task.kind == "charge":
            self.task_state = f"charging at {a.get('charger') or 'a charger'}"
            try:
                return await self.wait_charged(task, self.charge_timeout)
            finally:
                self.task_state = "idle"
        self.task_state = "idle"
        return ""

    def status(self) -> str:
        b = self.battery()
        bat = f"  battery {b:.0%}{' charging' if self.charging() else ''}" if b is not None and math.isfinite(b) else ""
        return CollectAgent.status(self) + bat
