"""``rsal host`` (the per-machine daemon) and ``rsal run`` placing host groups on it, as real processes.

A router on a free loopback port, one or two daemons with different names connected to it, and
``rsal run --connect`` with a scenario whose group names ``machine: robot1``. Checked: the group runs
on that daemon (and not on the other) and the robot really moves (the runner's ground truth), a
daemon killed by PID mid-run is reported in one line and its agents counted as lost (exit 1, the
agent host it launched gone with it), a missing daemon is one line naming it and the fix, the
daemon's typed refusals (malformed request, unknown application or group, malformed scenario, no
launcher token), a run stopped when its launcher's token goes, and the daemon's SIGTERM stopping its
runs. Waits are conditions with deadlines; every process is cleaned up by PID.
"""

from __future__ import annotations

import math
import os
import re
import signal
import textwrap
from pathlib import Path

import pytest

from agents.hostwire import LaunchRequest, OutLine, RunExit
from rsal.keys import host_key, host_rpc_key, host_run_key
from rsal.msgs import decode, decode_map, encode
from rsal.transport import TransportArgs, open_session
from tests.conftest import MAPS, ROOT, rsal_cmd, wait_until

WANDER = """
scenario: hostd
arguments: {{report_every: 1.0, startup_timeout: 60}}
agent_types: {{wanderer: WallfollowAgent}}
applications:
  wallfollow:
    simulator: {{world: {world}}}
    agents:
      - {{type: wanderer, robot: r0, id: wf0, machine: {machine}}}
    end: {{duration: {duration}, timeout: 300{truth}}}
"""


def wander(tmp_path: Path, machine: str = "robot1", duration: float = 6, truth: bool = True) -> Path:
    p = tmp_path / "w.yaml"
    judge = ", travel: 0.3, clearance: 0.3" if truth else ""
    p.write_text(WANDER.format(world=MAPS / "testroom.world", machine=machine, duration=duration, truth=judge))
    return p


def pid_gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.fixture
def fabric(procs, port):
    """A router and a function that starts a daemon ``name`` on it (waits for its token line)."""
    ep = f"tcp/127.0.0.1:{port}"
    procs(rsal_cmd("router", "--listen", ep))

    def daemon(name: str):
        d = procs(rsal_cmd("host", "--name", name, "--connect", ep), env={"PYTHONPATH": str(ROOT)})
        wait_until(lambda: f"up: token hosts/{name}" in d.output() or not d.alive(), 30, f"daemon {name} up")
        assert d.alive(), d.output()
        return d

    return ep, daemon


def finished(proc, timeout: float, what: str) -> str:
    wait_until(lambda: not proc.alive(), timeout, what, interval=0.1)
    return proc.output()


def test_run_places_a_group_on_the_named_daemon_and_the_robot_moves(tmp_path, procs, fabric):
    ep, daemon = fabric
    d1, d2 = daemon("robot1"), daemon("robot2")
    run = procs(rsal_cmd("run", str(wander(tmp_path)), "--connect", ep, "--speedup", "2", "--progress", "2"))
    out = finished(run, 120, "rsal run to end")
    assert run.p.returncode == 0, out
    m = re.search(r"\[run\] launched wf0 on machine robot1 \(run (\w+), pid (\d+) on robot1\): 1 agent\(s\): wf0", out)
    assert m, out
    # its lines come back with the group's prefix, and the daemon launched it, the other did not
    assert "[host wf0] wf0 running: WallfollowAgent on robot r0, token agents/wf0" in out
    assert f"launched run {m.group(1)}: hostd/wallfollow group wf0 (pid {m.group(2)})" in d1.output()
    assert "launched" not in d2.output()
    # the verdict is the simulator's ground truth: r0 really drove
    t = re.search(r"\(ground truth: r0 travelled ([\d.]+) m, nearest wall ([\d.]+) m\)", out)
    assert t and float(t.group(1)) >= 0.3, out
    # stopped at the end by a stop request, and its exit came back
    wait_until(lambda: f"run {m.group(1)} (wf0) ended: stopped (stop request)" in d1.output(), 10, "the run's end")
    assert pid_gone(int(m.group(2)))


def test_a_daemon_killed_mid_run_is_reported_and_its_agents_lost(tmp_path, procs, fabric):
    ep, daemon = fabric
    d1 = daemon("robot1")
    run = procs(rsal_cmd("run", str(wander(tmp_path, duration=120)), "--connect", ep, "--timeout", "200"))
    wait_until(lambda: "[run] all 1 agent(s) alive" in run.output() or not run.alive(), 90, "the agent up")
    assert run.alive(), run.output()
    child = int(re.search(r"pid (\d+) on robot1", run.output()).group(1))
    d1.kill()  # SIGKILL by PID: no goodbye
    out = finished(run, 60, "rsal run to notice the lost daemon")
    assert run.p.returncode == 1, out
    assert "[run] machine robot1 lost mid-run: agents wf0 of host group wf0 are lost" in out
    assert (
        f"[run] result: FAILED — agent host 'wf0' (pid {child} on robot1) was lost: host daemon 'robot1' left "
        "the fabric (its token hosts/robot1 went)" in out
    )
    assert re.search(r"\[run\] elapsed [\d.]+ s; agents started 1/1; outcomes: none; agents lost 1", out)
    wait_until(lambda: pid_gone(child), 10, "the launched agent host to die with its daemon")


def test_tolerate_lost_reports_the_lost_agents_and_runs_on(tmp_path, procs, fabric):
    ep, daemon = fabric
    d1 = daemon("robot1")
    w = wander(tmp_path, duration=8, truth=False)
    run = procs(rsal_cmd("run", str(w), "--connect", ep, "--tolerate-lost", "--speedup", "2", "--progress", "1"))
    wait_until(lambda: "[run] all 1 agent(s) alive" in run.output() or not run.alive(), 90, "the agent up")
    d1.kill()
    out = finished(run, 90, "rsal run to end its duration")
    assert run.p.returncode == 0, out
    assert "[run] machine robot1 lost mid-run: agents wf0 of host group wf0 are lost" in out
    assert "[run] result: ok — ran 8 s with every agent started and no failed outcome" in out
    assert re.search(r"agents started 1/1; outcomes: none; agents lost 1", out)


def test_a_missing_daemon_is_one_line_naming_it_and_the_fix(tmp_path, procs, fabric):
    ep, _ = fabric
    # four independent refusals, started together (each is a process start and a look at the fabric)
    run = procs(rsal_cmd("run", str(wander(tmp_path, machine="robot9")), "--connect", ep))
    (tmp_path / "own").mkdir()
    alone = procs(rsal_cmd("run", str(wander(tmp_path / "own"))))
    bad_flags = (
        (["--name", "a b"], "rsal host: --name 'a b' must be letters, digits"),
        (["--name", "x", "--host-config", str(tmp_path / "none.toml")], "none.toml: cannot read it"),
    )
    daemons = [(procs(rsal_cmd("host", *argv)), text) for argv, text in bad_flags]
    out = finished(run, 60, "rsal run to give up")
    assert run.p.returncode == 1, out
    line = (
        "rsal run: machine 'robot9' (host group wf0): no host daemon hosts/robot9 on the fabric; "
        "start 'rsal host --name robot9' there (docs/deployment.md) or remove its 'machine'"
    )
    assert line in out.splitlines(), out
    assert "Traceback" not in out
    assert "started sim" not in out  # checked before anything starts
    # without a fabric to join (a fresh port of its own), no daemon can be there: said at once, exit 2
    out = finished(alone, 30, "rsal run to refuse")
    assert alone.p.returncode == 2, out
    assert out.strip().endswith(
        "places agents on machine 'robot1', whose host daemon joins a running fabric: give --connect EP "
        "(e.g. a router's, rsal router --listen EP) or --config FILE"
    ), out
    # the daemon's own bad flags and files: one line, exit 2
    for d, text in daemons:
        out = finished(d, 30, "rsal host to refuse")
        assert d.p.returncode == 2 and text in out and len(out.strip().splitlines()) == 1, out


def _ask(session, name: str, op: str, payload: bytes) -> dict:
    key = host_rpc_key(name, op) if op in ("launch", "stop", "status") else f"{host_key(name)}/rpc/{op}"
    for reply in session.get(key, payload=payload, timeout=10):
        if reply.ok is not None:
            return decode_map(reply.ok.payload.to_bytes())
        return decode_map(reply.err.payload.to_bytes())
    raise AssertionError(f"no reply to {op}")


def test_refusals_stop_on_launcher_loss_and_sigterm(tmp_path, procs, fabric):
    ep, daemon = fabric
    d = daemon("robot1")
    s = open_session(TransportArgs(connect=[ep]))
    try:  # the daemon's token seen: its queryable is known here too
        wait_until(lambda: list(s.liveliness().get(host_key("robot1"), timeout=2)), 10, "the daemon's token")
        text = wander(tmp_path).read_text()
        req = LaunchRequest(run="run1", app="wallfollow", group="wf0", scenario=text)
        # no launcher token: refused; then malformed requests, each a typed one-line refusal
        r = _ask(s, "robot1", "launch", encode(req))
        assert r == {
            "ok": False,
            "code": "unavailable",
            "message": "the launcher's token hosts/robot1/run/run1/runner is not alive; declare it first",
        }
        token = s.liveliness().declare_token(host_run_key("robot1", "run1", "runner"))
        cases = {
            b"\x01": ("bad_request", "launch: payload must be a msgpack map, not int"),
            encode({"run": "run1"}): ("bad_request", "launch: field 'app' is missing"),
            encode({**req.to_dict(), "app": "nope"}): ("not_found", "no application 'nope'; use one of wallfollow"),
            encode({**req.to_dict(), "group": "g"}): ("not_found", "application 'wallfollow' has no host group 'g'"),
            encode({**req.to_dict(), "scenario": "scenario: [x"}): ("bad_request", "the scenario sent: "),
        }
        for payload, (code, text_part) in cases.items():
            r = _ask(s, "robot1", "launch", payload)
            assert r["ok"] is False and r["code"] == code and text_part in r["message"], r
            assert "\n" not in r["message"]
        assert _ask(s, "robot1", "reboot", b"")["code"] == "unknown_op"
        # a good launch: the agent host waits for r0's devices (no simulator); its lines stream back
        got: list = []
        sub = s.declare_subscriber(host_run_key("robot1", "run1", "*"), lambda smp: got.append(smp))
        r = _ask(s, "robot1", "launch", encode(req))
        assert r["ok"] is True and r["agents"] == ["wf0"], r
        pid = r["pid"]
        wait_until(lambda: any(str(x.key_expr).endswith("/out") for x in got), 20, "an output line")
        first = decode(OutLine, next(x for x in got if str(x.key_expr).endswith("/out")).payload.to_bytes())
        assert first.seq == 0 and first.line.startswith("[host wf0] starting WallfollowAgent wf0")
        assert _ask(s, "robot1", "launch", encode(req))["code"] == "bad_request"  # run id in use
        status = _ask(s, "robot1", "status", b"")
        assert status["runs"] == [{"run": "run1", "app": "wallfollow", "group": "wf0", "pid": pid, "state": "running"}]
        # the launcher leaves: the run is stopped, its exit put
        token.undeclare()
        wait_until(lambda: any(str(x.key_expr).endswith("/exit") for x in got), 30, "the run's exit")
        ex = decode(RunExit, next(x for x in got if str(x.key_expr).endswith("/exit")).payload.to_bytes())
        assert ex.reason.startswith("stopped (its launcher left the fabric)"), ex
        assert pid_gone(pid)
        # SIGTERM to the daemon with a run: the run stopped, the token withdrawn, exit 0
        token = s.liveliness().declare_token(host_run_key("robot1", "run2", "runner"))
        r = _ask(s, "robot1", "launch", encode(LaunchRequest(run="run2", app="wallfollow", group="wf0", scenario=text)))
        assert r["ok"] is True, r
        d.signal(signal.SIGTERM)
        wait_until(lambda: not d.alive(), 25, "the daemon to stop")
        assert d.p.returncode == 0, d.output()
        assert pid_gone(r["pid"])
        assert "run run2 (wf0) ended: stopped (host daemon stopped (SIGTERM))" in d.output()
        assert not list(s.liveliness().get(host_key("robot1"), timeout=2))
        sub.undeclare()
        token.undeclare()
    finally:
        s.close()


def test_scenario_machine_is_one_per_host_group(tmp_path):
    from agents.scenario import ScenarioError, load_scenario

    p = tmp_path / "m.yaml"
    p.write_text(
        textwrap.dedent("""
        scenario: m
        agent_types: {w: WallfollowAgent}
        applications:
          a:
            agents:
              - {type: w, robot: r0, host: g, machine: robot1}
              - {type: w, robot: r1, host: g}
            end: {duration: 1}
        """)
    )
    with pytest.raises(ScenarioError, match=r"applications\.a\.agents: host group 'g' is placed on machine 'robot1'"):
        load_scenario(p)
    p.write_text(p.read_text().replace("host: g}", "host: g, machine: robot1}"))
    assert load_scenario(p).applications["a"].machines() == {"g": "robot1"}
    p.write_text(p.read_text().replace("machine: robot1}", "machine: 'a b'}", 1))
    with pytest.raises(ScenarioError, match=r"agents\[0\]\.machine: machine 'a b' must be"):
        load_scenario(p)


def test_awareness_starts_an_agent_for_a_robot_that_appears_and_stops_it_when_it_goes(tmp_path, procs, fabric):
    from tests.truth import Truth

    ep, _ = fabric
    cfg = tmp_path / "host.toml"
    cfg.write_text('name = "robot1"\n[awareness]\nclass = "WallfollowAgent"\nrobots = ["r*"]\n')
    d = procs(rsal_cmd("host", "--host-config", str(cfg), "--connect", ep))
    wait_until(lambda: "up: token hosts/robot1" in d.output() or not d.alive(), 30, "the daemon up")
    assert d.alive(), d.output()
    sim = procs(rsal_cmd("sim", str(MAPS / "testroom.world"), "--connect", ep, "--truth"))
    up = wait_until(
        lambda: re.search(r"aware: robot r0 appeared; started WallfollowAgent for it \(pid (\d+)\)", d.output()),
        30,
        "the awareness agent for r0",
    )
    agent = int(up.group(1))
    assert "robot sim" not in d.output()  # the simulation's node has no base: no agent for it
    s = open_session(TransportArgs(connect=[ep]))
    truth = Truth(s, ["r0"])
    try:
        wait_until(truth.ready, 20, "r0's true pose")
        start = truth.pose("r0")
        wait_until(
            lambda: math.hypot(truth.pose("r0").x - start.x, truth.pose("r0").y - start.y) > 0.3,
            30,
            "r0 to drive (ground truth)",
        )
    finally:
        truth.close()
        s.close()
    sim.stop()
    wait_until(lambda: "aware: robot r0's devices went; stopping its WallfollowAgent" in d.output(), 20, "the stop")
    wait_until(lambda: pid_gone(agent), 20, "the awareness agent to end")


def test_the_wire_and_the_configuration_refuse_in_one_line(tmp_path):
    from agents.hostd import HostConfigError, load_host_config
    from rsal.msgs import MessageError

    good = LaunchRequest(run="r1", app="a", group="g", scenario="x", overrides=("k=1",))
    assert LaunchRequest.from_bytes(encode(good)) == good
    for bad, text in (
        ({**good.to_dict(), "run": "a/b"}, "field 'run': run 'a/b' must be letters"),
        ({**good.to_dict(), "suffix": ".json"}, "field 'suffix' = '.json' must be one of .yaml, .yml, .toml"),
        ({**good.to_dict(), "overrides": [1]}, "field 'overrides' must be a list of strings"),
        ({**good.to_dict(), "scenario": "x" * 300_000}, "over the 262144 a daemon takes"),
    ):
        with pytest.raises(MessageError, match=re.escape(text)):
            LaunchRequest.from_bytes(encode(bad))
    cfg = tmp_path / "h.toml"
    for body, text in (
        ('nmae = "x"\n', "h.toml: nmae: unknown key; did you mean 'name'?"),
        ("[awareness]\nrobots = ['r*']\n", "awareness.class: name the agent class to start"),
        ('[agents]\nconfig = "nope.json5"\n', "agents.config: no file"),
        ("name = [\n", "not valid TOML"),
    ):
        cfg.write_text(body)
        with pytest.raises(HostConfigError, match=re.escape(text)):
            load_host_config(str(cfg))
    cfg.write_text('name = "r0"\n[awareness]\nclass = "WallfollowAgent"\nrobots = "r*"\nargs = {period = 0.2}\n')
    c = load_host_config(str(cfg))
    assert (c.name, c.aware_class, c.aware_robots, c.aware_args) == ("r0", "WallfollowAgent", ("r*",), {"period": 0.2})
