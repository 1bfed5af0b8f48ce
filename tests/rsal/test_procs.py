"""rsal.procs: a child started with ``die_with_parent()`` or ``spawn()`` ends when its parent is
SIGKILLed, and a child spawned from a short-lived thread outlives that thread."""

from __future__ import annotations

import os
import signal
import sys
import time

from conftest import ROOT, wait_until

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
