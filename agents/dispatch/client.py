"""The requester's side of the dispatcher: building ``task_request`` messages and following
``task_state`` (:class:`TaskBoard`), shared by ``rsal task`` (:mod:`agents.dispatch.cli`) and the
control center's Tasks panel (:mod:`agents.control.tasks`).

:class:`TaskBoard` is the live list of tasks a person watches: every ``task_state``
(:class:`~agents.dispatch.tasks.TaskStatus`) updates its task's row (state, robot, reason, the
states it went through in order); a task that ended (``done``, ``failed``, ``cancelled``,
``refused``) stays ``hold`` seconds, then leaves, showing the robot it was last on. It has no
network and reads time from the caller (``now``), so it is unit-tested alone; it is thread-safe,
and :meth:`TaskBoard.wait` lets a caller wait (with a deadline) for a task to reach a state.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import uuid
from dataclasses import dataclass, field

from .tasks import TaskRequest, TaskState, TaskStatus

__all__ = ["TaskBoard", "TaskRow", "submit_request", "cancel_request", "list_request", "parse_route"]


def submit_request(kind: str, args: dict, robot: str = "", task_id: str = "", prefix: str = "cli") -> TaskRequest:
    """A ``submit`` request for a task of ``kind`` with ``args`` (the dispatcher validates them),
    directly assigned to ``robot`` when given; a fresh id ``<prefix>-<8 hex>`` unless ``task_id``."""
    tid = task_id or f"{prefix}-{uuid.uuid4().hex[:8]}"
    return TaskRequest("submit", task={"id": tid, "kind": kind, "args": dict(args), "robot": robot or ""})


def cancel_request(task_id: str) -> TaskRequest:
    return TaskRequest("cancel", task_id=task_id)


def list_request() -> TaskRequest:
    return TaskRequest("list")


def parse_route(text: str) -> list[list[float]]:
    """A patrol route typed by a person: points ``x, y`` separated by ``;`` or new lines
    (``1, -2.5; 4, -2.5; 4, 2.5``), or YAML ``[[1, -2.5], [4, -2.5]]``; ValueError with one line."""
    s = text.strip()
    if s.startswith("["):
        import yaml

        try:
            v = yaml.safe_load(s)
        except yaml.YAMLError:
            raise ValueError(f"route {text!r} is not a YAML list of points; write [[1, 2], [3, 4]]") from None
        items = v if isinstance(v, list) else None
    else:
        items = [p.replace(",", " ").split() for p in s.replace("\n", ";").split(";") if p.strip()]
    out = []
    for p in items or [None]:
        try:
            if not isinstance(p, list) or len(p) != 2:
                raise ValueError
            x, y = float(p[0]), float(p[1])
            if not (math.isfinite(x) and math.isfinite(y)):
                raise ValueError
        except (TypeError, ValueError):
            raise ValueError(f"route point {p!r} must be 'x, y' in metres; write e.g. '1, -2.5; 4, -2.5'") from None
        out.append([x, y])
    if len(out) < 2:
        raise ValueError(f"a patrol route needs two or more points 'x, y; x, y', got {text!r}")
    return out


@dataclass
class TaskRow:
    """A task as a person sees it: ``last``, its latest ``task_state`` (an empty field keeps the
    value an earlier one gave), the ``states`` it went through, when it was first seen and when it
    ended (``inf`` while it lives)."""

    last: TaskStatus
    first_seen: float = 0.0
    ended_at: float = math.inf
    states: list[str] = field(default_factory=list)

    def to_dict(self, now: float) -> dict:
        d = self.last.to_dict()
        d["id"] = d.pop("task_id")
        d.update(
            age=round(max(0.0, now - self.first_seen), 1),
            states=list(self.states),
            final=TaskState(self.last.state).final,
        )
        return d


class TaskBoard:
    """The live tasks from ``task_state`` messages (module docstring). ``hold``: seconds an ended
    task stays listed."""

    def __init__(self, hold: float = 30.0):
        if not (isinstance(hold, (int, float)) and hold >= 0):
            raise ValueError(f"hold {hold!r} must be a number of seconds >= 0")
        self.hold = float(hold)
        self._rows: dict[str, TaskRow] = {}
        self._cond = threading.Condition()

    def apply(self, st: TaskStatus, now: float) -> TaskRow | None:
        """Take one ``task_state``; returns the task's row (None for a refusal of no task id)."""
        if st.task_id in ("", "?"):
            return None
        with self._cond:
            row = self._rows.get(st.task_id)
            if row is None and not st.kind:
                return None  # a refused cancel of a task nobody knows: no task to list
            if row is None:
                row = self._rows[st.task_id] = TaskRow(st, first_seen=now)
            if not row.states or row.states[-1] != st.state:
                row.states.append(st.state)
            final = TaskState(st.state).final
            was = row.last
            row.last = dataclasses.replace(
                st,
                # an ended task keeps the robot it was last on (a cancel or re-bid may clear it)
                robot=st.robot or (was.robot if final else ""),
                kind=st.kind or was.kind,
                text=st.text or was.text,
                requester=st.requester or was.requester,
                places=st.places or was.places,
            )
            row.ended_at = (now if row.ended_at == math.inf else row.ended_at) if final else math.inf
            self._cond.notify_all()
            return row

    def rows(self, now: float) -> list[dict]:
        """The tasks listed at ``now`` (live ones, and ended ones for ``hold`` seconds), oldest first."""
        with self._cond:
            for tid in [t for t, r in self._rows.items() if now - r.ended_at > self.hold]:
                del self._rows[tid]
            return [r.to_dict(now) for r in sorted(self._rows.values(), key=lambda r: (r.first_seen, r.last.task_id))]

    def get(self, task_id: str) -> TaskRow | None:
        with self._cond:
            return self._rows.get(task_id)

    def wait(self, task_id: str, states: set[str] | None, timeout: float) -> TaskRow | None:
        """Wait until ``task_id`` is in one of ``states`` (None: any state); the row or None after
        ``timeout`` seconds (wall clock: a person waits)."""
        import time

        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                row = self._rows.get(task_id)
                if row is not None and (states is None or row.last.state in states):
                    return row
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
