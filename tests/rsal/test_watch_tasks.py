"""The fleet dispatcher's tasks in ``rsal watch`` (:mod:`rsal.watch.tasks`): the pure conversion
of ``task_state`` and ``fleet`` bodies to drawings, the hold of ended tasks, and the logger drawing
them from service samples (in memory, a fake recording stream)."""

from __future__ import annotations

import collections
from types import SimpleNamespace

import msgpack
import numpy as np
import pytest

from agents.dispatch.tasks import FleetMsg, TaskStatus
from rsal.watch import Watcher, WatchOptions
from rsal.watch.tasks import STATE_COLORS, TaskView, robot_link, task_drawing, task_log


def _state(tid="t1", kind="go_to", state="bidding", robot="", places=((3.5, -2.5),), **kw) -> dict:
    # the dispatcher's own wire type, so the view reads what the dispatcher sends
    return TaskStatus(tid, kind, state, robot, places=tuple(places), **kw).to_dict()


def test_a_go_to_is_its_goal_coloured_by_state_and_labelled():
    d = task_drawing(_state(state="active", robot="fleet0"))
    assert d is not None and d.points.tolist() == [[3.5, -2.5]] and d.strip is None
    assert d.color == STATE_COLORS["active"] and d.label == "t1 go_to active -> fleet0"
    assert task_drawing(_state(state="bidding")).label == "t1 go_to bidding -> -"
    assert task_drawing(_state(state="bidding")).color != d.color


def test_a_patrol_route_is_a_closed_line_strip_and_a_fetch_a_line():
    route = [(1.0, -2.5), (4.0, -2.5), (4.0, 2.5)]
    d = task_drawing(_state(kind="patrol", places=route))
    assert d.points.tolist() == [list(p) for p in route]
    assert d.strip.tolist() == [list(p) for p in route] + [[1.0, -2.5]]
    f = task_drawing(_state(kind="fetch", places=[(1, 1), (2, 2)]))
    assert f.strip.tolist() == [[1, 1], [2, 2]]


def test_what_names_no_task_or_has_bad_places_is_not_drawn():
    assert task_drawing(_state(tid="?", state="refused", places=())) is None
    assert task_drawing({"task_id": "t1", "state": "nope", "places": []}) is None
    assert task_drawing({"task_id": "t1", "state": "active", "places": [[1, "a"]]}) is None
    assert task_drawing({"task_id": "t1", "state": "active", "places": [[1, 2, 3]]}) is None
    d = task_drawing(_state(kind="charge", places=()))  # a charge task before its charger is chosen
    assert d is not None and len(d.points) == 0


def test_log_entries_name_the_change_and_warn_on_failure():
    assert task_log(_state(state="assigned", robot="fleet1")) == ("t1 go_to assigned -> fleet1", "INFO")
    text, level = task_log(_state(state="refused", reason="outside_map", text="goal is outside the map"))
    assert level == "WARN" and "outside_map" in text and "outside the map" in text


def test_the_link_goes_from_the_robot_to_its_next_point():
    m = FleetMsg("status", robot="r0", x=1.0, y=2.0, active="t1", target=(3.0, 4.0)).to_dict()
    tid, line = robot_link(m)
    assert tid == "t1" and line.tolist() == [[1.0, 2.0], [3.0, 4.0]]
    assert robot_link(m, (1.5, 2.5))[1].tolist() == [[1.5, 2.5], [3.0, 4.0]]  # the view's ground truth
    idle = FleetMsg("status", robot="r0", x=1.0, y=2.0).to_dict()
    assert robot_link(idle) is None
    assert robot_link({"op": "bid", "active": "t1", "target": [1, 2]}) is None


def test_ended_tasks_leave_after_the_hold_and_links_only_while_active():
    v = TaskView(hold=3.0)
    v.state(_state(state="active", robot="f0"), now=0.0)
    assert v.link("t1") and v.unlink() == []
    v.state(_state(state="done", robot="f0"), now=10.0)
    assert v.unlink() == ["t1"] and not v.link("t1")
    assert v.expired(12.9) == [] and v.expired(13.0) == ["t1"] and v.expired(20.0) == []
    v.state(_state(tid="t2", state="failed"), now=0.0)
    v.state(_state(tid="t2", state="bidding"), now=1.0)  # re-bid: lives again
    assert v.expired(100.0) == []


def _svc(service: str, sender: str, body: dict) -> SimpleNamespace:
    data = msgpack.packb({"sender": sender, "conversation": "c", "time": 1.0, **body})
    return SimpleNamespace(key_expr=f"svc/{service}/{sender}", payload=SimpleNamespace(to_bytes=lambda: data))


class FakeRec:
    def __init__(self):
        self.logs: list[tuple[str, str, object]] = []

    def log(self, path, archetype, static=False):
        self.logs.append((path, type(archetype).__name__, archetype))

    def set_time(self, *a, **kw):
        pass


def test_the_watcher_draws_tasks_links_and_log_and_clears_ended_ones():
    rec = FakeRec()
    w = Watcher(session=None, rec=rec, opts=WatchOptions(task_hold=0.0))
    route = [(1.0, -2.5), (4.0, -2.5), (4.0, 2.5)]
    for st in ("bidding", "assigned", "active"):
        w._on_text(_svc("task_state", "dispatcher", _state(kind="patrol", state=st, robot="f0", places=route)))
    fleet = FleetMsg("status", robot="r0", x=0.5, y=0.5, active="t1", target=(4.0, -2.5)).to_dict()
    w._on_text(_svc("fleet", "f0", fleet))
    w.tick()
    kinds = collections.Counter((p, k) for p, k, _ in rec.logs)
    assert kinds[("world/tasks/t1", "Points2D")] == 3 and kinds[("world/tasks/t1/route", "LineStrips2D")] == 3
    assert kinds[("world/tasks/t1/link", "LineStrips2D")] == 1 and kinds[("log/tasks", "TextLog")] == 3
    link = next(a for p, k, a in rec.logs if p == "world/tasks/t1/link")
    pts = np.asarray(link.strips.as_arrow_array().to_pylist()[0], dtype=float)
    assert pts == pytest.approx(np.array([[0.5, 0.5], [4.0, -2.5]]))  # from the robot's reported pose
    texts = [str(a.text.as_arrow_array().to_pylist()[0]) for p, k, a in rec.logs if p == "log/tasks"]
    assert texts == ["t1 patrol bidding -> f0", "t1 patrol assigned -> f0", "t1 patrol active -> f0"]
    n = len(rec.logs)
    w._on_text(_svc("task_state", "dispatcher", _state(kind="patrol", state="done", robot="f0", places=route)))
    w.tick()
    new = [(p, k) for p, k, _ in rec.logs[n:]]
    # drawn done, its link cleared, then (hold 0) the task leaves the map; the log keeps it
    assert ("world/tasks/t1", "Points2D") in new and ("log/tasks", "TextLog") in new
    assert ("world/tasks/t1/link", "Clear") in new and new[-1] == ("world/tasks/t1", "Clear")
