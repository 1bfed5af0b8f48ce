"""Shared test helpers: free loopback ports, real server processes, clients on loopback.

Integration tests start real processes (``start_new_session=True``) and always stop them by the
PID they started; they wait on conditions with deadlines, never on fixed sleeps.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from rsal.procs import die_with_parent

ROOT = Path(__file__).resolve().parent.parent
MAPS = ROOT / "maps"


def stock_session(listen: str | None = None, connect: str | None = None):
    """A plain zenoh-python peer, as an outsider or a stock client opens it (no project code):
    loopback endpoints, multicast scouting off."""
    import json

    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    # a peer that only connects would listen on Zenoh's default, every interface
    conf.insert_json5("listen/endpoints", json.dumps([listen or "tcp/127.0.0.1:0"]))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps([connect]))
    return zenoh.open(conf)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(cond, timeout: float, what: str, interval: float = 0.02):
    """Poll ``cond()`` until truthy; fail the test with ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(interval)


class Proc:
    """A child process in its own session, killed by PID on exit."""

    def __init__(self, args: list[str], *, env: dict | None = None, cwd: Path = ROOT):
        e = dict(os.environ)
        e.update(env or {})
        e.setdefault("PYTHONUNBUFFERED", "1")
        self.args = args
        self.log_path = Path(os.environ.get("PYTEST_TMP", "/tmp")) / f"proc-{os.getpid()}-{time.monotonic_ns()}.log"
        self._log = open(self.log_path, "w+b")
        # SIGTERM when the test process dies (a killed pytest leaves no simulator running); tied to
        # the forking thread, so only from the main thread
        orphan = die_with_parent() if threading.current_thread() is threading.main_thread() else {}
        self.p = subprocess.Popen(
            args, stdout=self._log, stderr=subprocess.STDOUT, cwd=cwd, env=e, start_new_session=True, **orphan
        )

    @property
    def pid(self) -> int:
        return self.p.pid

    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.p.poll() is None

    def signal(self, sig: int) -> None:
        if self.alive():
            os.kill(self.p.pid, sig)

    def stop(self, timeout: float = 10.0) -> int:
        if self.alive():
            self.signal(signal.SIGTERM)
            try:
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.signal(signal.SIGKILL)
                self.p.wait(5)
        return self.p.returncode

    def kill(self) -> None:
        if self.alive():
            self.signal(signal.SIGKILL)
            self.p.wait(5)

    def close(self) -> None:
        try:
            self.stop()
        finally:
            self._log.close()
            try:
                self.log_path.unlink()
            except OSError:
                pass


def rsal_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "rsal.cli", *args]


@pytest.fixture
def procs():
    started: list[Proc] = []

    def start(args, **kw) -> Proc:
        p = Proc(args, **kw)
        started.append(p)
        return p

    yield start
    for p in started:
        p.close()


@pytest.fixture
def port() -> int:
    return free_port()


@pytest.fixture
def fabric_factory():
    from rsal.client import Fabric
    from rsal.transport import TransportArgs

    made = []

    def make(port: int) -> Fabric:
        f = Fabric.connect(TransportArgs(connect=[f"tcp/127.0.0.1:{port}"]))
        made.append(f)
        return f

    yield make
    for f in made:
        f.close()


# Scenario tests run the simulator this many times faster than real time; their agents follow the
# simulation's clock (sim_time), so they behave as at real time.
SPEEDUP = "3"
# Scenario tests whose robots are moved only by the navigation stack inside the simulator's process
# (goals to Wavefront, VFH on each odometry message) run faster: no commander in another process has
# to refresh a velocity within the bases' 0.5 simulated seconds of cmd_timeout (docs/protocol.md,
# "Command timeout"), so the speed-up is bounded only by what the simulator's process keeps up with;
# when it cannot, the simulation runs slower and everything follows it (docs/concepts.md, "One clock").
SPEEDUP_NAV = "6"


@pytest.fixture
def sim_time():
    """``follow(session, node="sim")``: this process follows that simulation's clock
    (:func:`rsal.clock.use_sim_time`) until the end of the test."""
    from rsal.clock import WallClock, set_clock, use_sim_time

    made = []

    def follow(session, node: str = "sim"):
        c = use_sim_time(session, node)
        made.append(c)
        assert c.wait_started(60.0), f"no time from the simulation of node {node!r}"
        return c

    yield follow
    set_clock(WallClock())
    for c in made:
        c.close()


class LoopThread:
    """An asyncio loop on a daemon thread for tests that host agents in-process; ``run(coro)``
    waits for the result (``timeout`` seconds, the instance's default unless given)."""

    def __init__(self, timeout: float = 20.0):
        import asyncio

        self.default_timeout = timeout
        self.loop = asyncio.new_event_loop()
        self.t = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.t.start()

    def run(self, coro, timeout: float | None = None):
        import asyncio

        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout or self.default_timeout)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.t.join(5)
        self.loop.close()


def pytest_terminal_summary(terminalreporter):
    """Say why each rerun test failed the first time: the summary's RERUN line names it only, and a
    test that passes at its rerun is flaky; the reason is what mends it."""
    reruns = terminalreporter.stats.get("rerun", [])
    if not reruns:
        return
    terminalreporter.section("why the rerun tests failed first")
    for rep in reruns:
        text = str(rep.longrepr or "").rstrip().splitlines()
        here = rep.nodeid.split("::", 1)[0] + ":"  # the test file's own frames: where it waited
        terminalreporter.write_line(f"{rep.nodeid}:")
        for line in [ln for ln in text[:-25] if ln.startswith(here)] + text[-25:]:
            terminalreporter.write_line(f"    {line}")
