"""The ``planner`` interface: a global planner (Player's ``planner``; the ``wavefront`` driver).

Message :class:`PlannerData` (``data``); proxy :class:`Planner`, whose goals are futures resolved
by the planner's events. Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass

from ..data import Position
from ..msgs import ErrorCode, RpcError, _Msg, _need, get_float, get_int, get_str, get_vec
from .base import Device, Interface

__all__ = ["PLANNER_STATUS", "PlannerData", "Planner", "INTERFACE"]


PLANNER_STATUS = ("idle", "driving", "done", "aborted", "invalid")


@dataclass(frozen=True)
class PlannerData(_Msg):
    """planner ``data`` (Player's planner interface): ``status`` one of idle, driving, done, aborted
    (a replan failed), invalid (the goal cannot be planned); ``pose`` the localized pose, ``goal`` and
    ``waypoint`` (current target) in the map frame (empty list when none), ``waypoint_index`` of
    ``waypoint_count``; ``message`` says why for aborted/invalid."""

    t: float
    status: str
    pose: tuple[float, float, float]
    goal: tuple[float, ...] = ()
    waypoint: tuple[float, ...] = ()
    waypoint_index: int = 0
    waypoint_count: int = 0
    message: str = ""

    @classmethod
    def from_dict(cls, m: dict) -> PlannerData:
        def opt3(name: str) -> tuple[float, ...]:
            v = _need(m, name, False)
            return () if v is None or v == [] else get_vec(m, name, 3)

        return cls(
            get_float(m, "t"),
            get_str(m, "status", choices=PLANNER_STATUS),
            get_vec(m, "pose", 3),
            opt3("goal"),
            opt3("waypoint"),
            get_int(m, "waypoint_index", 0, lo=0),
            get_int(m, "waypoint_count", 0, lo=0),
            get_str(m, "message", ""),
        )


class Planner(Device):
    """A global planner (Player's planner; the ``wavefront`` driver): goals in the map frame.

    :meth:`set_goal` returns a future that resolves to the final status, ``"done"``, or raises
    :class:`~rsal.RpcError` (``not_found`` for an invalid goal: outside the map, in an obstacle,
    unreachable; ``unavailable`` when aborted, e.g. a replan failed, or superseded by another goal).
    """

    data_type = PlannerData

    def __init__(self, fabric, addr):
        super().__init__(fabric, addr)
        self._goal_futures: list[tuple[int, Future]] = []
        self._done_listeners: list[Callable[[str], None]] = []
        self._glock = threading.Lock()

    @property
    def status(self) -> str:
        m = self.latest
        return m.status if m is not None else "idle"

    @property
    def waypoint_count(self) -> int:
        m = self.latest
        return m.waypoint_count if m is not None else 0

    @property
    def waypoint_index(self) -> int:
        m = self.latest
        return m.waypoint_index if m is not None else 0

    def current_waypoint(self) -> Position | None:
        m = self.latest
        return Position(*m.waypoint) if m is not None and m.waypoint else None

    def waypoints(self, timeout: float = 5.0) -> list[Position]:
        return [Position(*w) for w in self.rpc("waypoints", timeout=timeout)["waypoints"]]

    def plan(self, goal: tuple[float, float], start: tuple[float, float] | None = None, timeout: float = 5.0) -> dict:
        """A plan from ``start`` (default: the localized pose) to ``goal`` without driving it
        (``rpc/plan``): ``{"length": m, "waypoints": [[x, y], ...]}``. Raises
        :class:`~rsal.RpcError`: ``not_found`` when there is no path, ``unavailable`` before the map."""
        args: dict = {"goal": [float(goal[0]), float(goal[1])]}
        if start is not None:
            args["start"] = [float(start[0]), float(start[1])]
        return self.rpc("plan", timeout=timeout, **args)

    def set_goal(self, goal: Position, timeout: float = 5.0) -> Future:
        """Plan to ``goal`` and drive there. The future resolves to "done" or raises RpcError."""
        fut: Future = Future()
        try:
            r = self.rpc("set_goal", timeout=timeout, goal=list(goal.as_tuple()))
        except Exception as e:  # RpcError (invalid goal, timeout) ends the future at once
            fut.set_exception(e)
            return fut
        with self._glock:
            for _, f in self._goal_futures:  # a new goal supersedes the old ones
                if not f.done():
                    f.set_exception(RpcError(ErrorCode.UNAVAILABLE, "superseded by a new goal"))
            self._goal_futures = [(int(r.get("goal_id", 0)), fut)]
        return fut

    def stop(self, timeout: float = 5.0) -> dict:
        return self.rpc("stop", timeout=timeout)

    def resume(self, timeout: float = 5.0) -> dict:
        return self.rpc("resume", timeout=timeout)

    def add_is_done_listener(self, fn: Callable[[str], None]) -> None:
        """``fn(status)`` when a goal ends: "done", "aborted" or "invalid"."""
        self._done_listeners.append(fn)

    def _handle_event(self, ev: dict) -> None:
        kind = ev.get("event")
        if kind not in ("done", "aborted", "invalid"):
            return
        gid = ev.get("goal_id", 0)
        with self._glock:
            keep = []
            for g, f in self._goal_futures:
                if g != gid:
                    keep.append((g, f))
                elif not f.done():
                    if kind == "done":
                        f.set_result("done")
                    else:
                        code = ErrorCode.NOT_FOUND if kind == "invalid" else ErrorCode.UNAVAILABLE
                        f.set_exception(RpcError(code, str(ev.get("message", kind))))
            self._goal_futures = keep
        for fn in self._done_listeners:
            self.fabric.dispatcher.submit(fn, kind)


INTERFACE = Interface(
    "planner",
    proxy=Planner,
    data=PlannerData,
    event="{event: done | aborted | invalid, goal_id, message}",
    summary=lambda m: (
        f"{m.status} waypoint {m.waypoint_index}/{m.waypoint_count}" + (f" ({m.message})" if m.message else "")
    ),
    doc="a global planner: goals in the map frame, waypoints, status",
)
