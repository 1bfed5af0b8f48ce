"""The control center's Tasks panel: the fleet dispatcher's tasks, live, with submit and cancel
(``docs/control.md``, ``docs/dispatch.md``).

The control center joins the fabric as one agent (``control-<pid>``, on an agent host of its own
on a background thread, over the control's Zenoh session) so its requests carry a sender like any
agent's, exactly as ``rsal task`` does: the messages are built by :mod:`agents.dispatch.client`
(the code ``rsal task`` uses), and every ``task_state`` feeds a
:class:`~agents.dispatch.client.TaskBoard` that ``GET /api/tasks`` lists (id, kind, state, robot,
age, the states in order). On start it asks the dispatcher for the tasks it already knows
(``list``, again 2 s later). ``POST /api/tasks`` submits (go_to with ``x``, ``y``; charge; patrol with a ``route``
typed as text; or any kind with ``args``) and answers with the task's first state, or the
dispatcher's refusal as HTTP 400; ``POST /api/tasks/<id>/cancel`` cancels.
"""

from __future__ import annotations

import asyncio
import logging
import os
import threading
import time

from ..dispatch.client import TaskBoard, cancel_request, list_request, parse_route, submit_request
from ..dispatch.tasks import KINDS, TaskRequest, TaskState, TaskStatus
from ..runtime import Agent, AgentHost
from ..services import Message
from .api import NAME, ApiError, _num, _only

__all__ = ["TasksApi", "TaskDesk", "task_from_form"]

log = logging.getLogger("agents.control")

#: seconds the API waits for the dispatcher's first answer to a submit or cancel
ANSWER_WAIT = 3.0
#: seconds an ended task stays in the panel
HOLD = 60.0


def task_from_form(body: dict) -> tuple[str, dict, str]:
    """``(kind, args, robot)`` from the page's form: ``{kind, x, y, route, laps, charger, target,
    args, robot}``; :class:`ApiError` with one line for a bad field (the dispatcher checks the rest)."""
    _only(body, "task", ("kind", "x", "y", "yaw", "route", "laps", "charger", "target", "args", "robot"))
    kind = body.get("kind")
    if kind not in KINDS:
        raise ApiError(f"task kind {kind!r} is not one of {', '.join(KINDS)}")
    robot = body.get("robot") or ""
    if not isinstance(robot, str) or (robot and not NAME.match(robot)):
        raise ApiError(f"robot {robot!r} must be a robot agent's id (letters, digits, '_', '-', '.')")
    extra = body.get("args") or {}
    if not isinstance(extra, dict):
        raise ApiError('args must be a JSON object of task arguments, e.g. {"duration": 5}')
    args = dict(extra)
    if kind == "go_to":
        args |= {"x": _num(body, "x"), "y": _num(body, "y")}
        if body.get("yaw") is not None:
            args["yaw"] = _num(body, "yaw")
    elif kind == "patrol":
        route = body.get("route")
        if isinstance(route, str):
            try:
                args["route"] = parse_route(route)
            except ValueError as e:
                raise ApiError(str(e)) from None
        elif route is not None:
            args["route"] = route
        if body.get("laps") not in (None, ""):
            args["laps"] = body["laps"]
    elif kind == "charge":
        if body.get("charger"):
            args["charger"] = body["charger"]
        if body.get("target") is not None:
            args["target"] = _num(body, "target")
    return kind, args, robot


class TaskDesk(Agent):
    """The control center's agent: follows ``task_state`` into ``board`` and sends requests."""

    def __init__(self, agent_id: str, board: TaskBoard):
        super().__init__(agent_id)
        self.board = board
        self.bad = 0

    async def created(self) -> None:
        self.subscribe(TaskStatus.SERVICE, self._on_state)
        self.publish(TaskRequest.SERVICE, list_request())
        self._require_host().spawn(self._list_again(), f"{self.id}: list")

    async def _list_again(self) -> None:
        """Ask once more after 2 s: a session that just joined a running fabric may not have had
        its routes to the dispatcher when the first ``list`` went out."""
        await asyncio.sleep(2.0)
        if self.state == "running":
            self.publish(TaskRequest.SERVICE, list_request())

    def _on_state(self, msg: Message) -> None:
        try:
            self.board.apply(TaskStatus.from_dict(msg.body), time.monotonic())
        except Exception as e:  # a malformed state: dropped, counted, logged once
            self.bad += 1
            if self.bad == 1:
                log.warning("control: dropped a malformed task_state from %s: %s", msg.sender, e)


class TasksApi:
    """The endpoints of the Tasks panel (a part of :class:`agents.control.Control`)."""

    def _init_tasks(self) -> None:
        self.task_board = TaskBoard(HOLD)
        self.desk_id = f"control-{os.getpid()}"  # not listed among the fabric's agents: it is this page
        self._desk: TaskDesk | None = None
        self._desk_loop: asyncio.AbstractEventLoop | None = None
        self._desk_stop: asyncio.Event | None = None

    def _start_tasks(self, session) -> None:
        """Run :class:`TaskDesk` on an agent host of its own (a daemon thread with its loop)."""
        ready = threading.Event()
        self._desk_loop = loop = asyncio.new_event_loop()

        async def main() -> None:
            self._desk_host = host = AgentHost(session)
            self._desk_stop = asyncio.Event()
            try:
                self._desk = await host.start(TaskDesk(self.desk_id, self.task_board))
            finally:
                ready.set()
            await self._desk_stop.wait()
            await host.stop()

        def run() -> None:
            asyncio.set_event_loop(loop)
            try:
                loop.run_until_complete(main())
            except Exception:
                log.exception("control: the tasks agent stopped")
                ready.set()

        self._desk_thread = threading.Thread(target=run, name="control-tasks", daemon=True)
        self._desk_thread.start()
        ready.wait(10.0)

    def _stop_tasks(self) -> None:
        loop, stop = self._desk_loop, self._desk_stop
        if loop is None or stop is None or loop.is_closed():
            return
        loop.call_soon_threadsafe(stop.set)
        self._desk_thread.join(5.0)

    def _send(self, req: TaskRequest) -> None:
        desk = self._desk
        if desk is None or desk.state != "running" or self._desk_loop is None:
            raise ApiError("the control center's tasks agent is not running; see its log", 503)
        self._desk_loop.call_soon_threadsafe(desk.publish, TaskRequest.SERVICE, req)

    # ------------------------------------------------------------------ endpoints
    def tasks(self) -> dict:
        return {"tasks": self.task_board.rows(time.monotonic()), "hold": self.task_board.hold}

    def submit_task(self, body: dict) -> dict:
        kind, args, robot = task_from_form(body)
        req = submit_request(kind, args, robot, prefix="ctl")
        tid = req.task["id"]
        self._send(req)
        row = self.task_board.wait(tid, None, ANSWER_WAIT)
        if row is None:
            raise ApiError(
                f"no DispatcherAgent answered task {tid} within {ANSWER_WAIT:g} s; start one "
                "('rsal agent DispatcherAgent') on this fabric",
                504,
            )
        if row.last.state == TaskState.REFUSED:
            raise ApiError(f"refused ({row.last.reason}): {row.last.text}")
        return row.to_dict(time.monotonic())

    def cancel_task(self, task_id: str) -> dict:
        row = self.task_board.get(task_id)
        if row is None:
            raise ApiError(f"no task {task_id!r} in the list; see GET /api/tasks", 404)
        if TaskState(row.last.state).final:
            raise ApiError(f"task {task_id} already ended ({row.last.state}); nothing to cancel")
        self._send(cancel_request(task_id))
        row = self.task_board.wait(task_id, {s.value for s in TaskState if s.final}, ANSWER_WAIT)
        if row is None:
            raise ApiError(f"the dispatcher did not confirm the cancel of {task_id} within {ANSWER_WAIT:g} s", 504)
        return row.to_dict(time.monotonic())
