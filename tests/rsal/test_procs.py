"""rsal.procs: a child started with ``die_with_parent()`` or ``spawn()`` ends when its parent is
SIGKILLed, and a child spawned from a short-lived thread outlives that thread; the supervisor
:class:`Child` relays and keeps output lines, states an exit in one line and stops a child with
SIGINT, then SIGTERM, then SIGKILL, each after its deadline, by PID."""

from __future__ import annotations

import os
import signal
import sys
import time

from rsal.procs import REPO_ROOT, Child, python_env, stop_all
from tests.conftest import ROOT, wait_until

PARENT = """
import subprocess, sys, time
from rsal.procs import die_with_parent
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"], **die_with_parent())
print(child.pid, flush=True)
time.sleep(120)
"""


SPAWNER = """
import sys, threading, time
from rsal.procs import spawn
out = []
t = threading.Thread(target=lambda: out.append(spawn([sys.executable, "-c", "import time; time.sleep(120)"])))
t.start(); t.join()
print(out[0].pid, flush=True)
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ", 1)[1][0] != "Z"
    except FileNotFoundError:
        return False


def test_a_child_dies_when_its_parent_is_killed(procs):
    parent = procs([sys.executable, "-c", PARENT], env={"PYTHONPATH": str(ROOT)})
    line = wait_until(lambda: parent.output().strip(), 10, "the parent to print its child's pid")
    child = int(line.split()[0])
    assert _alive(child)
    os.kill(parent.pid, signal.SIGKILL)
    try:
        wait_until(lambda: not _alive(child), 5, "the child to end after its parent was killed")
    finally:
        if _alive(child):
            os.kill(child, signal.SIGKILL)


def test_a_child_spawned_by_a_short_lived_thread_lives_until_its_parent_is_killed(procs):
    parent = procs([sys.executable, "-c", SPAWNER], env={"PYTHONPATH": str(ROOT)})
    line = wait_until(lambda: parent.output().strip(), 10, "the parent to print its child's pid")
    child = int(line.split()[0])
    try:
        deadline = time.monotonic() + 1.0  # the starting thread has ended: the child must stay
        while time.monotonic() < deadline:
            assert _alive(child), "the child died with the thread that asked for it"
            time.sleep(0.05)
        os.kill(parent.pid, signal.SIGKILL)
        wait_until(lambda: not _alive(child), 5, "the child to end after its parent was killed")
    finally:
        if _alive(child):
            os.kill(child, signal.SIGKILL)


# a child that says which signals it got and ignores the ones named in argv
STUBBORN = """
import signal, sys, time
for name in sys.argv[1:]:
    signal.signal(getattr(signal, name), lambda n, f: print("got", signal.Signals(n).name, flush=True))
print("ready", flush=True)
time.sleep(120)
"""


def test_child_forwards_lines_with_its_name_and_states_its_exit():
    got: list[str] = []
    seen: list[str] = []
    code = "import sys; print('hello'); print('[self] named'); print('bad thing', file=sys.stderr); sys.exit(3)"
    c = Child("kid", [sys.executable, "-c", code], forward=got.append, on_line=seen.append, stderr_apart=True)
    wait_until(lambda: c.poll() is not None, 10, "the child to exit")
    c.drained()
    assert sorted(got) == ["[kid] bad thing", "[kid] hello", "[self] named"]
    assert sorted(seen) == ["[self] named", "bad thing", "hello"]
    assert c.exit_reason() == "exited with code 3: bad thing"  # the last line of its stderr
    assert c.state == "failed" and c.info()["exit_code"] == 3


def test_child_keeps_its_last_lines_and_merges_stderr_by_default():
    code = "import sys\nfor i in range(10): print(i)\nprint('oops', file=sys.stderr)"
    c = Child("kid", [sys.executable, "-c", code], keep=3)
    wait_until(lambda: c.poll() is not None, 10, "the child to exit")
    c.drained()
    assert list(c.lines) == ["8", "9", "oops"]
    assert c.state == "finished" and c.exit_reason() == "exited with code 0: oops"


def _stubborn(*ignored: str) -> Child:
    c = Child("stub", [sys.executable, "-c", STUBBORN, *ignored])
    wait_until(lambda: "ready" in c.lines, 10, "the child to install its handlers")
    return c


def test_stop_escalates_from_sigint_to_sigterm():
    c = _stubborn("SIGINT")
    t0 = time.monotonic()
    rc = c.stop(((signal.SIGINT, 0.5), (signal.SIGTERM, 5.0)))
    assert rc == -signal.SIGTERM and time.monotonic() - t0 < 5.0
    assert "got SIGINT" in c.lines and c.state == "stopped"
    assert c.exit_reason() == "was ended by SIGTERM: got SIGINT"


def test_stop_kills_a_child_that_ignores_every_signal_and_says_so():
    c = _stubborn("SIGINT", "SIGTERM")
    killed: list[tuple[int, float]] = []
    rc = c.stop(((signal.SIGINT, 0.3), (signal.SIGTERM, 0.3)), on_kill=lambda ch, w: killed.append((ch.pid, w)))
    assert rc == -signal.SIGKILL and "got SIGTERM" in c.lines
    assert killed == [(c.pid, 0.6)]
    d = _stubborn("SIGINT", "SIGTERM")
    d.stop(((signal.SIGINT, 0.2),))  # the default report: a line among its own
    assert d.lines[-1] == f"[supervisor] pid {d.pid} did not stop within 0.2 s; killed"


def test_stop_all_runs_one_deadline_for_all_children():
    kids = [_stubborn("SIGINT") for _ in range(3)]
    t0 = time.monotonic()
    stop_all(kids, ((signal.SIGINT, 1.0), (signal.SIGTERM, 5.0)))
    took = time.monotonic() - t0
    assert all(k.poll() == -signal.SIGTERM for k in kids)
    assert took < 2.5, f"three children waited {took:.1f} s: their deadlines did not run together"
    stop_all(kids)  # stopped children: nothing to do


def test_python_env_puts_the_given_folders_then_cwd_and_the_repository_first(monkeypatch, tmp_path):
    monkeypatch.setenv("PYTHONPATH", "/elsewhere")
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    env = python_env(tmp_path, tmp_path)  # a folder named twice is listed once
    assert env["PYTHONPATH"].split(os.pathsep) == [str(tmp_path), str(tmp_path / "cwd"), str(REPO_ROOT), "/elsewhere"]
    assert env["PYTHONUNBUFFERED"] == "1" and (REPO_ROOT / "rsal" / "procs.py").is_file()
