"""rsal.procs: a child started with ``die_with_parent()`` ends when its parent is SIGKILLed."""

from __future__ import annotations

import os
import signal
import sys

from conftest import ROOT, wait_until

PARENT = """
import subprocess, sys, time
from rsal.procs import die_with_parent
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"], **die_with_parent())
print(child.pid, flush=True)
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
