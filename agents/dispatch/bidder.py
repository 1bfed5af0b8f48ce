"""A robot's bid for a dispatcher task: finish time plus the delay it causes, with its battery.

Open-RMF's cost for a task request (``rmf_task``'s ``TaskPlanner``, "quickest finish" with the
cost of delaying the robot's other tasks) for one robot and its queue: for every place ``k`` the new
task could go in the queue, the new task's finish time plus the sum of the delays it causes every
task after it; the bid is the cheapest place. Travel is ``travel(a, b)`` seconds between two points
(default: straight line over ``speed``; an agent with a planner gives path length over speed and
``None`` for unreachable). All places are evaluated at once with numpy: one array per queue, no
Python loop over the places.

Path travel (:class:`PathTravel`): where the robot has a global planner (``wavefront``'s
``planner:0``), a leg costs the length of the planner's path (``rpc/plan``: planned, not driven)
over ``speed``, so a goal behind a wall is costed by the way around it; no path is ``None``
(unreachable). A planner without ``plan`` makes every leg a straight line, and the robot says so
once; a planner that cannot answer now (no map yet, a timeout) costs that leg as a straight line.
Lengths are cached per pair of points (to the centimetre; at most ``cache`` pairs).

Battery (:class:`Energy`): a robot with a battery model adds the time to recharge when the plan
with the new task would bring its charge below the dispatcher's threshold: that plan includes a
detour to charge, as Open-RMF's planner inserts charging tasks.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rsal.msgs import ErrorCode, RpcError

from .tasks import Task, task_places

__all__ = ["Bid", "Energy", "PathTravel", "estimate", "plan_bid"]

log = logging.getLogger(__name__)

Point = tuple[float, float]


@dataclass(frozen=True)
class Energy:
    """A robot's energy use as fractions of its battery: ``per_metre``, ``per_second`` (electronics)
    and ``charge_rate`` (fraction gained per second on a charger). The Pioneer DX defaults of
    :mod:`simulator.energy`: 20 J/m, 20 W on 933 kJ, charged at 150 W."""

    per_metre: float = 20.0 / 933120.0
    per_second: float = 20.0 / 933120.0
    charge_rate: float = 150.0 / 933120.0


@dataclass(frozen=True)
class Bid:
    """``cost`` (s) = ``finish`` (s from now, when the new task ends) + ``delay`` (s, summed over the
    tasks after it); ``index`` where it goes in the queue; ``charge`` (s) of charging included."""

    cost: float
    finish: float
    delay: float
    index: int
    charge: float = 0.0


class PathTravel:
    """``travel(a, b)``: seconds from ``a`` to ``b`` along the planner's path at ``speed`` (module
    docstring). ``plan(a, b)`` returns the path length in metres or raises :class:`RpcError`
    (e.g. ``lambda a, b: planner.plan(b, start=a)["length"]``); ``owner`` names the robot in what
    it says. ``straight`` is true once the planner turned out to have no ``plan``."""

    def __init__(self, plan: Callable[[Point, Point], float], speed: float, owner: str = "", cache: int = 4096):
        if not speed > 0:
            raise ValueError(f"speed {speed!r} must be positive (m/s)")
        self.plan, self.speed, self.owner, self.size = plan, float(speed), owner, int(cache)
        self.straight = False
        self.asked = 0  # plans asked of the planner (cache misses)
        self._cache: OrderedDict[tuple, float | None] = OrderedDict()
        self._lock = threading.Lock()  # bids of two calls may run on two worker threads
        self._said: set[str] = set()

    def _say(self, topic: str, text: str) -> None:
        with self._lock:
            new = topic not in self._said
            self._said.add(topic)
        if new:
            log.warning("%s: %s", self.owner or "bidder", text)

    def __call__(self, a: Point, b: Point) -> float | None:
        line = math.hypot(b[0] - a[0], b[1] - a[1])
        if self.straight or line < 1e-3:
            return line / self.speed
        key = (round(a[0], 2), round(a[1], 2), round(b[0], 2), round(b[1], 2))
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
            self.asked += 1
        try:
            t: float | None = float(self.plan(a, b)) / self.speed
        except RpcError as e:
            if e.code == ErrorCode.NOT_FOUND:
                t = None  # no path: unreachable
            elif e.code == ErrorCode.UNKNOWN_OP:
                self.straight = True
                self._say("no_plan", f"the planner cannot plan without driving ({e}); bids use straight lines")
                return line / self.speed
            else:  # no map yet, a timeout: this leg as a straight line, not remembered
                self._say("unavailable", f"the planner did not answer a plan ({e}); that leg bid as a straight line")
                return line / self.speed
        with self._lock:
            self._cache[key] = t
            if len(self._cache) > self.size:
                self._cache.popitem(last=False)
        return t


def estimate(
    task: Task, speed: float, travel: Callable[[Point, Point], float | None]
) -> tuple[Point, Point, float, float] | None:
    """(entry point, exit point, seconds of work inside the task, metres inside) or None when a leg
    inside the task is unreachable."""
    pts = task_places(task)
    if not pts:
        return None
    work, metres = 0.0, 0.0
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        t = travel(a, b)
        if t is None:
            return None
        work += t
        metres += t * speed
    if task.kind == "custom":
        work += float(task.args.get("duration", 0.0))
    return pts[0], pts[-1], work, metres


def plan_bid(
    pose: Point,
    queue: Sequence[Task],
    task: Task,
    *,
    speed: float = 0.5,
    travel: Callable[[Point, Point], float | None] | None = None,
    battery: float | None = None,
    energy: Energy = Energy(),
    threshold: float = 0.2,
    target: float = 0.9,
    busy_until: float = 0.0,
) -> Bid | None:
    """The cheapest place for ``task`` in ``queue`` (tasks not started) for a robot at ``pose``
    that is busy for ``busy_until`` more seconds (its active task; ``pose`` is then where that task
    ends). None when the task cannot be reached. ``battery`` None: no energy constraint."""
    if not speed > 0:
        raise ValueError(f"speed {speed!r} must be positive (m/s)")
    if travel is None:

        def travel(a: Point, b: Point) -> float:
            return math.hypot(b[0] - a[0], b[1] - a[1]) / speed

    new = estimate(task, speed, travel)
    if new is None:
        return None
    ests = []
    for q in queue:
        e = estimate(q, speed, travel)
        ests.append(e if e is not None else (pose, pose, 0.0, 0.0))
    n = len(ests)
    ent_new, ex_new, work_new, m_new = new
    # leg k goes from stop k-1 (the pose for k = 0) to the entry of queue task k
    exits = [pose] + [e[1] for e in ests]  # n + 1: where the robot is before place k
    entries = [e[0] for e in ests]
    to_new = [travel(p, ent_new) for p in exits]  # n + 1 legs to the new task
    if all(t is None for t in to_new):
        return None
    from_new = [travel(ex_new, e) for e in entries] + [0.0]  # new task -> the next queued one
    base = [travel(exits[k], entries[k]) for k in range(n)] + [0.0]
    inf = math.inf
    to_a = np.array([inf if t is None else t for t in to_new])
    from_a = np.array([inf if t is None else t for t in from_new])
    base_a = np.array([0.0 if t is None else t for t in base])
    work = np.array([e[2] for e in ests] + [0.0])
    # finish times of the queue as it is: cumulative legs + work
    legs = base_a + work
    start = busy_until + np.concatenate([[0.0], np.cumsum(legs[:-1])])  # time robot leaves stop k-1
    finish_new = start + to_a + work_new
    detour = to_a + work_new + from_a - base_a  # extra time for everything after place k
    after = n - np.arange(n + 1)  # tasks after place k
    delay = np.where(after > 0, detour * after, 0.0)
    cost = finish_new + delay
    charge = np.zeros(n + 1)
    if battery is not None:
        total_s = float(start[-1] + legs[-1]) + float(to_a.min()) + work_new
        metres = speed * (float(np.sum(base_a)) + float(to_a.min())) + m_new + sum(e[3] for e in ests)
        left = battery - metres * energy.per_metre - total_s * energy.per_second
        if left < threshold:  # the plan needs a recharge on the way
            charge[:] = (target - max(left, 0.0)) / energy.charge_rate
            cost = cost + charge
    if not np.isfinite(cost).any():
        return None
    k = int(np.argmin(cost))
    return Bid(float(cost[k]), float(finish_new[k] + charge[k]), float(delay[k]), k, float(charge[k]))
