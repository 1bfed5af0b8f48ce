"""The dispatcher's tasks for a person: the live task list (:class:`agents.dispatch.client.TaskBoard`),
the control center's task form (:func:`agents.control.tasks.task_from_form`) and, with real
processes, the control center's Tasks panel API.

The integration test starts ``rsal control`` and ``rsal agent DispatcherAgent`` as processes and a
stand-in robot agent in this process (a :class:`~agents.dispatch.agent.FleetWorker` with no
simulator, keeping its own record of what it performed); a task submitted with ``rsal task`` shows
in ``GET /api/tasks`` with its states in order (bidding, assigned, active, done) and the robot
that truly performed it; one submitted and cancelled through the API is cancelled and never
performed; a bad task is refused in one line.
"""

from __future__ import annotations

import subprocess

import pytest

from agents.control.api import ApiError
from agents.control.tasks import task_from_form
from agents.dispatch.client import TaskBoard, parse_route, submit_request
from agents.dispatch.tasks import TaskStatus
from agents.runtime import AgentHost
from rsal.transport import TransportArgs
from tests.agents.browser import save_screenshot
from tests.agents.standin import StandIn
from tests.agents.test_control import assert_one_line_error, call
from tests.conftest import ROOT, LoopThread, free_port, rsal_cmd, wait_until


# ---------------------------------------------------------------------------- the board
def _st(tid: str, state: str, robot: str = "", kind: str = "go_to") -> TaskStatus:
    return TaskStatus(tid, kind, state, robot, places=((1.0, 2.0),))


def test_the_board_lists_live_tasks_with_their_states_in_order_and_age():
    b = TaskBoard(hold=10.0)
    for t, st in ((0.0, "bidding"), (0.5, "assigned"), (1.0, "active"), (1.0, "active")):
        b.apply(_st("t1", st, "fleet0" if st != "bidding" else ""), t)
    b.apply(_st("t2", "bidding"), 2.0)
    rows = b.rows(3.0)
    assert [r["id"] for r in rows] == ["t1", "t2"]  # oldest first
    r = rows[0]
    assert r["states"] == ["bidding", "assigned", "active"] and r["robot"] == "fleet0" and r["state"] == "active"
    assert r["age"] == 3.0 and r["kind"] == "go_to" and r["places"] == [[1.0, 2.0]] and r["final"] is False


def test_ended_tasks_stay_for_the_hold_then_leave():
    b = TaskBoard(hold=10.0)
    b.apply(_st("t1", "bidding"), 0.0)
    b.apply(_st("t1", "active", "fleet0"), 1.0)
    b.apply(_st("t1", "cancelled"), 5.0)  # the dispatcher's cancel names no robot
    assert b.rows(15.0)[0]["final"] is True and b.rows(15.0)[0]["robot"] == "fleet0"
    assert b.rows(15.1) == []
    b.apply(_st("t2", "failed"), 0.0)
    b.apply(_st("t2", "bidding"), 1.0)  # re-bid: alive again
    assert [r["id"] for r in b.rows(100.0)] == ["t2"]


def test_statuses_of_no_task_are_not_listed_and_wait_has_a_deadline():
    b = TaskBoard()
    assert b.apply(TaskStatus("?", "gotu", "refused", reason="unknown_kind"), 0.0) is None
    assert b.apply(TaskStatus("nope", "", "refused", reason="not_found"), 0.0) is None  # a refused cancel
    assert b.rows(0.0) == []
    assert b.wait("t1", None, 0.05) is None
    b.apply(_st("t1", "bidding"), 0.0)
    assert b.wait("t1", {"bidding"}, 0.05).last.state == "bidding"
    with pytest.raises(ValueError, match="hold"):
        TaskBoard(hold=-1)


def test_requests_are_the_ones_rsal_task_sends():
    r = submit_request("go_to", {"x": 1, "y": 2}, "fleet0", prefix="ctl")
    assert r.op == "submit" and r.task["id"].startswith("ctl-") and r.task["robot"] == "fleet0"
    assert r.task["kind"] == "go_to" and r.task["args"] == {"x": 1, "y": 2}
    assert submit_request("charge", {}, task_id="c1").task["id"] == "c1"


def test_routes_typed_by_a_person():
    assert parse_route("1, -2.5; 4, -2.5\n4 2.5") == [[1.0, -2.5], [4.0, -2.5], [4.0, 2.5]]
    assert parse_route("[[1, 2], [3, 4]]") == [[1.0, 2.0], [3.0, 4.0]]
    for bad in ("1, 2", "1, 2; a, b", "[[1, 2], [3]]", "", "[1, 2"):
        with pytest.raises(ValueError, match="route"):
            parse_route(bad)


def test_the_task_form_checks_its_fields():
    assert task_from_form({"kind": "go_to", "x": 1, "y": 2.5}) == ("go_to", {"x": 1.0, "y": 2.5}, "")
    kind, args, robot = task_from_form({"kind": "patrol", "route": "0, 0; 1, 0", "laps": 2, "robot": "fleet1"})
    assert (kind, args, robot) == ("patrol", {"route": [[0.0, 0.0], [1.0, 0.0]], "laps": 2}, "fleet1")
    assert task_from_form({"kind": "charge", "charger": "c0"}) == ("charge", {"charger": "c0"}, "")
    for body, text in (
        ({"kind": "goto"}, "not one of"),
        ({"kind": "go_to", "x": 1}, "y is missing"),
        ({"kind": "go_to", "x": "a", "y": 1}, "finite number"),
        ({"kind": "patrol", "route": "1, 2"}, "two or more"),
        ({"kind": "go_to", "x": 1, "y": 1, "robot": "a b"}, "robot"),
        ({"kind": "go_to", "x": 1, "y": 1, "colour": "red"}, "unknown field"),
    ):
        with pytest.raises(ApiError, match=text):
            task_from_form(body)


def test_the_api_answers_in_one_line_when_it_cannot_send(tmp_path):
    from agents.control import Control

    c = Control(tmp_path, "tcp/127.0.0.1:1", watch=False)  # never opened: no tasks agent
    assert c.tasks() == {"tasks": [], "hold": 60.0}
    with pytest.raises(ApiError, match="tasks agent is not running") as e:
        c.submit_task({"kind": "go_to", "x": 1, "y": 1})
    assert e.value.status == 503
    with pytest.raises(ApiError, match="no task 'x'"):
        c.cancel_task("x")


def test_no_dispatcher_is_one_line_not_a_wait_for_ever(tmp_path, monkeypatch):
    import agents.control.tasks as ct
    from agents.control import Control

    monkeypatch.setattr(ct, "ANSWER_WAIT", 0.5)
    c = Control(tmp_path, "", watch=False)
    c.open(TransportArgs(listen=[f"tcp/127.0.0.1:{free_port()}"]))
    try:
        with pytest.raises(ApiError, match="no DispatcherAgent answered task ctl-.* within 0.5 s") as e:
            c.submit_task({"kind": "go_to", "x": 1, "y": 1})
        assert e.value.status == 504 and c.desk_id not in c.state()["agents"]
    finally:
        c.close()


# ---------------------------------------------------------------------------- real processes
@pytest.mark.timeout(120)
def test_control_lists_a_submitted_tasks_states_in_order_and_cancels_one(procs, tmp_path):
    port, fabric = free_port(), f"tcp/127.0.0.1:{free_port()}"
    ctl = procs(
        rsal_cmd("control", "--port", str(port), "--listen", fabric, "--no-watch", "--scenarios", str(tmp_path))
    )
    disp = procs(  # started together: it finds the control's fabric once that listens
        rsal_cmd("agent", "DispatcherAgent", "--id", "dispatcher", "--arg", "window=0.3", "--connect", fabric)
    )
    base = f"http://127.0.0.1:{port}"

    def up():
        try:
            return call(base, "GET", "/api/tasks")[0] == 200
        except OSError:
            return False

    wait_until(up, 60, f"rsal control serving on port {port}\n{ctl.output()}", interval=0.2)
    assert call(base, "GET", "/api/tasks")[1]["tasks"] == []
    lt = LoopThread()
    host = lt.run(_open_host(fabric))
    try:
        robot = lt.run(host.start(StandIn("fleet0", robot="r0")))
        wait_until(lambda: "dispatcher" in call(base, "GET", "/api/state")[1]["agents"], 60, f"{disp.output()}")

        # a task from rsal task: the panel shows its states in order and the robot that did it
        def task(*args: str) -> subprocess.CompletedProcess:
            cmd = rsal_cmd("task", *args, "--connect", fabric)
            return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=60)

        out = task("submit", "go_to", "--arg", "x=2", "--arg", "y=1", "--id", "a1")
        assert out.returncode == 0, out.stderr

        def row(tid: str, state: str):
            rows = [r for r in call(base, "GET", "/api/tasks")[1]["tasks"] if r["id"] == tid]
            return rows[0] if rows and rows[0]["state"] == state else None

        r = wait_until(lambda: row("a1", "done"), 30, f"task a1 done\n{disp.output()}")
        assert r["states"] == ["bidding", "assigned", "active", "done"]
        assert r["robot"] == "fleet0" and r["kind"] == "go_to" and r["places"] == [[2.0, 1.0]]
        assert robot.performed == ["a1"] and robot.pos == (2.0, 1.0)  # the stand-in's own record

        # a task submitted from the panel and cancelled while under way: cancelled, never performed
        lt.loop.call_soon_threadsafe(robot.hold.clear)
        status, b = call(base, "POST", "/api/tasks", body={"kind": "patrol", "route": "0, 0; 3, 0; 3, 2"})
        assert status == 200 and b["state"] == "bidding" and b["id"].startswith("ctl-"), b
        wait_until(lambda: row(b["id"], "active"), 30, "the panel's task active")
        status, c = call(base, "POST", f"/api/tasks/{b['id']}/cancel", body={})
        assert status == 200 and c["state"] == "cancelled", c
        assert c["states"] == ["bidding", "assigned", "active", "cancelled"] and c["robot"] == "fleet0"
        wait_until(lambda: robot.abandoned == [b["id"]], 10, "the robot abandons the cancelled task")
        lt.loop.call_soon_threadsafe(robot.hold.set)
        assert robot.performed == ["a1"]

        # bad input: one line each
        bad = {"kind": "go_to", "x": 1e9, "y": 0, "robot": "nobody"}
        assert_one_line_error(*call(base, "POST", "/api/tasks", body=bad), 400, "unknown_robot")
        assert_one_line_error(*call(base, "POST", "/api/tasks/zzz/cancel", body={}), 404, "no task 'zzz'")
        assert_one_line_error(*call(base, "POST", "/api/tasks/a1/cancel", body={}), 400, "already ended")
    finally:
        lt.run(host.stop())
        lt.close()


async def _open_host(ep: str) -> AgentHost:
    return AgentHost.connect(TransportArgs(connect=[ep]))


@pytest.mark.timeout(180)
def test_the_page_submits_lists_and_cancels_tasks(procs, tmp_path, browser_page):
    """The Tasks panel in a browser (Debian's chromium driven by Playwright, as
    tests/agents/browser.py): a go_to from the form is listed until done, a bad route is refused
    in one line on the page, a patrol under way is cancelled with its button."""
    port, fabric = free_port(), f"tcp/127.0.0.1:{free_port()}"
    ctl = procs(
        rsal_cmd("control", "--port", str(port), "--listen", fabric, "--no-watch", "--scenarios", str(tmp_path))
    )
    procs(rsal_cmd("agent", "DispatcherAgent", "--id", "dispatcher", "--arg", "window=0.3", "--connect", fabric))
    base = f"http://127.0.0.1:{port}"
    wait_until(lambda: _up(base), 60, f"rsal control serving on port {port}\n{ctl.output()}", interval=0.2)
    lt = LoopThread()
    host = lt.run(_open_host(fabric))
    try:
        robot = lt.run(host.start(StandIn("fleet0", robot="r0")))
        wait_until(lambda: "dispatcher" in call(base, "GET", "/api/state")[1]["agents"], 60, "the dispatcher")
        page, errors = browser_page(1400, 1000)
        page.goto(base + "/")
        page.fill("#task-x", "2")
        page.fill("#task-y", "1")
        page.click("#task-submit")
        page.wait_for_selector("#tasks tr td.taskstate.done", timeout=30_000)
        row = page.locator("#tasks tbody tr").first
        assert row.locator("td").nth(1).inner_text() == "go_to" and row.locator("td").nth(3).inner_text() == "fleet0"
        assert row.locator("button.cancel").is_disabled()
        assert robot.performed == [row.get_attribute("data-task")]

        page.select_option("#task-kind", "patrol")
        assert page.locator("#task-x").is_hidden() and page.locator("#task-route").is_visible()
        page.fill("#task-route", "1, 0; a, b")
        page.click("#task-submit")
        page.wait_for_function("() => document.querySelector('#task-error').textContent.includes('route point')")

        lt.loop.call_soon_threadsafe(robot.hold.clear)
        page.fill("#task-route", "0, 0; 3, 0; 3, 2")
        page.click("#task-submit")
        active = page.locator("#tasks tbody tr", has=page.locator("td.taskstate.active"))
        active.wait_for(timeout=30_000)
        tid = active.get_attribute("data-task")
        active.locator("button.cancel").click()
        page.wait_for_selector(f"#tasks tr[data-task='{tid}'] td.taskstate.cancelled", timeout=15_000)
        save_screenshot(page, tmp_path, "tasks-panel.png")
        wait_until(lambda: robot.abandoned == [tid], 10, "the robot abandons the cancelled patrol")
        assert errors == []
        lt.loop.call_soon_threadsafe(robot.hold.set)
    finally:
        lt.run(host.stop())
        lt.close()


def _up(base: str) -> bool:
    try:
        return call(base, "GET", "/api/tasks")[0] == 200
    except OSError:
        return False
