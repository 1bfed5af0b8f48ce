"""``rsal run`` as a real process (thesis fig. 3.11, scenarios of 4.2), and ``rsal agent --arg``.

Each test starts ``rsal run`` through the ``procs`` fixture (its own session, killed by PID at the
end) on a scenario file: the demo ``deploy/scenarios/wander.yaml`` (simulator + WallfollowAgent, end
by duration) or one the test writes into ``tmp_path`` with the :class:`tests.agents.scenario_agents.
Reporter` agent, which publishes outcomes. Checked: success and its summary, the end as soon as the
count of distinct subjects is reached, a final verdict, a failing agent host (one line, exit 1),
the timeout (exit 1), SIGINT (exit 130, every child PID gone), bad files (exit 2) and ``--connect`` to
a running fabric. The agent-host process is also run on its own (tolerated failures, an unknown
class or application in one line). Waits are conditions with deadlines, never fixed sleeps.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

from agents.services import decode_message
from rsal.transport import TransportArgs, open_session
from tests.conftest import MAPS, ROOT, free_port, rsal_cmd, wait_until

REPORTER = "tests.agents.scenario_agents:Reporter"


def scenario(tmp_path: Path, apps: str, name: str = "s.yaml") -> Path:
    p = tmp_path / name
    head = f"""
    scenario: test
    description: outcomes on a schedule
    arguments: {{report_every: 1.0, startup_timeout: 60}}
    agent_types:
      rep: {REPORTER}
      wf: WallfollowAgent
    applications:
    """
    p.write_text(textwrap.dedent(head) + textwrap.indent(textwrap.dedent(apps), "  "))
    return p


def finished(proc, timeout: float, what: str) -> str:
    wait_until(lambda: not proc.alive(), timeout, what, interval=0.1)
    return proc.output()


def run_lines(out: str, prefix: str) -> list[str]:
    return [line for line in out.splitlines() if line.startswith(prefix)]


def pid_gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_wander_demo_runs_for_its_duration_and_succeeds(procs):
    # at four times real time: the agent, the duration and the progress follow the simulation's clock
    p = procs(
        rsal_cmd("run", "deploy/scenarios/wander.yaml", "--app", "wallfollow", "--progress", "2", "--speedup", "4")
    )
    out = finished(p, 150, "rsal run to end the wander scenario")
    assert p.p.returncode == 0, out
    assert re.search(r"\[run\] started sim \(pid \d+\): rsal sim maps/testroom.world --listen tcp/127.0.0.1:\d+", out)
    assert "[run] started wf0 (pid" in out and "[host wf0] wf0 running: WallfollowAgent on robot r0" in out
    assert "[run] agent wf0 is up" in out
    assert re.search(r"\[run\] t=[\d.]+ s agents 1/1 alive, [\d.]+/20 s", out)
    assert "[run] result: ok — ran 20 s with every agent started and no failed outcome" in out
    # judged on ground truth (the file's end: travel 2 m, clearance 0.4 m): r0 really drove, off the walls
    m = re.search(r"\(ground truth: r0 travelled ([\d.]+) m, nearest wall ([\d.]+) m\)", out)
    assert m, out
    assert float(m.group(1)) >= 2.0 and float(m.group(2)) >= 0.4, m.group(0)
    assert re.search(r"\[run\] elapsed [\d.]+ s; agents started 1/1; outcomes: none", out)
    assert "[host wf0] on the simulation's clock (RSAL_SIM_TIME=sim)" in out
    wall = float(re.search(r"times on the simulation's clock \(([\d.]+) s of wall time\)", out).group(1))
    assert wall < 20.0, f"20 simulated seconds at speed-up 4 took {wall} s of wall time"
    assert "[host wf0] wf0 stopped (SIGTERM)" in out  # hosts stopped before the simulator
    sim_end = out.find("[sim] summary")  # the simulator's last line (its summary, when it had time)
    assert out.index("[host wf0] wf0 stopped") < (sim_end if sim_end >= 0 else out.rindex("[sim]"))
    assert "Traceback" not in out


def test_a_robot_that_does_not_move_fails_a_travel_end_on_ground_truth(procs, tmp_path):
    # the Reporter agent holds robot r0 but never drives it: 20 quiet seconds are no wander
    f = scenario(
        tmp_path,
        f"""
        still:
          simulator: {{world: {MAPS / "testroom.world"}}}
          agents:
            - {{type: rep, robot: r0, id: still0, args: {{event: noise, subjects: [x], every: 5.0}}}}
          end: {{duration: 4, travel: 0.5, clearance: 0.4, timeout: 90}}
        """,
    )
    p = procs(rsal_cmd("run", str(f), "--app", "still", "--speedup", "4"))
    out = finished(p, 120, "rsal run to end the still scenario")
    assert p.p.returncode == 1, out
    assert "[run] result: FAILED — ground truth: r0 travelled 0.00 m (< travel 0.5 m)" in out, out
    assert "rsal run: ground truth: r0 travelled 0.00 m (< travel 0.5 m)" in out


def test_run_ends_as_soon_as_the_count_of_distinct_subjects_is_reached(procs, tmp_path):
    path = scenario(
        tmp_path,
        """
        quick:
          description: two reporters, three subjects
          agents:
            - {type: rep, id: rep_a, host: reporters, args: {subjects: [a, b], every: 0.3}}
            - {type: rep, id: rep_c, host: reporters, args: {subjects: [c], every: 0.3, delay: 600}}
          end: {event: caught, count: 2, timeout: 240}
        other:
          agents: [{type: rep}]
          end: {duration: 5}
        """,
    )
    p = procs(rsal_cmd("run", str(path), "--app", "quick"))
    out = finished(p, 120, "rsal run to end when two subjects were caught")
    assert p.p.returncode == 0, out
    assert "[run] started reporters (pid" in out and "agent host with 2 agent(s): rep_a, rep_c" in out
    assert "[run] outcome from rep_a: caught a reported by rep_a" in out
    result = run_lines(out, "[run] result:")
    assert len(result) == 1 and result[0].startswith("[run] result: ok — caught ")
    assert "caught a reported by rep_a" in result[0] and "caught b reported by rep_a" in result[0]
    assert "caught c" not in out  # rep_c never got to speak: the run ended at the count
    elapsed = float(re.search(r"\[run\] elapsed ([\d.]+) s; agents started 2/2; outcomes: caught 2", out).group(1))
    assert elapsed < 100


def test_a_final_outcome_ends_the_run_with_its_verdict(procs, tmp_path):
    path = scenario(
        tmp_path,
        """
        judged:
          agents:
            - {type: rep, id: judge, args: {event: verdict, subjects: [run], ok: false, final: true}}
          end: {event: caught, count: 5}
        """,
    )
    p = procs(rsal_cmd("run", str(path)))
    out = finished(p, 120, "rsal run to end on the verdict")
    assert p.p.returncode == 1, out
    assert "[run] result: FAILED — verdict run reported by judge" in out
    errors = run_lines(out, "rsal run:")
    assert len(errors) == 1 and "verdict run reported by judge" in errors[0]


def test_a_failing_agent_host_is_one_line_and_exit_1(procs, tmp_path):
    path = scenario(
        tmp_path,
        """
        broken:
          agents:
            - {type: rep, id: rep, args: {subjects: [a], every: 1.0}}
            - {type: wf, robot: r9, id: wf9, args: {startup_timeout: 2}}
          end: {event: caught, count: 2, timeout: 240}
        """,
    )
    p = procs(rsal_cmd("run", str(path), "--app", "broken"))
    out = finished(p, 120, "rsal run to fail on the missing robot")
    assert p.p.returncode == 1, out
    errors = run_lines(out, "rsal run:")
    assert len(errors) == 1, out
    assert re.match(
        r"rsal run: agent host 'wf9' \(pid \d+\) exited with code 1: host wf9: agent wf9: robot 'r9'", errors[0]
    )
    assert "within 2 s" in errors[0]
    assert "[host rep] rep stopped (SIGTERM)" in out  # the healthy host was stopped cleanly
    assert "[run] result: FAILED — agent host 'wf9'" in out
    assert "Traceback" not in out


def test_timeout_is_a_failure_and_a_repeated_subject_counts_once(procs, tmp_path):
    path = scenario(
        tmp_path,
        """
        never:
          agents:
            - {type: rep, id: rep, args: {subjects: [same], every: 0.2}}
          end: {event: caught, count: 2, timeout: 240}
        """,
    )
    p = procs(rsal_cmd("run", str(path), "--timeout", "6"))
    out = finished(p, 120, "rsal run to time out")
    assert p.p.returncode == 1, out
    assert "[run] outcome from rep: caught same reported by rep" in out
    errors = run_lines(out, "rsal run:")
    assert errors == ["rsal run: timeout after 6 s (caught 1/2, 1/1 agents up)"], out
    assert "[run] result: FAILED — timeout after 6 s" in out


def test_sigint_stops_every_child_and_exits_130(procs, tmp_path):
    path = scenario(
        tmp_path,
        f"""
        sim:
          simulator: {{world: {MAPS / "testroom.world"}}}
          agents:
            - {{type: wf, robot: r0, id: wf0}}
            - {{type: rep, id: rep, args: {{subjects: [x], every: 1.0}}}}
          end: {{event: caught, count: 9, timeout: 240}}
        """,
    )
    p = procs(rsal_cmd("run", str(path)))
    wait_until(
        lambda: "[run] agent wf0 is up" in p.output() and "[run] agent rep is up" in p.output() or not p.alive(),
        120,
        "both agents up",
        interval=0.1,
    )
    assert p.alive(), p.output()
    pids = {name: int(pid) for name, pid in re.findall(r"\[run\] started (\S+) \(pid (\d+)\)", p.output())}
    assert set(pids) == {"sim", "wf0", "rep"}
    assert all(not pid_gone(pid) for pid in pids.values())
    p.signal(signal.SIGINT)
    out = finished(p, 60, "rsal run to stop after SIGINT")
    assert p.p.returncode == 130, out
    assert "[run] SIGINT: stopping" in out and "[run] result: interrupted (SIGINT)" in out
    assert "[host wf0] wf0 stopped (SIGTERM)" in out and "[host rep] rep stopped (SIGTERM)" in out
    assert all(pid_gone(pid) for pid in pids.values()), pids


def test_bad_files_and_arguments_exit_2_with_one_line(procs, tmp_path):
    # four independent refusals, started together (each is a process start-up)
    bad = scenario(tmp_path, "x:\n  agents: [{type: rep, robto: r0}]\n  end: {duration: 5}\n", "bad.yaml")
    good = scenario(tmp_path, "one:\n  description: first\n  agents: [{type: rep}]\n  end: {duration: 5}\n")
    two = scenario(
        tmp_path,
        "a:\n  agents: [{type: rep}]\n  end: {duration: 5}\nb:\n  agents: [{type: rep}]\n  end: {duration: 5}\n",
        "two.yaml",
    )
    p_bad = procs(rsal_cmd("run", str(bad)))
    p_app = procs(rsal_cmd("run", str(good), "--app", "two"))
    p_two = procs(rsal_cmd("run", str(two)))
    p_set = procs(rsal_cmd("run", str(good), "--set", "nonsense"))
    out = finished(p_bad, 60, "rsal run to reject the file").strip()
    assert p_bad.p.returncode == 2 and out.splitlines() == [out]
    assert out == f"rsal run: {bad}: applications.x.agents[0].robto: unknown key; did you mean 'robot'?"
    out = finished(p_app, 60, "rsal run to reject the application")
    assert p_app.p.returncode == 2
    assert "  one  first" in out and f"rsal run: {good}: no application 'two'; use one of one" in out
    out = finished(p_two, 60, "rsal run to ask for an application")
    assert p_two.p.returncode == 2 and f"rsal run: {two}: choose an application with --app (a, b)" in out
    out = finished(p_set, 60, "rsal run to reject --set").strip()
    assert p_set.p.returncode == 2 and out.startswith("rsal run: --set 'nonsense': must be KEY=VALUE")


def test_rsal_agent_passes_arg_values_to_any_registered_class(procs):
    ep = f"tcp/127.0.0.1:{free_port()}"
    got = []
    lock = threading.Lock()

    def on_sample(sample) -> None:
        msg = decode_message("outcome", str(sample.key_expr).rsplit("/", 1)[-1], sample.payload.to_bytes())
        with lock:
            got.append(msg.body)

    cmd = ["agent", REPORTER, "--id", "rep", "--arg", "event=delivered", "--arg", "subjects=[b7]", "--arg", "every=0.2"]
    agent = procs(rsal_cmd(*cmd, "--listen", ep), cwd=ROOT)
    session = open_session(TransportArgs(connect=[ep]))
    try:
        sub = session.declare_subscriber("svc/outcome/*", on_sample)
        wait_until(lambda: got, 60, "an outcome from the agent")
        assert got[0].event == "delivered" and got[0].subject == "b7"
        agent.signal(signal.SIGTERM)
        out = finished(agent, 30, "the agent to stop")
        assert agent.p.returncode == 0, out
        assert "[agent] rep stopped (SIGTERM)" in out
        sub.undeclare()
    finally:
        session.close()
    bad = procs(rsal_cmd("agent", REPORTER, "--arg", "subject=[b7]", "--listen", f"tcp/127.0.0.1:{free_port()}"))
    out = finished(bad, 30, "the command to reject the argument").strip()
    assert bad.p.returncode == 1 and out.splitlines() == [out]
    assert out.startswith("rsal agent: agent reporter (Reporter):") and "'subject'" in out


def test_agent_host_process_tolerates_failures_when_told_so(procs, tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    path = scenario(
        tmp_path,
        """
        mixed:
          agents:
            - {type: rep, id: rep, host: mixed, args: {every: 0.2}}
            - {type: wf, id: wf9, robot: r9, host: mixed}
          end: {event: caught}
        """,
    )
    argv = [sys.executable, "-m", "agents.hostproc", str(path), "--app", "mixed", "--host", "mixed"]
    argv += ["--set", "startup_timeout=1.0", "--set", "laser=false", "--tolerate-failures", "--report-every", "1"]
    host = procs([*argv, "--listen", ep])
    wait_until(lambda: "[host mixed] rep running" in host.output() or not host.alive(), 60, "rep running")
    out = host.output()
    assert host.alive(), out
    assert "host mixed: agent wf9: robot 'r9': no position2d device appeared within 1 s" in out
    wait_until(lambda: "[host mixed] rep t=" in host.output(), 30, "a progress line of rep")
    host.signal(signal.SIGTERM)
    out = finished(host, 30, "the host to stop")
    assert host.p.returncode == 0, out
    assert "[host mixed] rep stopped (SIGTERM): sent" in out and "Traceback" not in out


def test_agent_host_process_rejects_an_unknown_class_or_host_in_one_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(
        "scenario: bad\nagent_types: {x: Nope}\napplications: {one: {agents: [{type: x, id: a}], end: {event: e}}}\n"
    )
    for extra, start in (
        ([], "host a: unknown agent class 'Nope'; classes: "),
        (["--app", "two"], f"host a: {path}: no application 'two'; use one of one"),
    ):
        argv = [sys.executable, "-m", "agents.hostproc", str(path), "--app", "one", "--host", "a", *extra]
        p = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert p.returncode == 1 and p.stdout == ""
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(start), p.stderr


def test_connect_joins_a_running_fabric(procs, tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    seen = []
    session = open_session(TransportArgs(listen=[ep]))  # the running fabric: this test's session
    try:
        sub = session.declare_subscriber("svc/outcome/*", lambda s: seen.append(str(s.key_expr)))
        path = scenario(
            tmp_path,
            """
            joined:
              agents: [{type: rep, id: rep, args: {subjects: [z], every: 0.2}}]
              end: {event: caught, count: 1, timeout: 240}
            """,
        )
        p = procs(rsal_cmd("run", str(path), "--connect", ep))
        out = finished(p, 120, "rsal run on the running fabric to end")
        assert p.p.returncode == 0, out
        assert f"fabric {ep}" in out and "[run] result: ok — caught z reported by rep" in out
        assert "svc/outcome/rep" in seen  # the agent host joined this fabric
        sub.undeclare()
    finally:
        session.close()


def test_a_forged_outcome_from_a_stranger_changes_nothing(procs, tmp_path):
    """The ghost forgery replayed with a stock Zenoh client: a final, successful ``caught`` from a
    peer that is no agent of the application does not end the run; the run ends by its own timeout,
    and the stranger is reported once."""
    import json

    import zenoh

    from agents.services import Outcome, encode_message

    ep = f"tcp/127.0.0.1:{free_port()}"
    path = scenario(
        tmp_path,
        """
        never:
          agents:
            - {type: rep, id: rep, args: {subjects: [same], every: 0.2}}
          end: {event: caught, count: 2, timeout: 240}
        """,
    )
    p = procs(rsal_cmd("run", str(path), "--listen", ep, "--timeout", "8"))
    wait_until(lambda: "[run] agent rep is up" in p.output(), 60, "the runner's agent to be up")
    c = zenoh.Config()
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/endpoints", json.dumps([ep]))
    c.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    with zenoh.open(c) as intruder:
        for i in range(3):
            body = Outcome("caught", f"ghost{i}", f"prey ghost{i} caught", ok=True, final=(i == 0))
            intruder.put("svc/outcome/intruder", encode_message("intruder", body, f"c{i}", 1.0))
        out = finished(p, 120, "rsal run to end by its timeout")
    assert p.p.returncode == 1, out
    ignored = [line for line in out.splitlines() if "ignored an outcome from intruder" in line]
    assert len(ignored) == 1, out
    assert run_lines(out, "rsal run:") == ["rsal run: timeout after 8 s (caught 1/2, 1/1 agents up)"], out
    assert "ghost" not in out.split("[run] result:")[1]


def test_nav_servers_run_the_stacks_beside_the_simulator_and_are_stopped(procs, tmp_path):
    # simulator.nav_servers: 1 -> rsal sim .. --nav-servers 1 and one rsal sim .. --nav-part 0/1 server
    # (threads: 1 -> the simulator's --threads 1);
    # the run ends (ok) once r0's planner, served by that server, is on the fabric: the reporter waits
    # for its token
    path = scenario(
        tmp_path,
        f"""
        nav:
          simulator: {{world: {MAPS / "testroom.world"}, nav: vfh, nav_servers: 1, threads: 1}}
          agents:
            - {{type: rep, id: rep, args: {{event: ready, subjects: [r0], after: "r0:planner:0"}}}}
          end: {{event: ready, count: 1, timeout: 120}}
        """,
    )
    p = procs(rsal_cmd("run", str(path)))
    wait_until(lambda: "[run] agent rep is up" in p.output() or not p.alive(), 120, "the agent up", interval=0.1)
    pids = {name: int(pid) for name, pid in re.findall(r"\[run\] started (\S+) \(pid (\d+)\)", p.output())}
    assert set(pids) == {"sim", "nav0", "rep"}, p.output()
    assert re.search(r"rsal sim \S*testroom.world --listen \S+ --nav vfh --nav-servers 1 --threads 1", p.output())
    # the stack's server joins the fabric, requires r0's devices and the map, and serves r0's stack
    up = "wavefront r0: providing r0:planner:0"
    wait_until(lambda: up in p.output() or not p.alive(), 60, "the nav server's planner up", interval=0.1)
    out = finished(p, 120, "rsal run to end")
    assert p.p.returncode == 0, out
    assert "part 0/1: navigation stacks of 1 robot(s) (r0)" in out
    for dev in ("amcl r0: providing r0:localize:0, r0:position2d:2", "vfh r0: providing r0:position2d:1", up):
        assert re.search(r"\[nav0\] .*" + re.escape(dev), out), dev
    assert all(pid_gone(pid) for pid in pids.values()), pids
    assert "Traceback" not in out
