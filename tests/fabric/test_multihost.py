"""The fabric across hosts: network namespaces made by the test (tests/netns.py) stand in for a
simulator host, two robot hosts and an agent host on one LAN.

- sim host: ``rsal sim maps/hunt.world`` — the robots' bases and lasers, the simulation (at the
  suite's speed-up; the agents follow its clock with ``RSAL_SIM_TIME``, the leases stay wall time);
- robot host 1 and 2: ``rsal serve`` with the hunters r1's / r2's navigation stack
  (deploy/r0-nav.toml for that robot: mapfile, vfh, amcl, wavefront), requiring their base and
  laser over the network;
- agent host: Hunt and Prey (``rsal run deploy/scenarios/hunt_prey.yaml --app fleet``: the prey
  on r0, hunters on r1 and r2) and a watcher of the whole fabric (tests/fabric/netwatch.py).

While the hunt runs, robot host 2's cable is pulled: r2's devices are reported lost within the
configured Zenoh lease (plus the keep-alive slack), r2's base, on the simulator host, stops by its
command timeout once its local planner's commands no longer arrive (simulator ground truth), while
r1's devices stay and r1 keeps driving;
when the cable is back, r2's devices return without any process being restarted and r2 drives
again under its hunter (ground truth); a hunt that ended meanwhile must have ended with the prey
caught.

The same hunt runs again in the **secured profile** (docs/security.md): ``rsal secure`` makes a
fleet in a temporary folder with one identity per host (the simulator host for its nodes, robot
hosts 1 and 2 for r1 and r2, the agent host for the scenario's agents and services, the runner and
the watcher as operators), every process connects to ``rsal router`` with its own identity over
TLS; the prey and both hunters drive through the secured router (simulator ground truth), and a
hunt that ends meanwhile must end with a catch the true poses confirm.

An agent host placed on a robot host (``rsal host`` there, the scenario's ``machine: robot1``): the
runner on the agent host launches r0's wall-follower on robot host 1's daemon, r0 drives (ground
truth), and cutting robot host 1's link is reported by the runner as that machine lost with its
agent (exit 1), within the lease and its slack of the cut, three cuts in a row.

Skipped, with the reason, where namespaces cannot be made (not root, no iproute2).
"""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import sys
import time

import pytest

from agents.scenario import load_scenario
from tests.conftest import MAPS, ROOT, SPEEDUP, Proc, rsal_cmd, wait_until
from tests.netns import Lan, unavailable

why = unavailable()
pytestmark = pytest.mark.skipif(why is not None, reason=f"no network namespaces here: {why}")

LEASE_MS = 3000
TUNING = ["--cfg", f"transport/link/tx/lease:{LEASE_MS}", "--cfg", "transport/link/tx/keep_alive:4"]
WORLD = MAPS / "hunt.world"
POSES = {"r1": (-14.0, 1.75, 0.0), "r2": (10.0, 1.75, 180.0)}  # maps/hunt.world
SCENARIO = ROOT / "deploy" / "scenarios" / "hunt_prey.yaml"
HUNT_SERVICES = ("send_position", "outcome")


def nav_config(tmp_path, robot: str) -> str:
    """deploy/r0-nav.toml for ``robot``: its node, start pose and an absolute map path."""
    text = (ROOT / "deploy" / "r0-nav.toml").read_text()
    text = text.replace('node = "r0"', f'node = "{robot}"').replace("r0:", f"{robot}:")
    text = text.replace('"../maps/floor.png"', json.dumps(str(MAPS / "floor.png")))
    x, y, a = POSES[robot]
    text = re.sub(r"init_pose = \[[^\]]*\]", f"init_pose = [{x}, {y}, {a}]", text)
    path = tmp_path / f"{robot}-nav.toml"
    path.write_text(text)
    return str(path)


def moved(a: list[float] | None, b: list[float] | None) -> float:
    """Planar distance between two poses (0 while either is unknown)."""
    if a is None or b is None:
        return 0.0
    return math.hypot(a[0] - b[0], a[1] - b[1])


class Watch:
    """The JSON lines of tests/fabric/netwatch.py, read as they come."""

    def __init__(self, proc: Proc):
        self.proc = proc

    def events(self) -> list[dict]:
        out = []
        for line in self.proc.output().splitlines():
            if line.startswith("{"):
                try:
                    out.append(json.loads(line))
                except json.JSONDecodeError:
                    pass  # a line being written
        return out

    def alive(self) -> set[str]:
        devs: set[str] = set()
        for e in self.events():
            if "join" in e:
                devs.add(e["join"])
            elif "leave" in e:
                devs.discard(e["leave"])
        return devs

    def truths(self, robot: str) -> list[list[float]]:
        """The robot's true poses from the simulation, oldest first (one every half second)."""
        return [e["truth"][robot] for e in self.events() if "truth" in e and robot in e["truth"]]

    def pose(self, addr: str) -> list[float] | None:
        for e in reversed(self.events()):
            if "poses" in e and addr in e["poses"]:
                return e["poses"][addr]
        return None


@pytest.fixture
def lan():
    net = Lan()
    yield net
    net.close()


@pytest.mark.timeout(600)
def test_a_robot_host_cut_off_is_lost_the_others_continue_and_it_rejoins(lan, tmp_path):
    sim_ip = lan.host("sim")
    r1_ip = lan.host("robot1")
    r2_ip = lan.host("robot2")
    lan.host("agents")
    sim_ep = f"tcp/{sim_ip}:7447"
    procs: list[Proc] = []

    def start(host: str, argv: list[str], env: dict | None = None) -> Proc:
        p = Proc(lan.cmd(host, argv), env=env)
        procs.append(p)
        return p

    try:
        start("sim", rsal_cmd("sim", str(WORLD), "--no-map", "--listen", sim_ep, "--speedup", SPEEDUP, *TUNING))
        for host, robot, ip in (("robot1", "r1", r1_ip), ("robot2", "r2", r2_ip)):
            start(
                host,
                rsal_cmd(
                    "serve", nav_config(tmp_path, robot), "--connect", sim_ep, "--listen", f"tcp/{ip}:7447", *TUNING
                ),
            )
        watch = Watch(
            start(
                "agents",
                [
                    sys.executable,
                    str(ROOT / "tests" / "fabric" / "netwatch.py"),
                    "--connect",
                    sim_ep,
                    "--truth",
                    "r1,r2",
                ]
                + TUNING,
            )
        )
        stack = {f"{r}:{d}" for r in ("r1", "r2") for d in ("planner:0", "localize:0", "position2d:1", "position2d:2")}
        wait_until(lambda: stack <= watch.alive(), 120, "both robot hosts' navigation stacks across the LAN")

        # The hunt, from the agent host; r1 moves under its hunter.
        hunt = start(
            "agents",
            rsal_cmd("run", str(SCENARIO), "--app", "fleet", "--connect", sim_ep, "--progress", "2", *TUNING),
            env={"RSAL_SIM_TIME": "sim"},  # the agents follow the simulation's clock (rsal.clock)
        )
        wait_until(lambda: watch.pose("r1:position2d:0") is not None, 30, "r1's odometry at the agent host")
        start_pose = watch.pose("r1:position2d:0")
        wait_until(lambda: moved(watch.pose("r1:position2d:0"), start_pose) > 0.2, 120, "the hunter r1 to start moving")

        before = watch.truths("r2")
        lan.cut("robot2")
        t_cut = time.monotonic()
        # r2's base lost its commander (the local planner on the cut host): its command timeout (0.5 s)
        # stops it. Ground truth from 1.5 s after the cut on (the timeout plus the polls' spacing).
        wait_until(lambda: len(watch.truths("r2")) >= len(before) + 8, 30, "r2's true pose after the cut")
        after = watch.truths("r2")[len(before) + 3 :]
        drift = max(moved(p, after[0]) for p in after)
        was_moving = len(before) >= 2 and moved(before[-1], before[-2]) > 0.02
        assert drift < 0.02, (
            f"r2 kept moving {drift:.2f} m after its commands stopped (moving at the cut: {was_moving})"
        )
        r2_stack = {a for a in stack if a.startswith("r2:")}
        wait_until(
            lambda: not (r2_stack & watch.alive()),
            LEASE_MS / 1000 * 2 + 5 - (time.monotonic() - t_cut),  # counted from the cut
            "robot host 2's devices to be reported lost after its link went down",
        )
        lost_after = time.monotonic() - t_cut
        assert {a for a in stack if a.startswith("r1:")} <= watch.alive(), "robot host 1's devices were lost too"
        p1 = watch.pose("r1:position2d:0")
        if hunt.alive():  # the hunt may already be won; r1 drives only while it hunts
            wait_until(
                lambda: moved(watch.pose("r1:position2d:0"), p1) > 0.2 or not hunt.alive(),
                30,
                "r1 to keep driving while robot host 2 is cut off",
            )

        lan.restore("robot2")
        wait_until(lambda: r2_stack <= watch.alive(), 60, "robot host 2's devices to come back without a restart")
        assert all(p.alive() for p in procs if p is not hunt), "a process died: " + "\n".join(
            p.output()[-500:] for p in procs if not p.alive()
        )
        # r2 drives again under its hunter once its host is back (ground truth), unless the hunt is
        # already over; the whole hunt across hosts is judged by the secured test below
        back = watch.truths("r2")
        wait_until(
            lambda: (
                not hunt.alive()
                or (len(watch.truths("r2")) > len(back) and moved(watch.truths("r2")[-1], back[-1]) > 0.2)
            ),
            60,
            "r2 to drive again after its host rejoined",
        )
        if not hunt.alive():
            assert hunt.p.returncode == 0, hunt.output()[-3000:]
            assert re.search(r"prey r0 caught by r[12] after", hunt.output()), hunt.output()[-2000:]
        print(
            f"r2 lost {lost_after:.1f} s after the cut (lease {LEASE_MS / 1000:g} s); r2 moving at the cut: "
            f"{was_moving}, moved {drift:.3f} m from 1.5 s after it"
        )
    finally:
        for p in procs:
            p.close()


def _secure(fleet_dir, *argv):
    r = subprocess.run(rsal_cmd("secure", *argv, "--dir", str(fleet_dir)), capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed to make certificates")
@pytest.mark.timeout(600)
def test_hunt_and_prey_across_hosts_in_the_secured_profile(lan, tmp_path):
    router_ip = lan.host("router")
    for host in ("sim", "robot1", "robot2", "agents"):
        lan.host(host)
    app = load_scenario(SCENARIO).applications["fleet"]
    fleet = tmp_path / "fleet"
    _secure(fleet, "init", "--host", router_ip, "--port", "7448")
    _secure(fleet, "add-robot", "simhost", "--nodes", "sim,r0,r1,r2")
    _secure(fleet, "add-robot", "robot1", "--nodes", "r1")
    _secure(fleet, "add-robot", "robot2", "--nodes", "r2")
    _secure(
        fleet,
        "add-agents",
        "hunthost",
        "--agents",
        ",".join(a.id for a in app.agents),
        "--services",
        ",".join(HUNT_SERVICES),
        "--robots",
        ",".join(sorted({a.robot for a in app.agents})),
    )
    _secure(fleet, "add-operator", "runner")
    _secure(fleet, "add-operator", "watcher")
    member = {
        n: str(fleet / "members" / f"{n}.json5")
        for n in ("simhost", "robot1", "robot2", "hunthost", "runner", "watcher")
    }
    procs = []

    def start(host, argv, env=None):
        p = Proc(lan.cmd(host, argv), env=env)
        procs.append(p)
        return p

    try:
        router = start("router", rsal_cmd("router", "--config", str(fleet / "router.json5")))
        wait_until(lambda: "routing on" in router.output(), 30, "the fleet's router to listen")
        start("sim", rsal_cmd("sim", str(WORLD), "--no-map", "--speedup", SPEEDUP, "--config", member["simhost"]))
        for host, robot in (("robot1", "r1"), ("robot2", "r2")):
            start(host, rsal_cmd("serve", nav_config(tmp_path, robot), "--config", member[host]))
        watch = Watch(
            start(
                "agents",
                [
                    sys.executable,
                    str(ROOT / "tests" / "fabric" / "netwatch.py"),
                    "--truth",
                    "r0,r1,r2",
                    "--config",
                    member["watcher"],
                ],
            )
        )
        stack = {f"{r}:{d}" for r in ("r1", "r2") for d in ("planner:0", "localize:0", "position2d:1", "position2d:2")}
        wait_until(lambda: stack <= watch.alive(), 120, "both robot hosts' navigation stacks through the router")
        hunt = start(
            "agents",
            rsal_cmd(
                "run",
                str(SCENARIO),
                "--app",
                "fleet",
                "--config",
                member["runner"],
                "--agents-config",
                member["hunthost"],
                "--progress",
                "2",
            ),
            env={"RSAL_SIM_TIME": "sim"},
        )
        # Every robot is driven across hosts under its host's identity: the prey and both hunters
        # move (the simulation's ground truth), and no outcome of a stranger is ignored.
        wait_until(lambda: watch.truths("r1") and watch.truths("r2") and watch.truths("r0"), 60, "true poses")
        first = {r: watch.truths(r)[0] for r in ("r0", "r1", "r2")}
        wait_until(
            lambda: not hunt.alive() or all(moved(watch.truths(r)[-1], first[r]) > 0.5 for r in first),
            120,
            "the prey and both hunters to drive through the secured router",
        )
        out = hunt.output()
        assert "ignored an outcome" not in out, out[-2000:]
        if not hunt.alive():  # a hunt that is over must have been won, judged on the true poses
            assert hunt.p.returncode == 0, out[-3000:]
            caught = re.search(r"prey r0 caught by (r[12]) after", out)
            assert caught, out[-2000:]
            truth = [e["truth"] for e in watch.events() if "truth" in e and {"r0", caught[1]} <= set(e["truth"])]
            assert truth and moved(truth[-1]["r0"], truth[-1][caught[1]]) < 2.5
    finally:
        for p in procs:
            p.close()


CUTS = 3  # the agent host launched on robot host 1 and its link cut, this many times
REPORT_BOUND = LEASE_MS / 1000 + 3.0  # s from the cut: the lease, its keep-alive slack and the runner's loop


def daemon_seen(lan, host: str, sim_ep: str, name: str) -> bool:
    """Whether a fresh session on ``host`` finds the daemon ``name``'s token within 5 s."""
    code = (
        "import sys\n"
        "from agents.remote import daemon_alive\n"
        "from rsal.transport import TransportArgs, open_session\n"
        "s = open_session(TransportArgs(connect=[sys.argv[1]]))\n"
        "sys.exit(0 if daemon_alive(s, sys.argv[2], 5.0) else 1)\n"
    )
    argv = lan.cmd(host, [sys.executable, "-c", code, sim_ep, name])
    return subprocess.run(argv, cwd=ROOT, capture_output=True, timeout=60).returncode == 0


@pytest.mark.timeout(420)
def test_an_agent_host_launched_on_a_robot_hosts_daemon_drives_and_a_cut_loses_its_agents(lan, tmp_path):
    """``rsal host`` on robot host 1: the runner on the agent host launches r0's wall-follower there
    (scenario ``machine: robot1``); r0 drives (simulator ground truth); cutting robot host 1's link
    is reported by the runner in one line, its agent counted as lost, and the run fails. Three
    times (the link restored and the agent launched again in between): each report comes within
    the lease and its slack of the cut. (With Zenoh's own receive runtime settings, a presumably
    lingering close of another link to the cut host delayed it by 10 s in 8 of 12 cuts.)"""
    sim_ep = f"tcp/{lan.host('sim')}:7447"
    lan.host("robot1")
    lan.host("agents")
    scenario = tmp_path / "s.yaml"
    scenario.write_text(
        "scenario: placed\n"
        "arguments: {report_every: 1.0, startup_timeout: 60}\n"
        "agent_types: {wanderer: WallfollowAgent}\n"
        "applications:\n"
        "  a:\n"
        "    agents: [{type: wanderer, robot: r0, id: wf0, machine: robot1}]\n"
        "    end: {duration: 200, timeout: 260}\n"
    )
    procs: list[Proc] = []

    def start(host: str, argv: list[str]) -> Proc:
        p = Proc(lan.cmd(host, argv))
        procs.append(p)
        return p

    try:
        start("sim", rsal_cmd("sim", str(MAPS / "testroom.world"), "--listen", sim_ep, *TUNING))
        daemon = start("robot1", rsal_cmd("host", "--name", "robot1", "--connect", sim_ep, *TUNING))
        watch = Watch(
            start(
                "agents", [sys.executable, str(ROOT / "tests/fabric/netwatch.py"), "--connect", sim_ep, "--truth", "r0"]
            )
        )
        wait_until(lambda: "up: token hosts/robot1" in daemon.output(), 60, "robot host 1's daemon")
        wait_until(lambda: watch.truths("r0"), 60, "r0's true pose at the agent host")

        def launch_and_cut() -> float:
            """Launch wf0 on robot1, cut robot1's link once wf0 drives: seconds from the cut until
            the runner reports robot host 1 lost (its daemon's token gone)."""
            run = start("agents", rsal_cmd("run", str(scenario), "--connect", sim_ep, "--progress", "2", *TUNING))
            wait_until(lambda: "[run] all 1 agent(s) alive" in run.output() or not run.alive(), 90, "wf0 up on robot1")
            assert run.alive(), run.output()
            assert "[run] launched wf0 on machine robot1" in run.output()
            first = watch.truths("r0")[-1]
            wait_until(lambda: moved(watch.truths("r0")[-1], first) > 0.3, 60, "r0 to drive under wf0 (ground truth)")
            lan.cut("robot1")
            t_cut = time.monotonic()
            wait_until(lambda: "lost mid-run" in run.output(), 30, "the runner to report robot host 1 lost")
            lost = time.monotonic() - t_cut
            wait_until(lambda: not run.alive(), 30, "the runner to end")
            out = run.output()
            assert run.p.returncode == 1, out[-3000:]
            assert "[run] machine robot1 lost mid-run: agents wf0 of host group wf0 are lost" in out, out[-3000:]
            assert "was lost: host daemon 'robot1' left the fabric" in out
            return lost

        reports: list[float] = []
        for i in range(CUTS):
            if i:
                lan.restore("robot1")
                wait_until(lambda: daemon_seen(lan, "agents", sim_ep, "robot1"), 60, "robot1's daemon back")
            reports.append(launch_and_cut())
        text = ", ".join(f"{t:.1f}" for t in reports)
        print(f"robot host 1 reported lost {text} s after the cuts (lease {LEASE_MS} ms)")
        assert max(reports) <= REPORT_BOUND, f"a report later than {REPORT_BOUND:g} s after its cut: {text} s"
    finally:
        for p in procs:
            p.close()
