"""The fleet dispatcher end to end with real processes, judged on the simulator's ground truth.

``rsal sim maps/dispatch.world --nav vfh --truth`` (two Pioneers with the full navigation stack,
r0 at 23 % charge, one charger), a ``DispatcherAgent`` and two ``FleetAgent`` processes (``rsal
agent``), tasks submitted with ``rsal task``. The test watches ``task_state`` and reads the true
poses (``--truth``) at the moment a task is reported done:

1. bad tasks are refused by ``rsal task`` with one line and the typed reason (outside the map,
   unknown kind), nothing else happens;
2. task A is won by r0 (the nearer robot) and done with r0 truly at its goal; r0 is then below the
   20 % threshold and the dispatcher sends it to the charger: r0 truly docks and its battery rises
   to the charging target before it is given work again (50 % here, the policy's default is 90 %:
   the same charge, in 18 simulated seconds instead of 42);
3. task B, submitted while r0 charges, goes to r1; once B is active r1 breaks down (its base's
   emergency stop latched) and its agent is killed (SIGKILL): the dispatcher sees the liveliness
   token go, re-bids B
   and r0 does it after charging -- done by r0, truly at B's goal, r1 not; every task done exactly
   once;
4. a task assigned directly to f0 is cancelled; ``rsal task list`` shows every task's final state, and
   cancelling an unknown task is refused in one line.
"""

from __future__ import annotations

import os
import subprocess
import threading

import pytest

from agents.runtime import Agent, AgentHost
from agents.verdict import ARRIVE_TOLERANCE
from rsal.estop import estop
from rsal.transport import TransportArgs
from tests.conftest import MAPS, ROOT, SPEEDUP_NAV, LoopThread, rsal_cmd, wait_until
from tests.truth import Truth

WORLD = str(MAPS / "dispatch.world")
A = (3.5, -2.5)
B = (3.5, 2.5)
DOCK = (-4.0, 0.0)
#: the charging policy's target for the dispatcher and the FleetAgents (default 0.9)
TARGET = 0.5


class Watcher(Agent):
    """Collects every ``task_state`` with the true poses at its arrival."""

    def __init__(self, truth: Truth):
        super().__init__("watcher")
        self.truth = truth
        self.seen: list[tuple[dict, dict]] = []
        self.lock = threading.Lock()

    async def created(self) -> None:
        self.subscribe("task_state", self._on)

    def _on(self, msg) -> None:
        poses = {r: (p.x, p.y) for r, p in self.truth.poses().items()}
        with self.lock:
            self.seen.append((dict(msg.body), poses))

    def states(self, task_id: str) -> list[tuple[dict, dict]]:
        with self.lock:
            return [(b, p) for b, p in self.seen if b.get("task_id") == task_id]

    def reached(self, task_id: str, state: str) -> tuple[dict, dict] | None:
        return next(((b, p) for b, p in self.states(task_id) if b["state"] == state), None)


def _task(ep: str, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        rsal_cmd("task", *args, "--connect", ep), cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


def _dist(p, q) -> float:
    return ((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2) ** 0.5


@pytest.mark.timeout(600)
def test_dispatch_bids_charging_and_rebid_after_a_killed_robot(procs, port, fabric_factory):
    ep = f"tcp/127.0.0.1:{port}"
    env = {**os.environ, "RSAL_SIM_TIME": "sim"}
    procs(rsal_cmd("sim", WORLD, "--nav", "vfh", "--speedup", SPEEDUP_NAV, "--truth", "--listen", ep))
    fab = fabric_factory(port)
    truth = Truth(fab.session, ["r0", "r1"])
    wait_until(truth.ready, 60, "true poses from rsal sim --truth")
    power0 = fab.device("r0:power:0")
    common = ["--connect", ep, "--startup-timeout", "60", "--arg", f"target={TARGET}"]
    procs(
        rsal_cmd(
            "agent", "DispatcherAgent", "--id", "dispatcher", "--arg", "map=sim:map:0", "--arg", "simulation=sim",
            "--arg", "window=1.0", "--arg", "retry=2.0", "--arg", "max_rounds=200", *common,
        ),
        env=env,
    )  # fmt: skip
    fleet = {
        r: procs(rsal_cmd("agent", "FleetAgent", "--robot", r, "--id", f"f{r[1]}", *common), env=env)
        for r in ("r0", "r1")
    }
    lt = LoopThread(60)
    host = AgentHost.connect(TransportArgs(connect=[ep]))
    try:
        watcher = Watcher(truth)
        lt.run(_start(host, watcher))
        # 1. bad input: one line, a typed reason, exit 1
        bad = _task(ep, "submit", "go_to", "--arg", "x=20", "--arg", "y=0")
        assert bad.returncode == 1 and "refused (outside_map)" in bad.stderr, bad.stderr
        assert len(bad.stderr.strip().splitlines()) == 1 and "Traceback" not in bad.stderr
        bad = _task(ep, "submit", "goto", "--arg", "x=1", "--arg", "y=0")
        assert bad.returncode == 1 and "unknown_kind" in bad.stderr and "did you mean 'go_to'" in bad.stderr
        # both robots report before any task is bid for
        wait_until(lambda: all(lt.run(_known(host)).get(a) for a in ("f0", "f1")), 90, "both FleetAgents on the fabric")

        # 2. task A: r0 (nearer) wins, does it, then goes to charge below 20 %
        ok = _task(ep, "submit", "go_to", "--id", "A", "--arg", f"x={A[0]}", "--arg", f"y={A[1]}")
        assert ok.returncode == 0, ok.stderr
        wait_until(lambda: watcher.reached("A", "done") is not None, 240, "task A done")
        body, poses = watcher.reached("A", "done")
        assert body["robot"] == "f0"
        assert _dist(poses["r0"], A) < ARRIVE_TOLERANCE, poses  # ground truth: r0 is at A
        wait_until(lambda: any(b["kind"] == "charge" and b["robot"] == "f0" for b, _ in watcher.seen), 60, "a charge")
        charge = next(b["task_id"] for b, _ in watcher.seen if b["kind"] == "charge")

        # 3. task B while r0 charges: r1 takes it; r1's agent dies once B is active
        ok = _task(ep, "submit", "go_to", "--id", "B", "--arg", f"x={B[0]}", "--arg", f"y={B[1]}")
        assert ok.returncode == 0, ok.stderr
        wait_until(lambda: watcher.reached("B", "active") is not None, 120, "task B active")
        assert watcher.reached("B", "active")[0]["robot"] == "f1"
        assert estop(fab.session, "r1", timeout=10.0).confirmed  # r1 breaks down where it is ...
        fleet["r1"].kill()  # ... and its agent dies with it
        wait_until(lambda: watcher.reached(charge, "done") is not None, 400, "r0's charge done")
        body, poses = watcher.reached(charge, "done")
        assert _dist(poses["r0"], DOCK) < 0.6 and power0.fraction >= TARGET - 0.01, (poses, power0.fraction)
        wait_until(lambda: watcher.reached("B", "done") is not None, 300, "task B done by another robot")
        body, poses = watcher.reached("B", "done")
        assert body["robot"] == "f0"
        assert _dist(poses["r0"], B) < ARRIVE_TOLERANCE and _dist(poses["r1"], B) > 1.0, poses
        for tid in ("A", "B", charge):
            assert sum(b["state"] == "done" for b, _ in watcher.states(tid)) == 1
        b_states = [b["state"] for b, _ in watcher.states("B")]
        assert b_states.index("bidding", b_states.index("active")) > 0  # re-bid after f1 went

        # 4. a task directly assigned to f0 and cancelled; the list shows every task's state
        ok = _task(ep, "submit", "go_to", "--id", "C", "--robot", "f0", "--arg", "x=0", "--arg", "y=-3")
        assert ok.returncode == 0 and "f0" in ok.stdout, ok.stderr
        gone = _task(ep, "cancel", "C")
        assert gone.returncode == 0 and "cancelled" in gone.stdout, gone.stderr
        rows = {line.split()[0]: line.split()[2] for line in _task(ep, "list").stdout.splitlines()}
        assert rows["A"] == rows["B"] == rows[charge] == "done" and rows["C"] == "cancelled", rows
        missing = _task(ep, "cancel", "nope")
        assert missing.returncode == 1 and "not_found" in missing.stderr
    finally:
        for b, poses in list(watcher.seen):  # shown when the test fails
            print(b["task_id"], b["state"], b["robot"], b["reason"], b["text"], poses)
        lt.run(host.stop())
        lt.close()
        truth.close()


async def _start(host: AgentHost, agent: Agent) -> None:
    await host.start(agent)


async def _known(host: AgentHost) -> dict[str, bool]:
    return {h.id: True for h in await host.who_is_there(0.5)}
