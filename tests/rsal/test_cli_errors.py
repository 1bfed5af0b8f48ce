"""No traceback reaches a user: every ``rsal`` command, run against a fabric that does not answer
(nothing listening, a device that is announced but silent, a port in use, a bad endpoint), exits 1
with exactly one line on stderr that names the failure; ``-v`` keeps the traceback.

The formatter and the safety net (:mod:`rsal.errnet`) are tested in-process; the commands run as
real processes on loopback ports of their own, with short timeouts, and are cleaned up by PID.
"""

from __future__ import annotations

import logging
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import zenoh

from rsal.errnet import OneLineFormatter, describe, install_thread_hook, run_guarded
from rsal.msgs import ErrorCode, RpcError
from tests.conftest import ROOT, free_port, rsal_cmd, wait_until

SILENT = Path(__file__).with_name("silent_device.py")


# ---------------------------------------------------------------------------- helpers
def run(*args: str, timeout: float = 30.0, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run ``rsal ARGS`` to its end (killed by PID if it outlives ``timeout``)."""
    import os

    e = dict(os.environ, PYTHONUNBUFFERED="1")
    e.pop("RSAL_DEBUG", None)
    e.update(env or {})
    return subprocess.run(
        rsal_cmd(*args), cwd=ROOT, env=e, capture_output=True, text=True, timeout=timeout, start_new_session=True
    )


def one_line(r: subprocess.CompletedProcess, prog: str, *expected: str, code: int = 1) -> str:
    """Assert the exit code, no traceback anywhere and exactly one line on stderr, from ``prog``,
    containing each of ``expected``; return that line."""
    assert "Traceback" not in r.stdout + r.stderr, r.stdout + r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, f"stderr is not one line:\n{r.stderr}"
    assert r.returncode == code, (r.returncode, r.stderr)
    line = lines[0]
    assert line.startswith(f"{prog}: "), line
    for text in expected:
        assert text in line, f"{text!r} not in {line!r}"
    assert ".rs:" not in line, line  # no Rust source locations
    return line


def nothing_at() -> str:
    """A loopback endpoint with nothing listening."""
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def busy_port():
    """A loopback port that a plain socket holds (listening) during the test."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    yield s.getsockname()[1]
    s.close()


@pytest.fixture
def silent(procs):
    """Start a peer that announces the given devices and never answers them; returns its endpoint."""

    def start(*addrs: str) -> str:
        ep = nothing_at()
        p = procs([sys.executable, str(SILENT), "--listen", ep, *addrs])
        wait_until(lambda: "ready" in p.output() or not p.alive(), 15, "the silent device peer")
        assert p.alive(), p.output()
        return ep

    return start


# ---------------------------------------------------------------------------- the net, in-process
def _raise(e: BaseException):
    def f():
        raise e

    return f


def test_rpc_timeout_is_one_line_with_the_key_and_what_to_do(capsys):
    e = RpcError(ErrorCode.TIMEOUT, "no answer from the device within 5 s: Timeout", "rsal/sim/simulation/0/rpc/models")
    assert run_guarded("rsal demo", _raise(e), debug=False) == 1
    out = capsys.readouterr()
    assert out.out == ""
    assert out.err == (
        "rsal demo: rsal/sim/simulation/0/rpc/models did not answer within 5 s; is its device server still "
        "starting, busy or gone? retry, or check the server's output and 'rsal ls'\n"
    )


def test_zenoh_errors_lose_their_rust_locations():
    with pytest.raises(zenoh.ZError) as bad:
        zenoh.Config().insert_json5("connect/endpoints", '["nonsense"]')
    line = describe(bad.value)
    assert line.startswith("bad endpoint (") and "tcp/127.0.0.1:7447" in line, line
    assert ".rs:" not in line and "\n" not in line


def test_port_in_use_and_other_os_errors(busy_port):
    with socket.socket() as s, pytest.raises(OSError) as e:
        s.bind(("127.0.0.1", busy_port))
    assert "port is in use" in describe(e.value)
    assert (
        describe(FileNotFoundError(2, "No such file or directory", "w.world")) == "w.world: No such file or directory"
    )


def test_ctrl_c_exits_130(capsys):
    assert run_guarded("rsal ls", _raise(KeyboardInterrupt()), debug=True) == 130
    assert capsys.readouterr().err == "rsal ls: interrupted\n"


def test_a_bug_is_one_line_that_says_how_to_get_the_traceback(capsys):
    assert run_guarded("rsal ls", lambda: 1 / 0, debug=False) == 1
    err = capsys.readouterr().err
    assert err == (
        "rsal ls: unexpected ZeroDivisionError: division by zero (a bug: run with -v (or RSAL_DEBUG=1) for the "
        "traceback, and report it)\n"
    )
    assert run_guarded("rsal ls", lambda: 1 / 0, debug=True) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback") and err.splitlines()[-1].startswith("rsal ls: unexpected ZeroDivisionError")


def test_a_user_error_is_its_message(capsys):
    assert (
        run_guarded("rsal sim", _raise(ValueError("w.world:3: unknown model 'pionner'; did you mean 'pioneer'?"))) == 1
    )
    assert capsys.readouterr().err == "rsal sim: w.world:3: unknown model 'pionner'; did you mean 'pioneer'?\n"


def test_logged_exceptions_stay_on_one_line_unless_debug():
    def render(debug: bool) -> str:
        rec = None
        try:
            raise RpcError(ErrorCode.INTERNAL, "driver failed", "rsal/r0/laser/0/rpc/describe")
        except RpcError:
            rec = logging.getLogger("t").makeRecord(
                "t", logging.ERROR, __file__, 1, "poll of %s", ("r0",), sys.exc_info()
            )
        return OneLineFormatter("%(levelname)s %(name)s: %(message)s", debug=debug).format(rec)

    line = render(False)
    assert "\n" not in line and "poll of r0: RpcError: rsal/r0/laser/0/rpc/describe: internal: driver failed" in line
    assert "Traceback" in render(True)


def test_a_dying_thread_prints_one_line(monkeypatch, capsys):
    monkeypatch.setattr(threading, "excepthook", threading.excepthook)
    install_thread_hook("rsal watch")
    t = threading.Thread(target=_raise(TimeoutError("r0:laser:0: no data within 1 s")), name="poller")
    t.start()
    t.join()
    assert capsys.readouterr().err == "rsal watch: thread poller: r0:laser:0: no data within 1 s\n"


# ---------------------------------------------------------------------------- every command, for real
def test_ls_with_nothing_listening():
    one_line(run("ls", "--connect", nothing_at(), "--wait", "0.5"), "rsal ls", "no devices match")


def test_ls_with_a_bad_endpoint_and_the_traceback_with_v():
    one_line(run("ls", "--connect", "nonsense"), "rsal ls", "bad --connect endpoint 'nonsense'", "tcp/127.0.0.1:7447")
    r = run("ls", "--connect", "nonsense", "-v")
    assert r.returncode == 1 and "Traceback" in r.stderr
    assert r.stderr.splitlines()[-1].startswith("rsal ls: bad --connect endpoint 'nonsense'")


def test_ls_with_a_silent_device_lists_it_and_says_so(silent):
    r = run("ls", "--connect", silent("r0:position2d:0"), "--timeout", "0.5", "--wait", "0.5")
    one_line(r, "rsal ls", "1 device(s) did not answer", code=0)
    assert "r0    position2d  0      ?" in r.stdout


def test_goto_with_nothing_listening():
    one_line(
        run("goto", "r0", "1", "1", "--connect", nothing_at(), "--wait", "1"), "rsal goto", "no planner r0:planner:0"
    )


def test_goto_with_a_silent_planner(silent):
    r = run("goto", "r0", "1", "1", "--connect", silent("r0:planner:0"), "--wait", "1")
    one_line(r, "rsal goto", "rsal/r0/planner/0/rpc/set_goal did not answer within 1 s", "retry")


def test_agent_with_nothing_listening():
    r = run("agent", "WallfollowAgent", "--robot", "r0", "--connect", nothing_at(), "--startup-timeout", "1")
    one_line(r, "rsal agent", "robot 'r0': no position2d device appeared within 1 s")


def test_agent_with_a_silent_robot(silent):
    ep = silent("r0:position2d:0", "r0:laser:0", "r0:ranger:0")
    r = run("agent", "WallfollowAgent", "--robot", "r0", "--connect", ep, "--startup-timeout", "1")
    one_line(r, "rsal agent", "robot 'r0'", "within 1 s")


def _scenario(tmp_path: Path, cls: str) -> Path:
    p = tmp_path / "unreachable.yaml"
    p.write_text(
        f"scenario: unreachable\narguments:\n  startup_timeout: 1\nagent_types:\n  a: {cls}\n"
        "applications:\n  only:\n    agents:\n      - {type: a, robot: r0, id: a0}\n"
        "    end:\n      duration: 5\n      timeout: 20\n"
    )
    return p


def test_run_with_nothing_listening(tmp_path):
    r = run("run", str(_scenario(tmp_path, "WallfollowAgent")), "--connect", nothing_at(), "--timeout", "10")
    one_line(r, "rsal run", "agent host 'a0'", "no position2d device appeared within 1 s")


def test_run_when_an_agent_host_hits_a_bug(tmp_path):
    (tmp_path / "buggy.py").write_text(
        "from agents.classes import WallfollowAgent\n\n\n"
        "class Buggy(WallfollowAgent):\n    def __init__(self, *a, **kw):\n        raise RuntimeError('boom')\n"
    )
    r = run("run", str(_scenario(tmp_path, "buggy:Buggy")), "--connect", nothing_at(), "--timeout", "10")
    one_line(r, "rsal run", "agent host 'a0'", "unexpected RuntimeError: boom", "-v")


def test_watch_save_with_nothing_listening(tmp_path):
    r = run("watch", "--save", str(tmp_path / "w.rrd"), "--connect", nothing_at(), "--wait", "1")
    one_line(r, "rsal watch", "no devices match '**' within 1 s")


@pytest.mark.parametrize("cmd", [["serve", "deploy/testroom-map.toml"], ["sim", "maps/testroom.world"]])
def test_servers_with_their_port_in_use(cmd, busy_port):
    r = run(*cmd, "--listen", f"tcp/127.0.0.1:{busy_port}")
    one_line(r, f"rsal {cmd[0]}", f"cannot listen on tcp/127.0.0.1:{busy_port}: the port is in use")


def test_control_with_its_port_in_use(busy_port):
    r = run("control", "--port", str(busy_port), "--no-watch")
    one_line(r, "rsal control", f"127.0.0.1:{busy_port}", "--port")


def test_router_with_a_bad_endpoint_or_its_port_in_use(busy_port):
    one_line(run("router", "--listen", "foo/bar"), "rsal router", "bad endpoint", "tcp/127.0.0.1:7447")
    r = run("router", "--listen", f"tcp/127.0.0.1:{busy_port}")
    one_line(r, "rsal router", f"cannot listen on tcp/127.0.0.1:{busy_port}: the port is in use")


def test_demo_with_its_port_in_use(busy_port):
    one_line(run("demo", "--endpoint", f"tcp/127.0.0.1:{busy_port}"), "rsal demo", "in use", "--endpoint")


def test_demo_with_a_silent_simulator(monkeypatch, capfd):
    """``rsal demo`` whose simulator announces itself but never answers (its child process replaced
    by the silent peer): the models request times out and the net turns it into one line."""
    import rsal.procs
    from rsal.cli import main

    real_popen = subprocess.Popen
    started: list[subprocess.Popen] = []

    def fake_popen(cmd, **kw):
        endpoint = cmd[cmd.index("--listen") + 1]
        p = real_popen([sys.executable, str(SILENT), "--listen", endpoint, "sim:simulation:0"], **kw)
        started.append(p)
        return p

    monkeypatch.setattr(rsal.procs.subprocess, "Popen", fake_popen)
    monkeypatch.setattr(threading, "excepthook", threading.excepthook)
    try:
        code = main(["demo", "--endpoint", nothing_at(), "--startup-timeout", "5"])
    finally:
        for p in started:
            if p.poll() is None:
                p.kill()
                p.wait(5)
    out = capfd.readouterr()
    assert code == 1
    assert "Traceback" not in out.out + out.err
    lines = [ln for ln in out.err.splitlines() if ln.startswith("rsal")]
    assert lines == [
        "rsal demo: rsal/sim/simulation/0/rpc/models did not answer within 5 s; is its device server still "
        "starting, busy or gone? retry, or check the server's output and 'rsal ls'"
    ], out.err
