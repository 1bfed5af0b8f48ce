"""Find and Collect in mixed reality (thesis 4.2.2, 4.3, figs. 4.5/4.6), end to end.

``rsal run deploy/scenarios/find_collect.yaml --app mixed`` starts the virtual world (the explorer
e1 with its blob camera, the blob blob0 and the proxy of c1), then the rehearsal of the real
collector c1 (``rsal rehearse``: an emulated Pioneer 2DX with a gripper and an emulated URG in
``maps/mixed_real_collect.world``, served by the real p2os and hokuyo drivers with amcl, vfh and
wavefront), then the agents. The test joins the run's fabric and samples both worlds' ground truth
while it runs: the real bin must truly end within 1 m of c1's home, c1 must truly have driven to it,
and c1's proxy in the virtual world must have followed c1's true pose. Every process the run
started must be gone afterwards.
"""

from __future__ import annotations

import math
import os
import re
import statistics
import threading
import time

import pytest

from rsal.client import Fabric
from rsal.transport import TransportArgs
from tests.conftest import MAPS, free_port, rsal_cmd, wait_until

HOME = (-22.0, 1.75)  # c1's start in maps/mixed_real_collect.world
BIN = (-14.0, 1.6)  # bin0 there, blob0 in maps/mixed_virtual_collect.world
DELIVERED = 1.0  # m: the scenario's verdict, a bin within 1 m of home


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


class _Sampler(threading.Thread):
    """True poses of c1 and bin0 in the real world and of c1's proxy in the virtual one, every 0.2 s."""

    def __init__(self, port: int):
        super().__init__(daemon=True, name="truth-sampler")
        self.port = port
        self.stop = threading.Event()
        self.samples: list[tuple[float, tuple, tuple, tuple | None]] = []  # t, c1, bin0, proxy c1

    def run(self) -> None:
        fab = Fabric.connect(TransportArgs(connect=[f"tcp/127.0.0.1:{self.port}"]))
        try:
            real, virtual = fab.device("world:simulation:0"), fab.device("sim:simulation:0")
            while not self.stop.wait(0.2):
                try:
                    c1, bin0 = real.get_pose("c1"), real.get_pose("bin0")
                except Exception:  # the rehearsal is not up yet, or gone
                    continue
                try:
                    proxy = virtual.get_pose("c1").as_tuple()
                except Exception:
                    proxy = None
                self.samples.append((time.monotonic(), c1.as_tuple(), bin0.as_tuple(), proxy))
        finally:
            fab.close()


@pytest.mark.timeout(600)
def test_the_real_collector_fetches_the_bin_the_virtual_explorer_found(procs):
    port = free_port()
    run = ("run", "deploy/scenarios/find_collect.yaml", "--app", "mixed", "--listen", f"tcp/127.0.0.1:{port}")
    p = procs(rsal_cmd(*run))
    sampler = _Sampler(port)
    sampler.start()
    try:
        wait_until(lambda: not p.alive(), 480, "rsal run to end the mixed Find and Collect", interval=0.2)
    finally:
        sampler.stop.set()
        sampler.join(10)
    out = p.output()
    assert p.p.returncode == 0, out
    assert "Traceback" not in out
    # the order of the run: virtual world, rehearsal of the real robot, then the agents
    assert out.index("[run] simulator up") < out.index("[run] started rehearse (pid")
    assert re.search(r"\[run\] started rehearse \(pid \d+\): rsal rehearse maps/mixed_real_collect.world c1 ", out)
    assert out.index("[run] rehearsed robot c1 up after") < out.index("[run] started collector1 (pid")
    assert "driver #1 (p2os): connected to c1 (Pioneer P2DX)" in out  # through the real driver
    # the real world runs in real time: every agent on the wall clock, not the virtual simulation's
    assert "on the simulation's clock" not in out
    # the virtual explorer found the blob where it is (AMCL's 0.30 m plus the camera's range estimate)
    m = re.search(r"explorer1: new green blob at \((-?[\d.]+), (-?[\d.]+)\)", out)
    assert m and math.dist((float(m.group(1)), float(m.group(2))), BIN) < 0.5, out
    assert re.search(r"\[run\] result: ok — blob0 at \(.*\) delivered home by collector1", out), out
    assert "[run] ground truth: 1 bin(s) within 1 m of a collector's home" in out

    # the real world's ground truth, sampled by this test
    s = sampler.samples
    assert len(s) > 50, f"only {len(s)} true-pose samples"
    assert math.dist(s[0][2][:2], BIN) < 0.05  # the bin lay at the blob's spot
    farthest = max(math.dist(c1[:2], HOME) for _, c1, _, _ in s)
    assert farthest > 6.5, f"c1 got only {farthest:.2f} m from home (ground truth)"
    end = s[-1][2][:2]
    assert math.dist(end, HOME) < DELIVERED, f"the real bin ended at {end}, not home (ground truth)"
    assert math.dist(end, BIN) > 6.0  # it was carried, not found lying home
    # the proxy followed c1: the ViewAgent mirrored its broadcast (AMCL) pose into the virtual world
    moving = [math.dist(c1[:2], px[:2]) for _, c1, _, px in s if px is not None and math.dist(c1[:2], HOME) > 0.5]
    assert len(moving) > 20
    assert statistics.median(moving) < 0.3, f"proxy off c1's true pose by {statistics.median(moving):.2f} m (median)"
    took = re.search(r"\[run\] elapsed ([\d.]+) s", out).group(1)
    print(
        f"mixed Find and Collect: {took} s; c1 up to {farthest:.2f} m from home; bin {math.dist(end, HOME):.2f} m "
        f"from home; proxy off c1 by {statistics.median(moving):.3f} m median, {max(moving):.3f} m worst"
    )

    # every process the run started, and the rehearsal's drivers' server, is gone
    pids = [int(x) for x in re.findall(r"\[run\] started \S+ \(pid (\d+)\)", out)]
    pids += [int(x) for x in re.findall(r"started the drivers: rsal serve \(pid (\d+)\)", out)]
    assert len(pids) >= 7
    wait_until(lambda: all(_gone(pid) for pid in pids), 10, "the run's processes to end")


def test_a_speedup_is_refused_for_a_rehearsed_robot(procs):
    p = procs(rsal_cmd("run", "deploy/scenarios/find_collect.yaml", "--app", "mixed", "--speedup", "3"))
    wait_until(lambda: not p.alive(), 60, "rsal run to refuse the speed-up", interval=0.1)
    out = p.output().strip()
    assert p.p.returncode == 2
    assert out == "rsal run: --speedup 3: application 'mixed' rehearses a real robot, which runs in real time"


def test_a_rehearsal_that_cannot_start_fails_the_run_in_one_line(procs, tmp_path):
    """A robot the real world does not have: rsal rehearse exits 1 with its one line, and the run
    fails naming the rehearsal and quoting it, before any agent starts."""
    f = tmp_path / "s.yaml"
    f.write_text(
        f"""
scenario: wrong
agent_types: {{collector: CollectAgent}}
applications:
  mixed:
    simulator: {{world: {MAPS / "mixed_virtual_collect.world"}}}
    rehearse: {{world: {MAPS / "mixed_real_collect.world"}, robot: c9}}
    agents:
      - {{type: collector, robot: c9}}
    end: {{event: delivered, timeout: 60}}
"""
    )
    p = procs(rsal_cmd("run", str(f)))
    wait_until(lambda: not p.alive(), 90, "rsal run to fail", interval=0.1)
    out = p.output()
    assert p.p.returncode == 1, out
    assert re.search(
        r"(?m)^rsal run: the rehearsal \(pid \d+\) exited with code 1: rsal rehearse: .*mixed_real_collect.world: "
        r"no robot named 'c9'; robots: c1$",
        out,
    ), out
    assert "[run] started collector-c9" not in out and "Traceback" not in out
