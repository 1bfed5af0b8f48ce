"""A robot agent with no body for the dispatcher's tests: a :class:`~agents.dispatch.agent.FleetWorker`
that performs a task by waiting ``seconds`` (while its ``hold`` event is set) and keeps its own record
of what it performed and abandoned, the truth the dispatcher's reports are judged against."""

from __future__ import annotations

import asyncio

from agents.dispatch.agent import FleetWorker
from agents.dispatch.tasks import Task, task_places
from agents.runtime import Agent

__all__ = ["StandIn"]


class StandIn(FleetWorker, Agent):
    """At (``x``, ``y``) until a task moves it to its last place; ``robot`` defaults to the upper-case id."""

    def __init__(self, agent_id: str, x: float = 0.0, y: float = 0.0, seconds: float = 0.3, robot: str = ""):
        Agent.__init__(self, agent_id, period=0.1, robot=robot or agent_id.upper())
        self.init_worker(speed=0.5, threshold=0.2, target=0.9, status_every=0.2, agent_id=agent_id)
        self.pos = (x, y)
        self.seconds = seconds
        self.performed: list[str] = []
        self.abandoned: list[str] = []
        self.hold = asyncio.Event()  # cleared: a task under way waits (to cancel or forfeit it meanwhile)
        self.hold.set()

    async def created(self) -> None:
        self.start_worker()

    async def killed(self) -> None:
        self.stop_worker()

    def where(self):
        return self.pos

    async def step(self) -> None:
        self.report_status()

    async def perform(self, task: Task) -> str:
        self.heading_to = task_places(task)[0]
        await self.hold.wait()
        await asyncio.sleep(self.seconds)
        self.pos = task_places(task)[-1]
        self.performed.append(task.id)
        return ""

    async def abandon(self, task: Task) -> None:
        self.abandoned.append(task.id)
