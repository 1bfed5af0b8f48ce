"""``rsal control`` in a real headless browser (agents/control/, thesis 3.4.2 / 5.2.3).

Debian's ``chromium``, driven by the ``playwright`` package (no browser download: the system's
``/usr/bin/chromium``, installed by ``./dev.sh test``'s set-up), opens the control page, starts the
Hunt and Prey application ``virtual`` by clicking, waits until the agents list shows hunter1,
hunter2 and prey0 and the Rerun web view of the same fabric is shown beside the controls, places
hunter r1 on the map (initial pose) and sends it a goal by dragging on the map, clicks Stop and
waits until the agents are gone. Screenshots are saved under ``tmp_path`` and, when
``RSAL_ARTIFACTS`` is set, in that folder. The test skips, with the reason, where chromium cannot
is missing or playwright is not installed.
"""

from __future__ import annotations

import math
import signal
import time
import urllib.request

import pytest

from rsal.client import Fabric
from rsal.transport import TransportArgs
from tests.agents.browser import save_screenshot
from tests.conftest import free_port, rsal_cmd, wait_until

AGENTS = ("hunter1", "hunter2", "prey0")
ROBOTS = ("r0", "r1", "r2")  # maps/hunt.world


# where a robot is drawn on the map canvas, in page coordinates, and its pose (the page's own
# transform); a point under the sticky header (a hunter near the map's top edge) is scrolled to the
# middle of the window first, so that a press there lands on the map
ROBOT_ON_CANVAS = """name => {
  const r = state.robots.find(x => x.name === name);
  const [px, py] = toPixel(r.pose[0], r.pose[1]);
  const c = document.querySelector('#map');
  const at = () => {
    const b = c.getBoundingClientRect();
    const k = b.width / c.width;
    return [b.left + px * k, b.top + py * k];
  };
  let [x, y] = at();
  if (document.elementFromPoint(x, y) !== c) {
    window.scrollBy(0, y - window.innerHeight / 2);
    [x, y] = at();
  }
  return {x, y, wx: r.pose[0], wy: r.pose[1], yaw: r.pose[2], onMap: document.elementFromPoint(x, y) === c};
}"""


def _drag(page, where: dict, length: float = 40.0) -> None:
    """Press at the robot's position and release ``length`` pixels away along its heading."""
    assert where["onMap"], f"the robot's drawn position {where} is not on the visible map"
    page.mouse.move(where["x"], where["y"])
    page.mouse.down()
    x1 = where["x"] + length * math.cos(where["yaw"])
    y1 = where["y"] - length * math.sin(where["yaw"])
    page.mouse.move(x1, y1, steps=2)
    page.mouse.up()


@pytest.mark.timeout(300)  # the test itself takes 30-150 s
def test_page_starts_hunt_and_prey_shows_agents_and_rerun_view_and_stops_it(procs, tmp_path, browser_page):
    port = free_port()
    fabric = f"tcp/127.0.0.1:{free_port()}"
    ctl = procs(rsal_cmd("control", "--port", str(port), "--listen", fabric))
    base = f"http://127.0.0.1:{port}/"

    def up():
        try:
            with urllib.request.urlopen(base + "api/state", timeout=5) as r:
                return r.status == 200
        except OSError:
            return False

    wait_until(up, 60, f"rsal control serving on {base}\n{ctl.output()}", interval=0.2)

    page, errors = browser_page(1600, 1200)
    page.goto(base)
    page.wait_for_selector('#scenario option[value="hunt_prey"]', state="attached", timeout=30_000)
    page.select_option("#scenario", "hunt_prey")
    page.select_option("#app", "virtual")
    assert page.locator('#arguments input[data-arg="report_every"]').input_value() == "1.0"
    # an argument added before the start: hunters that must come within 5 cm never catch the
    # prey, so the run goes on until Stop is clicked (it would end with the first catch)
    page.fill("#new-arg-name", "capture_distance")
    page.fill("#new-arg-value", "0.05")
    page.click("#add-arg")
    assert page.locator('#arguments input[data-arg="capture_distance"]').input_value() == "0.05"
    with page.expect_response(lambda r: r.url.endswith("/api/runs"), timeout=60_000) as resp:
        page.click("#start")
    t0 = time.monotonic()
    phases: dict[str, float] = {}

    def mark(what: str) -> None:  # seconds since the click on Start, printed at the end
        phases[what] = time.monotonic() - t0

    assert resp.value.status == 200, resp.value.text()
    assert resp.value.json()["set"] == {"capture_distance": "0.05"}
    assert "--set capture_distance=0.05" in resp.value.json()["command"]

    all_there = "ids => ids.every(id => document.querySelector(`#agents li[data-agent='${id}']`))"
    page.wait_for_function(all_there, arg=list(AGENTS), timeout=180_000, polling=250)
    mark("agents alive")
    assert page.locator('.run[data-run="1"] .state').inner_text() == "running"
    # the map of the simulator's floorplan with the robots on it
    page.wait_for_function(
        "() => document.querySelector('#map-info').textContent.startsWith('sim:map:0')", timeout=60_000
    )
    page.wait_for_function("() => document.querySelectorAll('#robot option').length === 3", timeout=60_000)
    # the Rerun web view of the same fabric beside the controls (software rendering: give it time)
    page.wait_for_function(
        "() => (document.querySelector('#viewer').getAttribute('src') || '').startsWith('http://localhost:')",
        timeout=90_000,
    )
    assert "rerun" in page.locator("#viewer").get_attribute("src")
    page.frame_locator("#viewer").locator("canvas").first.wait_for(state="visible", timeout=90_000)
    mark("rerun view shown")
    # place hunter r1 on the map (its localizer's initial pose) and send it a goal: press at
    # its drawn position, drag towards its heading
    page.select_option("#robot", "r1")
    page.check("#mode-pose")
    page.locator("#map").scroll_into_view_if_needed()
    mark("pose mode")
    where = page.evaluate(ROBOT_ON_CANVAS, "r1")
    with page.expect_response(lambda r: "/api/robots/r1/pose" in r.url, timeout=30_000) as resp:
        _drag(page, where)
    assert resp.value.status == 200, resp.value.text()
    assert "initial pose set" in resp.value.json()["note"]
    mark("pose set")
    page.check("#mode-goal")
    where = page.evaluate(ROBOT_ON_CANVAS, "r1")
    with page.expect_response(lambda r: "/api/robots/r1/goal" in r.url, timeout=30_000) as resp:
        _drag(page, where)
    assert resp.value.status == 200, resp.value.text()
    goal = resp.value.json()["goal"]
    assert abs(goal["x"] - where["wx"]) < 0.2 and abs(goal["y"] - where["wy"]) < 0.2, (goal, where)
    assert abs((goal["yaw"] - math.degrees(where["yaw"]) + 180) % 360 - 180) < 5, (goal, where)
    page.check('input[name="mode"][value="none"]')
    mark("goal sent")
    shot = save_screenshot(page, tmp_path, "control-hunt-running.png")
    mark("screenshot")
    assert shot.stat().st_size > 10_000

    # Stop all: the emergency stop of every base, whatever the scenario's agents command (ground
    # truth); the header keeps it on screen with the page scrolled down to the map
    assert page.evaluate("window.scrollY") > 0, "the page should be scrolled to the map here"
    assert page.locator("#estop-all").bounding_box()["y"] >= 0, "Stop all scrolled off the screen"
    with page.expect_response(lambda r: r.url.endswith("/api/estop"), timeout=30_000) as resp:
        page.click("#estop-all")
    assert resp.value.status == 200, resp.value.text()
    mark("stop all")
    with Fabric.connect(TransportArgs(connect=[fabric])) as fab:
        fab.node("sim:simulation:0").wait_for("sim:simulation:0", 1, timeout=10)
        sim = fab.device("sim:simulation:0")

        def truth() -> dict:
            return {n: sim.get_pose(n) for n in ROBOTS}

        time.sleep(0.5)  # the sampling interval of the ground truth (a base stops before it answers)
        a = truth()
        time.sleep(1.0)
        b = truth()
        moved = {n: math.hypot(b[n].x - a[n].x, b[n].y - a[n].y) for n in ROBOTS}
        assert all(d < 0.01 for d in moved.values()), f"robots moved after Stop all: {moved}"
        with page.expect_response(lambda r: r.url.endswith("/api/estop"), timeout=30_000) as resp:
            page.click("#estop-release-all")
        assert resp.value.status == 200, resp.value.text()
        wait_until(
            lambda: any(math.hypot(p.x - b[n].x, p.y - b[n].y) > 0.05 for n, p in truth().items()),
            30,
            "a robot to move again after Release all (its agent still commands it)",
        )
        mark("released")

    page.click('.run[data-run="1"] button.stop')
    none_left = "ids => ids.every(id => !document.querySelector(`#agents li[data-agent='${id}']`))"
    page.wait_for_function(none_left, arg=list(AGENTS), timeout=90_000, polling=250)
    mark("agents gone")
    page.wait_for_function(
        "() => document.querySelector('.run[data-run=\"1\"] .state').textContent === 'stopped'",
        timeout=90_000,
    )
    save_screenshot(page, tmp_path, "control-hunt-stopped.png")
    assert not errors, errors

    ctl.signal(signal.SIGTERM)
    assert ctl.p.wait(60) == 0, ctl.output()
    mark("control stopped")
    print("phases: " + ", ".join(f"{k} {v:.1f} s" for k, v in phases.items()))
