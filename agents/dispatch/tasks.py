"""Dispatcher tasks and the dispatcher's typed messages (the wire schema of ``agents.dispatch``).

The task model follows Open-RMF's task dispatcher (``rmf_task``: a task is a request that robots
bid for, awarded by cost, tracked through states) on the FIPA contract net (FIPA SC00029H,
:mod:`agents.contractnet`): the dispatcher's ``call`` is the ``cfp``, a robot's ``bid`` is the
``propose`` (``refuse`` when it cannot), ``award`` is the ``accept-proposal`` and ``progress``
``done``/``failed`` are ``inform-done``/``failure``. Beyond the plain contract net the dispatcher
may ``revoke`` an awarded task that has not started (periodic re-assignment) and a robot may
``forfeit`` one.

Task kinds and their ``args`` (metres, radians, map frame; seconds):

``go_to``   ``x``, ``y`` (``yaw`` optional)
``patrol``  ``route`` [[x, y], ...] (two or more points), ``laps`` (>= 1, default 1)
``fetch``   ``object`` (a name), ``at`` [x, y] where it lies, ``to`` [x, y] where it goes
``charge``  ``charger`` (a charger's name; empty: the dispatcher picks a free one), ``target`` (0..1)
``custom``  ``at`` [x, y] where it happens, ``duration`` (s, >= 0), anything else is passed on

A request that cannot be served is refused with a typed :class:`Refusal` and one line that names the
value and a fix; nothing raises across the wire.

Services (``svc/<service>/<sender>``, bodies validated here on decode):

``task_request``  anyone -> dispatcher: :class:`TaskRequest` (submit, cancel, list)
``task_state``    dispatcher -> anyone: :class:`TaskStatus` (every change of a task's state)
``dispatch``      dispatcher -> robots: :class:`DispatchMsg` (call, award, revoke)
``fleet``         robots -> dispatcher: :class:`FleetMsg` (bid, refuse, progress, status)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, ClassVar

from rsal.errors import RsalError
from rsal.msgs import MessageError, get_bool, get_float, get_int, get_str
from rsal.suggest import did_you_mean

__all__ = [
    "KINDS",
    "TaskState",
    "Refusal",
    "TaskRefused",
    "Task",
    "parse_task",
    "task_places",
    "task_outline",
    "TaskRequest",
    "TaskStatus",
    "DispatchMsg",
    "FleetMsg",
    "SCHEMAS",
    "decode_body",
]

KINDS = ("go_to", "patrol", "fetch", "charge", "custom")


class TaskState(StrEnum):
    """Where a task is: ``bidding`` (a call is open, or waits for the next one), ``assigned`` (in a
    robot's queue, not started), ``active``, then one of the final ``done``, ``failed``,
    ``cancelled``, ``refused``."""

    BIDDING = "bidding"
    ASSIGNED = "assigned"
    ACTIVE = "active"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"
    REFUSED = "refused"

    @property
    def final(self) -> bool:
        return self in (TaskState.DONE, TaskState.FAILED, TaskState.CANCELLED, TaskState.REFUSED)


class Refusal(StrEnum):
    """Why a task was refused or failed."""

    UNKNOWN_KIND = "unknown_kind"
    BAD_FIELD = "bad_field"
    OUTSIDE_MAP = "outside_map"
    UNREACHABLE = "unreachable"
    THROUGH_WALL = "through_wall"
    UNKNOWN_ROBOT = "unknown_robot"
    UNKNOWN_CHARGER = "unknown_charger"
    DUPLICATE_ID = "duplicate_id"
    NOT_FOUND = "not_found"
    NO_BIDS = "no_bids"
    ROBOT_FAILED = "robot_failed"


class TaskRefused(RsalError, ValueError):
    """A request the dispatcher does not take: ``reason`` (a :class:`Refusal`) and one line."""

    def __init__(self, reason: Refusal, text: str):
        super().__init__(text)
        self.reason = reason


def _point(args: dict, name: str, where: str) -> tuple[float, float]:
    v = args.get(name)
    ok = isinstance(v, (list, tuple)) and len(v) == 2
    if ok and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in v):
        return (float(v[0]), float(v[1]))
    raise TaskRefused(
        Refusal.BAD_FIELD, f"{where}: '{name}' must be a point [x, y] in metres, got {v!r}; e.g. {name}: [1.0, 2.0]"
    )


def _number(args: dict, name: str, where: str, default: float | None, lo: float, hi: float = math.inf) -> float:
    v = args.get(name, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        rng = f" from {lo:g} to {hi:g}" if math.isfinite(hi) else f" >= {lo:g}" if math.isfinite(lo) else ""
        raise TaskRefused(Refusal.BAD_FIELD, f"{where}: '{name}' must be a number{rng}, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class Task:
    """One validated task: ``id``, ``kind`` (one of :data:`KINDS`), its ``args`` (normalised) and
    ``robot`` (direct assignment to that robot agent; ``""``: bid for)."""

    id: str
    kind: str
    args: dict = field(default_factory=dict)
    robot: str = ""

    def to_dict(self) -> dict:
        return {"id": self.id, "kind": self.kind, "args": dict(self.args), "robot": self.robot}


def parse_task(m: Any, task_id: str = "") -> Task:
    """Validate a task map ``{kind, args, robot?, id?}``; raises :class:`TaskRefused`."""
    if not isinstance(m, dict):
        raise TaskRefused(Refusal.BAD_FIELD, f"a task is a map {{kind, args}}, got {type(m).__name__}")
    tid = m.get("id") or task_id
    if not isinstance(tid, str) or not tid:
        raise TaskRefused(Refusal.BAD_FIELD, f"task id {tid!r} must be a non-empty string")
    where = f"task {tid}"
    kind = m.get("kind")
    if kind not in KINDS:
        near = did_you_mean(str(kind), KINDS)
        hint = f"did you mean {near!r}?" if near else f"use one of {', '.join(KINDS)}"
        raise TaskRefused(Refusal.UNKNOWN_KIND, f"{where}: unknown task kind {kind!r}; {hint}")
    args = m.get("args", {})
    if not isinstance(args, dict) or not all(isinstance(k, str) for k in args):
        raise TaskRefused(Refusal.BAD_FIELD, f"{where}: 'args' must be a map, got {args!r}")
    robot = m.get("robot", "") or ""
    if not isinstance(robot, str):
        raise TaskRefused(Refusal.BAD_FIELD, f"{where}: 'robot' must be a robot agent's id, got {robot!r}")
    out: dict[str, Any]
    if kind == "go_to":
        x = _number(args, "x", where, None, -math.inf)
        y = _number(args, "y", where, None, -math.inf)
        out = {"x": x, "y": y, "yaw": _number(args, "yaw", where, 0.0, -math.inf)}
    elif kind == "patrol":
        route = args.get("route")
        if not isinstance(route, (list, tuple)) or len(route) < 2:
            raise TaskRefused(
                Refusal.BAD_FIELD, f"{where}: 'route' must list two or more points [[x, y], ...], got {route!r}"
            )
        pts = [_point({"route point": p}, "route point", where) for p in route]
        laps = args.get("laps", 1)
        if isinstance(laps, bool) or not isinstance(laps, int) or laps < 1:
            raise TaskRefused(Refusal.BAD_FIELD, f"{where}: 'laps' must be a whole number >= 1, got {laps!r}")
        out = {"route": [list(p) for p in pts], "laps": laps}
    elif kind == "fetch":
        obj = args.get("object")
        if not isinstance(obj, str) or not obj:
            raise TaskRefused(Refusal.BAD_FIELD, f"{where}: 'object' must name the object to fetch, got {obj!r}")
        out = {"object": obj, "at": list(_point(args, "at", where)), "to": list(_point(args, "to", where))}
    elif kind == "charge":
        ch = args.get("charger", "") or ""
        if not isinstance(ch, str):
            raise TaskRefused(Refusal.BAD_FIELD, f"{where}: 'charger' must be a charger's name, got {ch!r}")
        out = {"charger": ch, "target": _number(args, "target", where, 0.9, 0.0, 1.0)}
        for k in ("x", "y", "yaw"):  # filled in by the dispatcher when it picks the charger
            if k in args:
                out[k] = _number(args, k, where, None, -math.inf)
    else:  # custom
        out = dict(args)
        out["at"] = list(_point(args, "at", where))
        out["duration"] = _number(args, "duration", where, 0.0, 0.0)
    return Task(tid, kind, out, robot)


def task_places(task: Task) -> list[tuple[float, float]]:
    """The points a task visits, in order (a charge task: its charger once it is chosen)."""
    a = task.args
    if task.kind == "go_to":
        return [(a["x"], a["y"])]
    if task.kind == "patrol":
        route = [tuple(p) for p in a["route"]]
        return route * int(a["laps"])
    if task.kind == "fetch":
        return [tuple(a["at"]), tuple(a["to"])]
    if task.kind == "charge":
        return [(a["x"], a["y"])] if "x" in a else []
    return [tuple(a["at"])]


def task_outline(task: Task) -> list[tuple[float, float]]:
    """The points to draw for a task: :func:`task_places` with a patrol route once (not once per
    lap); the places a ``task_state`` carries for views (``rsal watch``, the control center)."""
    if task.kind == "patrol":
        return [(float(p[0]), float(p[1])) for p in task.args["route"]]
    return [(float(x), float(y)) for x, y in task_places(task)]


def _points(m: dict, name: str) -> tuple[tuple[float, float], ...]:
    v = m.get(name, [])
    if not isinstance(v, (list, tuple)):
        raise MessageError(f"field {name!r} must be a list of points [x, y]")
    out = []
    for p in v:
        ok = isinstance(p, (list, tuple)) and len(p) == 2
        if not ok or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in p):
            raise MessageError(f"field {name!r} must be a list of points [x, y] (finite metres), got {p!r}")
        out.append((float(p[0]), float(p[1])))
    return tuple(out)


# ---------------------------------------------------------------------------- wire bodies
class _Body:
    SERVICE: ClassVar[str] = ""

    def to_dict(self) -> dict:
        return {k: (_plain(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def _plain(v):
    return [_plain(x) for x in v] if isinstance(v, (tuple, list)) else v


def _map(m: dict, name: str) -> dict:
    v = m.get(name, {})
    if not isinstance(v, dict) or not all(isinstance(k, str) for k in v):
        raise MessageError(f"field {name!r} must be a map with string keys")
    return v


def _strs(m: dict, name: str) -> tuple[str, ...]:
    v = m.get(name, [])
    if not isinstance(v, (list, tuple)) or not all(isinstance(s, str) for s in v):
        raise MessageError(f"field {name!r} must be a list of strings")
    return tuple(v)


@dataclass(frozen=True)
class TaskRequest(_Body):
    """``task_request``: ``op`` ``submit`` (``task``: a task map), ``cancel`` (``task_id``) or
    ``list`` (the dispatcher answers with the state of every task it knows on ``task_state``)."""

    op: str
    task: dict = field(default_factory=dict)
    task_id: str = ""

    SERVICE: ClassVar[str] = "task_request"
    OPS: ClassVar[tuple[str, ...]] = ("submit", "cancel", "list")

    @classmethod
    def from_dict(cls, m: dict) -> TaskRequest:
        return cls(get_str(m, "op", choices=cls.OPS), _map(m, "task"), get_str(m, "task_id", ""))


@dataclass(frozen=True)
class TaskStatus(_Body):
    """``task_state``: task ``task_id`` of ``kind`` is now ``state`` (a :class:`TaskState`), on
    ``robot`` (``""`` while none); ``reason`` (a :class:`Refusal` value) when refused or failed;
    ``text`` one human-readable line; ``requester`` the agent that submitted it; ``places`` the
    task's points in the map frame (:func:`task_outline`: a patrol's route once, a charge task's
    charger once chosen; empty for a refused task), for views to draw."""

    task_id: str
    kind: str
    state: str
    robot: str = ""
    reason: str = ""
    text: str = ""
    requester: str = ""
    places: tuple[tuple[float, float], ...] = ()

    SERVICE: ClassVar[str] = "task_state"

    @classmethod
    def from_dict(cls, m: dict) -> TaskStatus:
        return cls(
            get_str(m, "task_id"),
            get_str(m, "kind", ""),
            get_str(m, "state", choices=[s.value for s in TaskState]),
            get_str(m, "robot", ""),
            get_str(m, "reason", ""),
            get_str(m, "text", ""),
            get_str(m, "requester", ""),
            _points(m, "places"),
        )


@dataclass(frozen=True)
class DispatchMsg(_Body):
    """``dispatch`` (dispatcher -> robots): ``op`` ``call`` (bid for ``task`` in round ``round``
    by ``reply_by``, wall seconds since the epoch; ``to`` empty: every robot agent not in
    ``exclude``, else only ``to``), ``award`` (``to`` performs ``task``, inserted at ``index`` of its
    queue) or ``revoke`` (``to`` drops ``task_id``, which it has not started)."""

    op: str
    task_id: str
    to: str = ""
    task: dict = field(default_factory=dict)
    round: int = 0
    reply_by: float = 0.0
    index: int = -1
    exclude: tuple[str, ...] = ()

    SERVICE: ClassVar[str] = "dispatch"
    OPS: ClassVar[tuple[str, ...]] = ("call", "award", "revoke")

    @classmethod
    def from_dict(cls, m: dict) -> DispatchMsg:
        op = get_str(m, "op", choices=cls.OPS)
        to = get_str(m, "to", "")
        if op != "call" and not to:
            raise MessageError(f"a {op} needs a receiver in 'to'")
        return cls(
            op,
            get_str(m, "task_id"),
            to,
            _map(m, "task"),
            get_int(m, "round", 0, lo=0),
            get_float(m, "reply_by", 0.0, lo=0.0),
            get_int(m, "index", -1, lo=-1),
            _strs(m, "exclude"),
        )


@dataclass(frozen=True)
class FleetMsg(_Body):
    """``fleet`` (robots -> dispatcher). ``op``:

    - ``bid``: for ``task_id`` in ``round``: ``cost`` (s; finish time of the task plus the delay it
      causes the robot's other tasks), ``finish`` (s from now), ``index`` (where it goes in the queue);
    - ``refuse``: for ``task_id`` in ``round``, with ``reason``;
    - ``progress``: ``task_id`` is now ``state`` (``active``, ``done``, ``failed``, ``forfeit``),
      ``reason`` when it is not done;
    - ``status``: the robot (``robot``, its pose ``x``, ``y``), its ``battery`` (0..1; -1: no
      battery model), ``charging``, its ``queue`` (task ids, the active one first), ``active`` and
      ``target`` (the point [x, y] its active task drives to next; empty when none).
    """

    op: str
    robot: str = ""
    task_id: str = ""
    round: int = 0
    cost: float = 0.0
    finish: float = 0.0
    index: int = -1
    state: str = ""
    reason: str = ""
    x: float = 0.0
    y: float = 0.0
    battery: float = -1.0
    charging: bool = False
    queue: tuple[str, ...] = ()
    active: str = ""
    target: tuple[float, ...] = ()

    SERVICE: ClassVar[str] = "fleet"
    OPS: ClassVar[tuple[str, ...]] = ("bid", "refuse", "progress", "status")
    PROGRESS: ClassVar[tuple[str, ...]] = ("active", "done", "failed", "forfeit")

    @classmethod
    def from_dict(cls, m: dict) -> FleetMsg:
        op = get_str(m, "op", choices=cls.OPS)
        kw: dict[str, Any] = {"robot": get_str(m, "robot", "")}
        if op in ("bid", "refuse", "progress"):
            kw["task_id"] = get_str(m, "task_id")
        if op in ("bid", "refuse"):
            kw["round"] = get_int(m, "round", 0, lo=0)
        if op == "bid":
            kw["cost"] = get_float(m, "cost", lo=0.0)
            kw["finish"] = get_float(m, "finish", 0.0, lo=0.0)
            kw["index"] = get_int(m, "index", -1, lo=-1)
        if op == "progress":
            kw["state"] = get_str(m, "state", choices=cls.PROGRESS)
        if op in ("refuse", "progress"):
            kw["reason"] = get_str(m, "reason", "")
        if op == "status":
            kw["x"] = get_float(m, "x", 0.0)
            kw["y"] = get_float(m, "y", 0.0)
            kw["battery"] = get_float(m, "battery", -1.0, lo=-1.0, hi=1.0)
            kw["charging"] = get_bool(m, "charging", False)
            kw["queue"] = _strs(m, "queue")
            kw["active"] = get_str(m, "active", "")
            t = m.get("target", [])
            kw["target"] = _points({"target": [t]}, "target")[0] if t else ()
        return cls(op, **kw)


SCHEMAS: dict[str, type] = {b.SERVICE: b for b in (TaskRequest, TaskStatus, DispatchMsg, FleetMsg)}


def decode_body(service: str, m: dict) -> Any:
    """The typed body of a ``service`` message map; raises :class:`MessageError`."""
    return SCHEMAS[service].from_dict(m)
