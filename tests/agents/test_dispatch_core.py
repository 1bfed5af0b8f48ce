"""The dispatcher's logic on a fake clock: bidding windows, awards, direct assignment, forfeits and
lost robots re-bid, re-assignment, charging policy, bad input refused with typed reasons, the
robots' cost model and the wire schema.

No network: :class:`agents.dispatch.Dispatcher` sends into a list, the robots are in-memory fakes
that bid with :func:`agents.dispatch.plan_bid` and answer when the test says so.
"""

from __future__ import annotations

import itertools
import logging
import math

import numpy as np
import pytest

from agents.dispatch import (
    ChargePolicy,
    Charger,
    Dispatcher,
    DispatchMsg,
    FleetMsg,
    Refusal,
    Task,
    TaskRefused,
    TaskRequest,
    TaskState,
    TaskStatus,
    parse_task,
    plan_bid,
    task_places,
)
from agents.dispatch.mapcheck import MapCheck
from agents.dispatch.tasks import decode_body
from rsal.msgs import MapData, MessageError


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class Harness:
    """A dispatcher on a fake clock with fake robots that bid their straight-line cost."""

    def __init__(self, **kw) -> None:
        self.clock = FakeClock()
        self.out: list = []
        self.d = Dispatcher(now=self.clock, send=self.out.append, **kw)
        self.pos: dict[str, tuple[float, float]] = {}
        self.auto_bid = True

    def robot(self, agent: str, x: float, y: float, battery: float = -1.0, charging: bool = False) -> None:
        self.pos[agent] = (x, y)
        self.d.on_fleet(agent, FleetMsg("status", robot=agent.upper(), x=x, y=y, battery=battery, charging=charging))

    def calls(self) -> list[DispatchMsg]:
        return [m for m in self.out if isinstance(m, DispatchMsg) and m.op == "call"]

    def awards(self, task_id: str | None = None) -> list[DispatchMsg]:
        return [m for m in self.out if isinstance(m, DispatchMsg) and m.op == "award" and task_id in (None, m.task_id)]

    def answer(self, call: DispatchMsg, only: set[str] | None = None) -> None:
        """Every called robot (or those in ``only``) bids its plan_bid cost for ``call``."""
        t = parse_task(call.task)
        for a in sorted(self.pos):
            if a in call.exclude or (only is not None and a not in only):
                continue
            queue = [self.d.tasks[q] for q in self.d.robots[a].queue if q != call.task_id]
            pose, shift = self.pos[a], 0
            if queue and queue[0].state is TaskState.ACTIVE:  # as a robot does: after its active task
                pose, shift = task_places(queue[0].task)[-1], 1
            b = plan_bid(pose, [r.task for r in queue[shift:]], t)
            self.d.on_fleet(
                a, FleetMsg("bid", task_id=call.task_id, round=call.round, cost=b.cost, index=b.index + shift)
            )

    def submit(self, task: dict) -> str:
        n = len(self.calls())
        rec = self.d.submit(task, "tester")
        if self.auto_bid and len(self.calls()) > n:
            self.answer(self.calls()[-1])
        return rec.task.id

    def advance(self, dt: float, step: float = 0.1) -> None:
        start, n = self.clock.t, max(1, round(dt / step))
        for i in range(1, n + 1):
            self.clock.t = start + dt * i / n
            self.d.tick()

    def state(self, tid: str) -> TaskState:
        return self.d.tasks[tid].state


GO = {"kind": "go_to", "args": {"x": 10.0, "y": 0.0}}


# ---------------------------------------------------------------------------- bidding
def test_window_awards_the_lowest_cost_once_every_robot_answered():
    h = Harness(window=2.0)
    h.robot("a", 0, 0)
    h.robot("b", 9, 0)
    h.auto_bid = False
    tid = h.submit(GO)
    call = h.calls()[-1]
    assert call.reply_by == pytest.approx(2.0) and call.task["kind"] == "go_to"
    h.answer(call, only={"a"})
    h.advance(1.0)
    assert h.state(tid) is TaskState.BIDDING  # b has not answered and the window is open
    h.answer(call, only={"b"})  # everyone answered: awarded at once, before the window ends
    assert h.state(tid) is TaskState.ASSIGNED and h.d.tasks[tid].robot == "b"
    assert [m.to for m in h.awards(tid)] == ["b"]


def test_window_closes_without_the_silent_robot_and_late_bids_are_ignored():
    h = Harness(window=2.0)
    h.robot("a", 0, 0)
    h.robot("b", 9, 0)
    h.auto_bid = False
    tid = h.submit(GO)
    call = h.calls()[-1]
    h.answer(call, only={"a"})
    h.advance(1.9)
    assert h.state(tid) is TaskState.BIDDING
    h.advance(0.2)
    assert h.d.tasks[tid].robot == "a"  # the window closed with a's bid only
    assert h.d.latencies and max(h.d.latencies) <= 0.1
    h.answer(call, only={"b"})  # late: changes nothing
    assert h.d.tasks[tid].robot == "a" and len(h.awards(tid)) == 1


def test_cost_ties_go_to_the_smaller_agent_id():
    h = Harness()
    h.robot("b", 5, 5)
    h.robot("a", 5, -5)
    tid = h.submit(GO)
    assert h.d.tasks[tid].robot == "a"


def test_cost_includes_the_delay_to_the_robots_other_tasks():
    # a is near but has a long task queued at the goal's far side; b is a bit farther and idle
    h = Harness()
    h.robot("a", 0, 0)
    h.robot("b", 14, 0)
    first = h.submit({"kind": "go_to", "args": {"x": -40.0, "y": 0.0}, "robot": "a"})
    assert h.d.tasks[first].robot == "a"
    tid = h.submit({"kind": "go_to", "args": {"x": 6.0, "y": 0.0}})
    # a: finish 80 + 12 = 92 at the end, or 12 first + delay 24 = 36; b: 16 -> b
    assert h.d.tasks[tid].robot == "b"


def test_direct_assignment_skips_bidding_and_unknown_robot_is_refused():
    h = Harness()
    h.robot("a", 0, 0)
    h.robot("b", 9, 0)
    tid = h.submit({**GO, "robot": "a"})
    assert h.d.tasks[tid].robot == "a" and not h.calls()
    with pytest.raises(TaskRefused) as e:
        h.submit({**GO, "robot": "zz"})
    assert e.value.reason is Refusal.UNKNOWN_ROBOT and "known: a, b" in str(e.value)
    refused = [m for m in h.out if isinstance(m, TaskStatus) and m.state == "refused"]
    assert refused and refused[-1].reason == "unknown_robot"


def test_no_bids_calls_again_then_fails():
    h = Harness(window=1.0, retry=2.0, max_rounds=3)
    h.robot("a", 0, 0)
    h.auto_bid = False
    tid = h.submit(GO)
    h.advance(20)
    assert len(h.calls()) == 3
    assert h.state(tid) is TaskState.FAILED and h.d.tasks[tid].reason == "no_bids"


# ---------------------------------------------------------------------------- failures
def _progress(h: Harness, agent: str, tid: str, state: str, reason: str = "") -> None:
    h.d.on_fleet(agent, FleetMsg("progress", task_id=tid, state=state, reason=reason))


@pytest.mark.parametrize("how", ["failed", "forfeit"])
def test_failed_or_forfeited_task_is_rebid_without_that_robot(how):
    h = Harness()
    h.robot("a", 9, 0)
    h.robot("b", 0, 0)
    tid = h.submit(GO)
    assert h.d.tasks[tid].robot == "a"
    _progress(h, "a", tid, "active")
    assert h.state(tid) is TaskState.ACTIVE
    _progress(h, "a", tid, how, "bumped")
    call = h.calls()[-1]
    assert "a" in call.exclude and h.state(tid) is TaskState.BIDDING
    h.answer(call)
    assert h.d.tasks[tid].robot == "b"
    _progress(h, "a", tid, "done")  # a late done from the robot that lost it: ignored
    assert h.state(tid) is TaskState.ASSIGNED
    _progress(h, "b", tid, "done")
    _progress(h, "b", tid, "done")
    done = [m for m in h.out if isinstance(m, TaskStatus) and m.task_id == tid and m.state == "done"]
    assert len(done) == 1 and done[0].robot == "b"


def test_lost_robot_tasks_are_rebid_and_open_calls_stop_waiting_for_it():
    h = Harness(window=5.0)
    h.robot("a", 9, 0)
    h.robot("b", 0, 0)
    t1 = h.submit(GO)
    t2 = h.submit({"kind": "go_to", "args": {"x": 12.0, "y": 0.0}})
    assert h.d.tasks[t1].robot == h.d.tasks[t2].robot == "a"
    h.auto_bid = False
    t3 = h.submit({"kind": "go_to", "args": {"x": -3.0, "y": 0.0}})
    h.answer(h.calls()[-1], only={"b"})  # a never answers t3
    n = len(h.calls())
    h.d.robot_lost("a")
    assert h.d.tasks[t3].robot == "b"  # the open call no longer waits for a
    new = h.calls()[n:]
    assert {c.task_id for c in new} == {t1, t2} and all("a" in c.exclude for c in new)
    for c in new:
        h.answer(c)
    assert h.d.tasks[t1].robot == h.d.tasks[t2].robot == "b"
    assert h.d.robots["a"].queue == []


def test_subscriber_of_another_robot_cannot_move_a_task():
    h = Harness()
    h.robot("a", 9, 0)
    h.robot("b", 0, 0)
    tid = h.submit(GO)
    _progress(h, "b", tid, "failed")
    _progress(h, "b", tid, "done")
    assert h.state(tid) is TaskState.ASSIGNED and h.d.tasks[tid].robot == "a"


# ---------------------------------------------------------------------------- re-assignment
def test_periodic_reassignment_moves_a_waiting_task_to_a_clearly_better_robot():
    h = Harness(reassign_period=10.0, reassign_margin=5.0)
    h.robot("a", 0, 0)
    first = h.submit({"kind": "go_to", "args": {"x": -40.0, "y": 0.0}})
    _progress(h, "a", first, "active")
    tid = h.submit({"kind": "go_to", "args": {"x": 30.0, "y": 0.0}})
    assert h.d.robots["a"].queue == [first, tid]
    h.robot("b", 30, 1)  # joins next to the waiting task's goal
    h.advance(10.0)
    call = next(c for c in h.calls() if c.task_id == tid and c.round == 2)
    assert "a" not in call.exclude  # the holder bids as well
    h.answer(call)
    revokes = [m for m in h.out if isinstance(m, DispatchMsg) and m.op == "revoke"]
    assert [(m.task_id, m.to) for m in revokes] == [(tid, "a")]
    assert h.d.tasks[tid].robot == "b" and h.d.robots["a"].queue == [first]
    assert not [c for c in h.calls() if c.task_id == first and c.round > 1]  # the active task stays


def test_reassignment_keeps_the_holder_within_the_margin():
    h = Harness(reassign_period=10.0, reassign_margin=5.0)
    h.robot("a", 0, 0)
    first = h.submit({"kind": "go_to", "args": {"x": 1.0, "y": 0.0}})
    _progress(h, "a", first, "active")
    tid = h.submit({"kind": "go_to", "args": {"x": 3.0, "y": 0.0}})
    h.robot("b", 2.0, 0)
    h.advance(10.0)
    for c in h.calls():
        if c.task_id == tid and c.round == 2:
            h.answer(c)
    assert h.d.tasks[tid].robot == "a"
    assert not [m for m in h.out if isinstance(m, DispatchMsg) and m.op == "revoke"]


# ---------------------------------------------------------------------------- charging
CHARGERS = [Charger("c0", -5.0, 0.0), Charger("c1", 20.0, 0.0)]


def test_low_battery_robot_goes_to_the_nearest_free_charger_and_gets_no_work():
    h = Harness(policy=ChargePolicy(threshold=0.2, target=0.9), chargers=CHARGERS)
    h.robot("a", 0, 0, battery=0.5)
    h.robot("b", 30, 0, battery=0.9)
    t1 = h.submit({"kind": "go_to", "args": {"x": -2.0, "y": 0.0}})
    t2 = h.submit({"kind": "go_to", "args": {"x": -1.0, "y": 0.0}})
    assert h.d.robots["a"].queue == [t1, t2] or set(h.d.robots["a"].queue) == {t1, t2}
    _progress(h, "a", h.d.robots["a"].queue[0], "active")
    active = h.d.robots["a"].queue[0]
    waiting = h.d.robots["a"].queue[1]
    h.robot("a", 0, 0, battery=0.15)
    h.advance(0.1)
    charge = h.d.robots["a"].charge_task
    assert charge and h.d.tasks[charge].task.args["charger"] == "c0"
    assert h.d.robots["a"].queue == [active, charge]  # the active task finishes first
    assert h.state(waiting) is TaskState.BIDDING and "a" in h.calls()[-1].exclude
    h.answer(h.calls()[-1])
    assert h.d.tasks[waiting].robot == "b"
    h.auto_bid = False
    t3 = h.submit({"kind": "go_to", "args": {"x": 0.5, "y": 0.0}})
    assert "a" in h.calls()[-1].exclude  # charging robots are not called for work
    _progress(h, "a", active, "done")
    _progress(h, "a", charge, "active")
    h.robot("a", -5, 0, battery=0.91, charging=True)
    _progress(h, "a", charge, "done")
    assert h.d.robots["a"].charger == "" and h.state(charge) is TaskState.DONE
    assert h.d.available(h.d.robots["a"])
    assert t3 in h.d.tasks


def test_fewer_chargers_than_robots_the_others_wait_for_one():
    h = Harness(policy=ChargePolicy(threshold=0.2, target=0.9), chargers=[Charger("c0", 0.0, 0.0)])
    for i, b in enumerate((0.1, 0.15, 0.12)):
        h.robot(f"r{i}", i, 0, battery=b)
    h.advance(0.1)
    holders = [a for a, r in h.d.robots.items() if r.charger]
    assert holders == ["r0"]  # the lowest battery first, one robot per charger
    h.robot("r0", 0, 0, battery=0.9)
    _progress(h, "r0", h.d.robots["r0"].charge_task, "done")
    h.advance(0.1)
    assert [a for a, r in h.d.robots.items() if r.charger] == ["r2"]


def test_charging_off_sends_nobody_to_charge():
    h = Harness(policy=ChargePolicy(enabled=False), chargers=CHARGERS)
    h.robot("a", 0, 0, battery=0.01)
    h.advance(1.0)
    assert not h.awards() and h.d.available(h.d.robots["a"])


@pytest.mark.parametrize("finishing", ["park", "charge", "nothing"])
def test_finishing_request_when_the_queue_empties(finishing):
    h = Harness(policy=ChargePolicy(threshold=0.2, target=0.9, finishing=finishing), chargers=CHARGERS)
    h.robot("a", 1, 2, battery=0.6)
    tid = h.submit(GO)
    _progress(h, "a", tid, "done")
    new = [m for m in h.awards() if m.task_id != tid]
    if finishing == "nothing":
        assert not new
    elif finishing == "park":
        assert [(m.task["kind"], m.task["args"]["x"], m.task["args"]["y"]) for m in new] == [("go_to", 1, 2)]
    else:
        assert [(m.task["kind"], m.task["args"]["charger"]) for m in new] == [("charge", "c0")]


def test_robot_without_battery_model_is_dispatched_and_said_once(caplog):
    h = Harness(policy=ChargePolicy(threshold=0.2), chargers=CHARGERS)
    with caplog.at_level(logging.WARNING, logger="agents.dispatch.core"):
        for _ in range(3):
            h.robot("a", 0, 0, battery=-1.0)
    said = [r for r in caplog.records if "no battery model" in r.getMessage()]
    assert len(said) == 1 and "without energy constraints" in said[0].getMessage()
    h.advance(1)
    tid = h.submit(GO)
    assert h.d.tasks[tid].robot == "a"


# ---------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "task, reason, words",
    [
        ({"kind": "goto", "args": {"x": 1, "y": 1}}, Refusal.UNKNOWN_KIND, "did you mean 'go_to'"),
        ({"kind": "dance"}, Refusal.UNKNOWN_KIND, "use one of go_to"),
        ({"kind": "go_to", "args": {"x": "a", "y": 1}}, Refusal.BAD_FIELD, "'x' must be a number"),
        ({"kind": "patrol", "args": {"route": [[0, 0]]}}, Refusal.BAD_FIELD, "two or more points"),
        ({"kind": "patrol", "args": {"route": [[0, 0], [1, 1]], "laps": 0}}, Refusal.BAD_FIELD, "'laps'"),
        ({"kind": "fetch", "args": {"at": [0, 0], "to": [1, 1]}}, Refusal.BAD_FIELD, "'object'"),
        ({"kind": "charge", "args": {"charger": "nope"}}, Refusal.UNKNOWN_CHARGER, "chargers: c0, c1"),
        ({"kind": "custom", "args": {"at": [0, 0], "duration": -1}}, Refusal.BAD_FIELD, "'duration'"),
        ("go", Refusal.BAD_FIELD, "a task is a map"),
    ],
)
def test_bad_tasks_are_refused_with_a_typed_reason_in_one_line(task, reason, words):
    h = Harness(chargers=CHARGERS)
    with pytest.raises(TaskRefused) as e:
        h.d.submit(task, "tester")
    assert e.value.reason is reason and words in str(e.value) and "\n" not in str(e.value)
    st = [m for m in h.out if isinstance(m, TaskStatus)]
    assert st[-1].state == "refused" and st[-1].reason == reason.value


def test_duplicate_id_and_cancel():
    h = Harness()
    h.robot("a", 0, 0)
    tid = h.submit({**GO, "id": "job1"})
    with pytest.raises(TaskRefused) as e:
        h.d.submit({**GO, "id": "job1"})
    assert e.value.reason is Refusal.DUPLICATE_ID
    h.d.cancel(tid, "tester")
    assert h.state(tid) is TaskState.CANCELLED and h.d.robots["a"].queue == []
    assert [(m.op, m.to) for m in h.out if isinstance(m, DispatchMsg) and m.op == "revoke"] == [("revoke", "a")]
    with pytest.raises(TaskRefused) as e:
        h.d.cancel("zz")
    assert e.value.reason is Refusal.NOT_FOUND


@pytest.fixture
def room() -> MapData:
    """A 10 x 6 m room at 0.1 m cells, walls around, an inner wall at x = 5 m from y = 0 to 4 m,
    and a closed box (walls all around) at x 7..9, y 4..6."""
    cells = -np.ones((60, 100), dtype=np.int8)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 1
    cells[0:40, 50] = 1
    cells[40:60, 70] = cells[40, 70:100] = 1
    return MapData(100, 60, 0.1, (0.0, 0.0), cells)


@pytest.mark.parametrize(
    "task, reason, words",
    [
        ({"kind": "go_to", "args": {"x": 12, "y": 1}}, Refusal.OUTSIDE_MAP, "use x in [0, 10]"),
        ({"kind": "go_to", "args": {"x": 5.0, "y": 2.0}}, Refusal.UNREACHABLE, "in or next to a wall"),
        ({"kind": "go_to", "args": {"x": 8.5, "y": 5.0}}, Refusal.UNREACHABLE, "no robot can reach"),
        ({"kind": "patrol", "args": {"route": [[2, 2], [8, 2]]}}, Refusal.THROUGH_WALL, "crosses a wall near (5."),
        ({"kind": "fetch", "args": {"object": "box", "at": [2, 2], "to": [-1, 2]}}, Refusal.OUTSIDE_MAP, "point 1"),
    ],
)
def test_map_checks(room, task, reason, words):
    check = MapCheck(room, [(1.0, 1.0)])
    h = Harness(check=check)
    with pytest.raises(TaskRefused) as e:
        h.d.submit(task)
    assert e.value.reason is reason and words in str(e.value)
    h.robot("a", 1, 1)
    ok = h.submit({"kind": "patrol", "args": {"route": [[2, 2], [2, 5], [6, 5]]}})  # around the wall
    assert h.d.tasks[ok].robot == "a"
    with pytest.raises(ValueError, match="charger 'far' .* is outside the map"):
        check.check_chargers([Charger("far", 30, 1)], "patrol.yaml")


# ---------------------------------------------------------------------------- the cost model
def test_plan_bid_matches_brute_force_over_every_place_in_the_queue():
    rng = np.random.default_rng(3)
    for _ in range(30):
        pts = rng.uniform(-10, 10, (6, 2))
        queue = [Task(f"q{i}", "go_to", {"x": p[0], "y": p[1], "yaw": 0.0}) for i, p in enumerate(pts[:4])]
        new = Task("n", "custom", {"at": list(pts[4]), "duration": 3.0})
        pose = tuple(pts[5])
        b = plan_bid(pose, queue, new, speed=0.5)

        def finishes(order, pose=pose):
            t, here, out = 0.0, pose, {}
            for task in order:
                p = (task.args["x"], task.args["y"]) if task.kind == "go_to" else tuple(task.args["at"])
                t += math.dist(here, p) / 0.5 + (3.0 if task.kind == "custom" else 0.0)
                here = p
                out[task.id] = t
            return out

        base = finishes(queue)
        best = min(
            (f["n"] + sum(f[q.id] - base[q.id] for q in queue), k)
            for k in range(len(queue) + 1)
            for f in [finishes(queue[:k] + [new] + queue[k:])]
        )
        assert b.cost == pytest.approx(best[0]) and b.index == best[1]


def test_plan_bid_unreachable_and_battery():
    t = Task("n", "go_to", {"x": 100.0, "y": 0.0, "yaw": 0.0})
    assert plan_bid((0, 0), [], t, travel=lambda a, b: None) is None
    full = plan_bid((0, 0), [], t, battery=0.9)
    low = plan_bid((0, 0), [], t, battery=0.203, threshold=0.2, target=0.9)
    assert full.charge == 0 and full.cost == pytest.approx(200.0)
    assert low.charge > 3000 and low.cost == pytest.approx(200.0 + low.charge)


# ---------------------------------------------------------------------------- wire schema
def test_messages_round_trip_and_malformed_ones_are_refused():
    for body in (
        TaskRequest("submit", {"kind": "go_to", "args": {"x": 1, "y": 2}}),
        TaskStatus("t1", "go_to", "assigned", "a", "", "awarded to a", "cc"),
        DispatchMsg("call", "t1", "", {"kind": "go_to"}, 2, 1.5e9, -1, ("a", "b")),
        FleetMsg("bid", task_id="t1", round=2, cost=3.5, finish=3.0, index=1),
        FleetMsg("status", robot="r0", x=1, y=2, battery=0.5, charging=True, queue=("t1",), active="t1"),
    ):
        assert decode_body(body.SERVICE, body.to_dict()) == body
    for service, m in (
        ("task_request", {"op": "explode"}),
        ("dispatch", {"op": "award", "task_id": "t1"}),
        ("fleet", {"op": "bid", "task_id": "t1", "cost": -1}),
        ("fleet", {"op": "progress", "task_id": "t1", "state": "bored"}),
        ("fleet", {"op": "status", "battery": 3}),
    ):
        with pytest.raises(MessageError):
            decode_body(service, m)


def test_many_tasks_none_lost_or_done_twice():
    """500 tasks over 20 robots, a quarter of them failed once: all done exactly once."""
    h = Harness(window=1.0, max_rounds=10)
    for i in range(20):
        h.robot(f"r{i:02d}", i * 2.0, 0)
    rng = np.random.default_rng(1)
    tids = [
        h.submit({"kind": "go_to", "args": {"x": float(x), "y": float(y)}}) for x, y in rng.uniform(0, 40, (500, 2))
    ]
    fail = set(tids[::4])
    for _ in itertools.count():
        pending = [t for t in tids if not h.state(t).final]
        if not pending:
            break
        for t in pending:
            rec = h.d.tasks[t]
            if rec.state is TaskState.ASSIGNED:
                _progress(h, rec.robot, t, "failed" if t in fail else "done")
                fail.discard(t)
        for c in h.calls():
            if not h.d.tasks[c.task_id].bids and h.d.tasks[c.task_id].closes < math.inf:
                h.answer(c)
        h.advance(1.0)
    done = [m for m in h.out if isinstance(m, TaskStatus) and m.state == "done"]
    assert sorted(m.task_id for m in done) == sorted(tids)
