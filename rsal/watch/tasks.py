"""The fleet dispatcher's tasks in ``rsal watch``: every task drawn in the map frame while it lives.

The dispatcher (``agents/dispatch``, ``docs/dispatch.md``) publishes each change of a task on the
``task_state`` service (``bidding`` -> ``assigned`` -> ``active`` -> ``done`` / ``failed`` /
``cancelled`` / ``refused``) with the task's points (``places``: a go_to's goal, a charge task's
charger, a fetch's pick-up and drop-off, a custom task's point, a patrol's route once); its robots
report on ``fleet`` (``status``) their pose, their active task and the point it drives to next
(``target``). This view reads both as plain msgpack maps (the RSAL layer imports nothing of
``agents``):

- :func:`task_drawing` (pure): a ``task_state`` map to what is drawn at ``world/tasks/<id>``:
  the points, a line strip (a patrol route as a closed loop; a fetch from pick-up to drop-off),
  the state's colour and the label ``<task id> <kind> <state> -> <robot>``;
- :func:`task_log` (pure): the text log entry of a state change (level WARN when it failed or was
  refused);
- :func:`robot_link` (pure): a robot's ``fleet`` status to the line from the robot to its active
  task's next point (``world/tasks/<id>/link``);
- :class:`TaskView`: which tasks are drawn, and when an ended task leaves the map (``hold``
  seconds after it ended; it stays in the text log ``log/tasks``).

Drawing and clearing are done by :class:`rsal.watch.app.Watcher`; everything here is unit-tested
without Rerun (``tests/rsal/test_watch_tasks.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .convert import rgba

__all__ = ["STATE_COLORS", "FINAL", "TaskDrawing", "task_drawing", "task_log", "robot_link", "TaskView"]

FINAL = ("done", "failed", "cancelled", "refused")
STATE_COLORS = {
    "bidding": rgba(250, 200, 0),
    "assigned": rgba(60, 140, 255),
    "active": rgba(40, 200, 40),
    "done": rgba(150, 150, 150),
    "failed": rgba(230, 30, 30),
    "cancelled": rgba(200, 120, 40),
    "refused": rgba(160, 0, 0),
}


@dataclass(frozen=True)
class TaskDrawing:
    """What a task looks like in the map frame: ``points`` (n, 2), an optional ``strip`` (m, 2)
    of lines between them, ``color`` (0xRRGGBBAA) and ``label``."""

    task_id: str
    state: str
    points: np.ndarray
    strip: np.ndarray | None
    color: int
    label: str


def _points(v) -> np.ndarray | None:
    if not isinstance(v, (list, tuple)):
        return None
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return None
    if a.size == 0:
        return np.zeros((0, 2))
    if a.ndim != 2 or a.shape[1] != 2 or not np.isfinite(a).all():
        return None
    return a


def task_drawing(m: dict) -> TaskDrawing | None:
    """A ``task_state`` body (a plain map: ``task_id``, ``kind``, ``state``, ``robot``, ``places``)
    as a :class:`TaskDrawing`; None when it names no task or its places are malformed."""
    tid, state = m.get("task_id"), m.get("state")
    if not isinstance(tid, str) or tid in ("", "?") or state not in STATE_COLORS:
        return None
    pts = _points(m.get("places", []))
    if pts is None:
        return None
    kind = str(m.get("kind", "") or "?")
    robot = str(m.get("robot", "") or "-")
    strip = None
    if kind == "patrol" and len(pts) >= 2:
        strip = np.vstack([pts, pts[:1]])  # the route is driven as a closed loop
    elif len(pts) >= 2:
        strip = pts.copy()
    return TaskDrawing(tid, state, pts, strip, STATE_COLORS[state], f"{tid} {kind} {state} -> {robot}")


def task_log(m: dict) -> tuple[str, str]:
    """``(text, level)`` of the text log entry for a ``task_state`` body."""
    tid, kind, state = m.get("task_id", "?"), m.get("kind", "") or "?", m.get("state", "?")
    robot = m.get("robot", "") or "-"
    text = f"{tid} {kind} {state} -> {robot}"
    extra = " ".join(str(x) for x in (m.get("reason", ""), m.get("text", "")) if x)
    level = "WARN" if state in ("failed", "refused") else "INFO"
    return (f"{text}: {extra}" if extra else text), level


def robot_link(m: dict, pose: tuple[float, float] | None = None) -> tuple[str, np.ndarray] | None:
    """``(task id, line (2, 2))`` from the robot to its active task's next point, from a ``fleet``
    ``status`` body (``active``, ``target`` [x, y], the robot's ``x``, ``y``); ``pose`` overrides
    the robot's reported position (the view's ground truth). None when it has no active task or
    no target."""
    if m.get("op") != "status":
        return None
    tid, target = m.get("active"), _points([m.get("target")] if m.get("target") else [])
    if not isinstance(tid, str) or not tid or target is None or len(target) != 1:
        return None
    if pose is None:
        x, y = m.get("x"), m.get("y")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in (x, y)):
            return None
        pose = (float(x), float(y))
    return tid, np.array([[pose[0], pose[1]], target[0]], dtype=float)


class TaskView:
    """The tasks on the map: :meth:`state` takes a ``task_state`` body at ``now`` and returns the
    drawing (or None); :meth:`expired` returns the ended tasks to clear (``hold`` seconds after
    they ended); :meth:`link` tells whether a robot's link may be drawn for a task (it is active)."""

    def __init__(self, hold: float = 5.0):
        self.hold = float(hold)
        self.states: dict[str, str] = {}
        self.ended: dict[str, float] = {}  # task id -> when it ended
        self.linked: set[str] = set()  # tasks with a link drawn

    def state(self, m: dict, now: float) -> TaskDrawing | None:
        d = task_drawing(m)
        if d is None:
            return None
        self.states[d.task_id] = d.state
        if d.state in FINAL:
            self.ended.setdefault(d.task_id, now)
        else:
            self.ended.pop(d.task_id, None)
        return d

    def link(self, task_id: str) -> bool:
        ok = self.states.get(task_id) == "active"
        if ok:
            self.linked.add(task_id)
        return ok

    def unlink(self) -> list[str]:
        """Tasks whose link is drawn but which are no longer active: their links to clear."""
        gone = [t for t in self.linked if self.states.get(t) != "active"]
        self.linked.difference_update(gone)
        return gone

    def expired(self, now: float) -> list[str]:
        out = [t for t, at in self.ended.items() if now - at >= self.hold]
        for t in out:
            del self.ended[t]
            self.states.pop(t, None)
            self.linked.discard(t)
        return out
