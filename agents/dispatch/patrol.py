"""Surveillance patrol on the dispatcher (thesis 5.4): routes kept patrolled around the clock.

The thesis's outlook has surveillance robots that "maintain their battery charge state ... by
heading to a recharging point when necessary". :class:`PatrolAgent` keeps one ``patrol`` task per
route with the fabric's :class:`~agents.dispatch.agent.DispatcherAgent`: it submits every route
at the start and again whenever its task ends (done or failed), so the routes stay covered while
the dispatcher moves work away from robots that go to charge. :func:`revisit_gaps` is the
coverage figure, computed from ground truth (true poses over time): for every route point the
longest time between two visits (a visit: a robot's centre within ``radius`` of the point).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from ..registry import agent_class
from ..runtime import Agent
from ..services import Message, Outcome
from .tasks import TaskRefused, TaskRequest, TaskState, TaskStatus, parse_task

__all__ = ["PatrolAgent", "revisit_gaps", "parse_routes"]

log = logging.getLogger(__name__)


def parse_routes(routes: Sequence, where: str) -> list[list[list[float]]]:
    """Routes ``[[[x, y], ...], ...]``, each validated as a patrol task; ValueError with one line."""
    if not isinstance(routes, (list, tuple)) or not routes:
        raise ValueError(f"{where}: routes must list one or more routes [[[x, y], ...], ...], got {routes!r}")
    out = []
    for i, r in enumerate(routes):
        try:
            t = parse_task({"id": f"route{i}", "kind": "patrol", "args": {"route": r}})
        except TaskRefused as e:
            raise ValueError(f"{where}: routes[{i}]: {e}") from None
        out.append(t.args["route"])
    return out


def revisit_gaps(
    times: np.ndarray, poses: np.ndarray, points: np.ndarray, *, radius: float = 0.6, start: float | None = None
) -> np.ndarray:
    """Per point, the longest time (s) without a visit. ``times`` (T,), ``poses`` (T, R, 2) true
    robot positions, ``points`` (P, 2). The gap runs from ``start`` (default the first time) to the
    first visit, between visits, and from the last visit to the end."""
    times = np.asarray(times, dtype=float)
    poses = np.asarray(poses, dtype=float).reshape(len(times), -1, 2)
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    d = np.linalg.norm(poses[:, :, None, :] - points[None, None, :, :], axis=-1)  # (T, R, P)
    seen = (d <= radius).any(axis=1)  # (T, P)
    t0 = times[0] if start is None else start
    gaps = np.empty(len(points))
    for p in range(len(points)):  # one vector op per point
        at = np.concatenate([[t0], times[seen[:, p]], [times[-1]]])
        gaps[p] = float(np.max(np.diff(at))) if len(at) > 1 else float(times[-1] - t0)
    return gaps


@agent_class("PatrolAgent")
class PatrolAgent(Agent):
    """Keeps one ``patrol`` task per route of ``routes`` with the dispatcher (``laps`` per task)."""

    capabilities = ("task_request", "outcome")

    def __init__(self, agent_id: str, *, robot: str = "", period: float = 1.0, routes: Sequence = (), laps: int = 1):
        super().__init__(agent_id, period=period, robot=robot)
        self.routes = parse_routes(routes, f"agent {agent_id}")
        if isinstance(laps, bool) or not isinstance(laps, int) or laps < 1:
            raise ValueError(f"agent {agent_id}: laps {laps!r} must be a whole number >= 1")
        self.laps = laps
        self.current: dict[int, str] = {}  # route index -> its open task id
        self.rounds = [0] * len(self.routes)
        self.completed = [0] * len(self.routes)
        self._due: set[int] = set(range(len(self.routes)))
        self._dispatcher = False

    async def created(self) -> None:
        self.subscribe(TaskStatus.SERVICE, self._on_state)

    def _on_state(self, msg: Message) -> None:
        try:
            st = TaskStatus.from_dict(msg.body)
        except Exception:
            return
        if st.requester != self.id:
            return
        route = next((i for i, t in self.current.items() if t == st.task_id), None)
        if route is None or not TaskState(st.state).final:
            return
        del self.current[route]
        if st.state == TaskState.DONE.value:
            self.completed[route] += 1
            self.publish(
                Outcome.SERVICE, Outcome("patrolled", f"route{route}", f"route {route} patrolled by {st.robot}")
            )
        else:
            log.warning(
                "%s: route %d's task %s %s (%s): submitting it again", self.id, route, st.task_id, st.state, st.text
            )
        self._due.add(route)

    async def step(self) -> None:
        if not self._dispatcher:
            self._dispatcher = any(h.cls == "DispatcherAgent" for h in await self._require_host().who_is_there(0.5))
            if not self._dispatcher:
                return
        for i in sorted(self._due):
            self.rounds[i] += 1
            tid = f"{self.id}-route{i}-{self.rounds[i]}"
            self.current[i] = tid
            task = {"id": tid, "kind": "patrol", "args": {"route": self.routes[i], "laps": self.laps}}
            self.publish(TaskRequest.SERVICE, TaskRequest("submit", task=task))
        self._due.clear()

    def status(self) -> str:
        return f"routes patrolled {self.completed}, open tasks {len(self.current)}"
