"""``rsal control`` (agents/control/, thesis 3.4.2 / 5.2.3): the JSON API without a browser.

Unit tests cover the map image and the input checks of an in-process :class:`Control` without a
fabric; the integration test starts a real ``rsal control`` process, starts the ``wander``
scenario's application through the API, sees its agent and devices, commands the robot, stops the
run and sees everything go, and checks that SIGTERM stops the control with exit 0.
"""

from __future__ import annotations

import json
import os
import re
import signal
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from agents.control import ApiError, Control, map_png
from tests.conftest import ROOT, free_port, rsal_cmd, wait_until

SCENARIOS = ROOT / "deploy" / "scenarios"


def call(base: str, method: str, path: str, body=None, raw: bytes | None = None) -> tuple[int, dict | bytes]:
    data = raw if raw is not None else (json.dumps(body).encode() if body is not None else None)
    req = urllib.request.Request(base + path, data=data, method=method)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    return _open(req)


def _open(req: urllib.request.Request) -> tuple[int, dict | bytes]:
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            payload = r.read()
            status = r.status
            ctype = r.headers.get("Content-Type", "")
    except urllib.error.HTTPError as e:
        payload, status, ctype = e.read(), e.code, e.headers.get("Content-Type", "")
    return status, (json.loads(payload) if ctype.startswith("application/json") else payload)


def assert_one_line_error(status: int, body, expect_status: int = 400, contains: str = "") -> None:
    assert status == expect_status, body
    assert isinstance(body, dict) and set(body) == {"error"}, body
    msg = body["error"]
    assert msg and "\n" not in msg and "Traceback" not in msg, msg
    assert contains in msg, msg


# ---------------------------------------------------------------------------- unit
def test_map_png_is_top_row_first_with_player_values():
    from io import BytesIO

    from PIL import Image

    cells = np.zeros((3, 4), dtype=np.int8)  # rows from the bottom
    cells[0, :] = 1  # bottom row occupied
    cells[2, :] = -1  # top row free
    img = np.asarray(Image.open(BytesIO(map_png(cells))))
    assert img.shape == (3, 4)
    assert (img[0] == 255).all() and (img[1] == 200).all() and (img[2] == 0).all()


def test_start_run_rejects_bad_inputs_with_one_line(tmp_path: Path):
    c = Control(SCENARIOS, "tcp/127.0.0.1:1", watch=False)
    bad = [
        ({"scenario": "nope", "app": "x"}, "is not in"),
        ({"scenario": "wander", "app": "nope"}, "has no application 'nope'"),
        ({"scenario": "wander", "app": "wallfollow", "set": {"bad-name": "1"}}, "must be a name"),
        ({"scenario": "wander", "app": "wallfollow", "set": {"report_every": 2}}, "YAML text"),
        ({"scenario": "wander", "app": "wallfollow", "set": {"report_every": "1\n2"}}, "one line"),
        ({"scenario": "wander", "app": "wallfollow", "set": ["x"]}, "must be a map"),
        ({"scenario": "wander", "app": "wallfollow", "extra": 1}, "unknown field 'extra'"),
        ({"app": "wallfollow"}, "scenario must be a non-empty string"),
    ]
    for body, text in bad:
        with pytest.raises(ApiError) as e:
            c.start_run(body)
        assert text in str(e.value) and "\n" not in str(e.value)
    assert c.runs == {}


def test_scenarios_lists_apps_arguments_and_broken_files(tmp_path: Path):
    (tmp_path / "broken.yaml").write_text("scenario: broken\nagent_types: {}\napplications: {}\n")
    text = (SCENARIOS / "wander.yaml").read_text()
    (tmp_path / "wander.yaml").write_text(text.replace("../../maps", str(ROOT / "maps")))
    c = Control(tmp_path, "tcp/127.0.0.1:1", watch=False)
    got = {s["name"]: s for s in c.scenarios()}
    assert "error" in got["broken"] and "agent_types" in got["broken"]["error"]
    w = got["wander"]
    assert w["arguments"] == {"report_every": 1.0, "startup_timeout": 60}
    # shown as the YAML text --set reads back to the same value
    assert w["arguments_yaml"] == {"report_every": "1.0", "startup_timeout": "60"}
    apps = {a["name"]: a for a in w["applications"]}
    assert apps["wallfollow"]["agents"] == ["wf0"] and apps["wallfollow"]["simulator"] == "testroom.world"


def _ended(pid: int) -> bool:
    """The process ``pid`` has exited: gone, or a zombie not yet reaped (an orphan's exit status
    waits for init, which in a container may collect it only a second or two later)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat[stat.rindex(")") + 2] == "Z"


# ---------------------------------------------------------------------------- integration
@pytest.mark.timeout(420)
def test_control_starts_and_stops_an_application_through_the_api(procs, tmp_path):
    # wander.yaml with a 10-minute duration: the run goes on until the test stops it, however slow
    # the machine is
    text = (SCENARIOS / "wander.yaml").read_text().replace("../../maps", str(ROOT / "maps"))
    text = text.replace("duration: 20", "duration: 600").replace("timeout: 120", "timeout: 700")
    (tmp_path / "wander.yaml").write_text(text)
    port = free_port()
    fabric = f"tcp/127.0.0.1:{free_port()}"
    ctl = procs(
        rsal_cmd("control", "--port", str(port), "--listen", fabric, "--no-watch", "--scenarios", str(tmp_path))
    )
    base = f"http://127.0.0.1:{port}"

    def up():
        try:
            return call(base, "GET", "/api/state")[0] == 200
        except OSError:
            return False

    wait_until(up, 60, f"rsal control serving on port {port}\n{ctl.output()}", interval=0.2)
    status, page = call(base, "GET", "/")
    assert status == 200 and b"RSAL control" in page
    status, st = call(base, "GET", "/api/state")
    assert st["fabric"] == fabric and st["agents"] == [] and st["runs"] == []

    # bad inputs: HTTP 400 (404 for unknown things) and one line
    assert_one_line_error(*call(base, "POST", "/api/runs", raw=b"{not json"), contains="not valid JSON")
    assert_one_line_error(*call(base, "POST", "/api/runs", body=[1]), contains="JSON object")
    req = urllib.request.Request(base + "/api/runs", data=b'{"scenario": "wander", "app": "wallfollow"}', method="POST")
    req.add_header("Content-Type", "text/plain")  # what a cross-site form could send without asking
    assert_one_line_error(*_open(req), 415, "application/json")
    req = urllib.request.Request(base + "/api/state", headers={"Host": f"evil.example:{port}"})
    assert_one_line_error(*_open(req), 403, "refused")
    assert_one_line_error(*call(base, "POST", "/api/runs", body={"scenario": "wander", "app": "nope"}))
    assert_one_line_error(*call(base, "POST", "/api/runs/99/stop", body={}), 404, "no run 99")
    assert_one_line_error(*call(base, "POST", "/api/robots/r0/stop", body={}), 404, "no position2d:0")
    assert_one_line_error(*call(base, "POST", "/api/robots/r:0/stop", body={}), 400, "node name")
    assert_one_line_error(*call(base, "GET", "/api/map"), 404, "no map device")
    assert_one_line_error(*call(base, "GET", "/api/nothing"), 404, "no such API")
    assert_one_line_error(*call(base, "GET", "/static/..%2Fcontrol.py"), 404)

    status, run = call(base, "POST", "/api/runs", body={"scenario": "wander", "app": "wallfollow", "set": {}})
    assert status == 200, run
    rid = run["id"]
    assert run["state"] == "running" and run["pid"] > 0 and run["agents"] == ["wf0"]
    assert "--connect " + fabric in run["command"]
    # one run at a time on the fabric
    second = call(base, "POST", "/api/runs", body={"scenario": "wander", "app": "escape"})
    assert_one_line_error(*second, 400, "stop it")

    def state():
        return call(base, "GET", "/api/state")[1]

    def run_info():
        return next(r for r in state()["runs"] if r["id"] == rid)

    st = wait_until(
        lambda: (s := state()) and "wf0" in s["agents"] and s,
        180,
        f"agent wf0 in /api/state\n{json.dumps(run_info()['lines'][-10:])}",
        interval=0.3,
    )
    assert "r0:position2d:0" in st["devices"] and "sim:map:0" in st["maps"]
    robots = {r["name"]: r for r in st["robots"]}
    assert set(robots) == {"r0"} and robots["r0"]["localize"] is False

    # the map of the simulator's floorplan
    status, m = call(base, "GET", "/api/map")
    assert status == 200 and m["device"] == "sim:map:0" and m["resolution"] > 0 and len(m["origin"]) == 2
    status, png = call(base, "GET", m["png"])
    assert status == 200 and png[:8] == b"\x89PNG\r\n\x1a\n"
    # the robot's pose (simulation truth) and commands
    wait_until(lambda: next(r for r in state()["robots"] if r["name"] == "r0")["pose"], 30, "a pose for r0")
    status, r = call(base, "POST", "/api/robots/r0/stop", body={})
    assert status == 200 and "zero velocity" in r["note"]
    assert_one_line_error(*call(base, "POST", "/api/robots/r0/pose", body={"x": 0, "y": 0}), 400, "no localize:0")
    assert_one_line_error(*call(base, "POST", "/api/robots/r0/goal", body={"x": "a", "y": 0}), 400, "finite number")
    assert_one_line_error(*call(base, "POST", "/api/robots/r0/fly", body={}), 404, "unknown robot action")

    # wall-following started from the page: a child agent that joins the fabric, stopped again
    status, r = call(base, "POST", "/api/robots/r0/wallfollow", body={"on": True})
    assert status == 200 and "wall-following started" in r["note"], r
    wait_until(lambda: "wallfollow-r0" in state()["agents"], 90, "agent wallfollow-r0 in /api/state")
    assert_one_line_error(*call(base, "POST", "/api/robots/r0/wallfollow", body={"on": True}), 400, "already")
    status, r = call(base, "POST", "/api/robots/r0/wallfollow", body={"on": False})
    assert status == 200, r
    wait_until(lambda: "wallfollow-r0" not in state()["agents"], 60, "agent wallfollow-r0 to leave")
    wf = wait_until(
        lambda: (
            (x := next(r for r in state()["robots"] if r["name"] == "r0")["wallfollow"])["state"] == "stopped" and x
        ),
        60,
        "the wall-following agent to exit",
    )
    assert wf["exit_code"] == 0, wf["lines"]

    status, stopped = call(base, "POST", f"/api/runs/{rid}/stop", body={})
    assert status == 200 and stopped["state"] in ("stopping", "stopped")
    wait_until(lambda: "wf0" not in state()["agents"], 60, "agent wf0 to leave")
    info = wait_until(lambda: (r := run_info())["state"] == "stopped" and r, 90, "the run to exit")
    assert info["exit_code"] == 130 and "interrupted" in info["result"]
    wait_until(lambda: not state()["devices"], 60, "the simulator's devices to leave")
    assert_one_line_error(*call(base, "POST", f"/api/runs/{rid}/stop", body={}), 400, "not running")

    # a second run, still going when the control is told to stop: SIGTERM stops it and its
    # processes (simulator, agent host) by PID, then the control exits 0
    status, run2 = call(base, "POST", "/api/runs", body={"scenario": "wander", "app": "wallfollow"})
    assert status == 200 and run2["id"] == rid + 1, run2
    wait_until(lambda: "wf0" in state()["agents"], 180, "agent wf0 of the second run")
    lines = next(r for r in state()["runs"] if r["id"] == run2["id"])["lines"]
    pids = [run2["pid"]] + [int(m) for m in re.findall(r"\[run\] started \S+ \(pid (\d+)\)", "\n".join(lines))]
    assert len(pids) == 3, lines  # rsal run, the simulator, the agent host
    ctl.signal(signal.SIGTERM)
    assert ctl.p.wait(90) == 0, ctl.output()
    assert "[control] stopped" in ctl.output()
    # rsal run is the control's child (reaped before it exits); the simulator and the agent host are
    # the run's, which reaps them when it stops them itself -- if the run had to be killed, they get
    # SIGTERM as their parent dies (die_with_parent) and end a moment later, on their own
    wait_until(
        lambda: all(_ended(pid) for pid in pids),
        30,
        f"pids {[p for p in pids if not _ended(p)]} to exit\n{ctl.output()[-2000:]}",
        interval=0.1,
    )


def test_robot_actions_check_their_inputs_before_touching_the_fabric():
    c = Control(SCENARIOS, "tcp/127.0.0.1:1", watch=False)
    c.devices = {"r0:position2d:0", "r0:laser:0"}
    bad = [
        ("r9", "stop", {}, "no position2d:0"),
        ("r/0", "stop", {}, "node name"),
        ("r0", "pose", {"x": "a", "y": 0}, "x must be a finite number"),
        ("r0", "pose", {"x": 1.0}, "y is missing"),
        ("r0", "pose", {"x": 1.0, "y": 2.0, "z": 0}, "unknown field 'z'"),
        ("r0", "pose", {"x": 1.0, "y": 2.0}, "no localize:0"),
        ("r0", "goal", {"x": 1.0, "y": float("nan")}, "finite number"),
        ("r0", "goal", {"x": 1.0, "y": 2.0}, "no planner:0"),
        ("r0", "wallfollow", {"on": "yes"}, "true or false"),
        ("r0", "wallfollow", {"on": False}, "is not wall-following"),
        ("r0", "fly", {}, "unknown robot action 'fly'"),
    ]
    for robot, action, body, text in bad:
        with pytest.raises(ApiError) as e:
            c.robot_action(robot, action, body)
        assert text in str(e.value) and "\n" not in str(e.value), (action, body, str(e.value))


def test_argument_values_are_shown_as_yaml_that_set_reads_back():
    from agents.control.api import _yaml_text
    from agents.scenario import parse_set

    for v in (1.0, 60, "r0", True, [1, 2], {"a": 1}, "yes", 1e20, ""):
        assert parse_set([f"k={_yaml_text(v)}"])["k"] == v


def test_stop_all_latches_every_robot_against_a_running_scenario(procs, tmp_path, fabric_factory):
    """The page's "Stop all" (POST /api/estop) overrides a running scenario's agent: judged on the
    simulator's true pose while the agent keeps commanding; the release lets it drive again."""
    import time

    text = (SCENARIOS / "wander.yaml").read_text().replace("../../maps", str(ROOT / "maps"))
    text = text.replace("duration: 20", "duration: 600").replace("timeout: 120", "timeout: 700")
    (tmp_path / "wander.yaml").write_text(text)
    port, fport = free_port(), free_port()
    procs(
        rsal_cmd(
            "control",
            "--port",
            str(port),
            "--listen",
            f"tcp/127.0.0.1:{fport}",
            "--no-watch",
            "--scenarios",
            str(tmp_path),
        )
    )
    base = f"http://127.0.0.1:{port}"

    def up():
        try:
            return call(base, "GET", "/api/state")[0] == 200
        except OSError:
            return False

    wait_until(up, 60, "rsal control serving", interval=0.2)
    status, run = call(base, "POST", "/api/runs", body={"scenario": "wander", "app": "wallfollow", "set": {}})
    assert status == 200, run
    fab = fabric_factory(fport)
    wait_until(lambda: "wf0" in call(base, "GET", "/api/state")[1]["agents"], 180, "agent wf0", interval=0.3)
    sim = fab.device("sim:simulation:0")

    def moving() -> bool:
        a = sim.rpc("get_pose", name="r0")["pose"]
        time.sleep(0.25)
        b = sim.rpc("get_pose", name="r0")["pose"]
        return max(abs(x - y) for x, y in zip(a, b, strict=True)) > 1e-4

    wait_until(moving, 60, "r0 to be driven by the scenario's agent (ground truth)")
    assert_one_line_error(*call(base, "POST", "/api/estop", body={"release": "yes"}), 400, "true or false")
    status, r = call(base, "POST", "/api/estop", body={})
    assert status == 200 and r["ok"] and r["robots"] == ["r0"] and r["note"].startswith("latched: r0"), r
    assert not moving() and not moving()  # the agent keeps commanding; the robot stays stopped
    assert "wf0" in call(base, "GET", "/api/state")[1]["agents"]
    status, r = call(base, "POST", "/api/estop", body={"release": True})
    assert status == 200 and r["note"].startswith("released: r0"), r
    wait_until(moving, 10, "r0 to drive again after the release")
    status, r = call(base, "POST", "/api/robots/r0/estop", body={})
    assert status == 200 and r["robots"] == ["r0"], r
    assert not moving()
    call(base, "POST", "/api/robots/r0/estop", body={"release": True})
    call(base, "POST", f"/api/runs/{run['id']}/stop", body={})
