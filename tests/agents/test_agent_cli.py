"""``rsal agent`` across processes (thesis 3.5, 3.6.1): the simulator in one process, the agent in
another, this test process watching the fabric through a raw Zenoh session on a free loopback port.

(a) WallfollowAgent on r0: its ``send_position`` messages arrive and the pose changes (the robot
moves); its token ``agents/<id>`` is alive; SIGTERM exits 0 with the token withdrawn and the robot
stopped. (b) An unknown class and (c) a robot whose devices never appear give one line on stderr and
exit 1. Every wait has a deadline; there are no fixed sleeps.
"""

from __future__ import annotations

import math
import signal
import threading

from agents.services import SendPosition, decode_message
from rsal.transport import TransportArgs, open_session
from tests.conftest import MAPS, free_port, rsal_cmd, wait_until

WORLD = str(MAPS / "testroom.world")


def alive_agents(session) -> set[str]:
    return {str(r.ok.key_expr) for r in session.liveliness().get("agents/*", timeout=1.0) if r.ok}


def test_wallfollow_agent_publishes_moves_and_stops_on_sigterm(procs, fabric_factory):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    sim = procs(rsal_cmd("sim", WORLD, "--listen", ep))
    agent = procs(rsal_cmd("agent", "WallfollowAgent", "--robot", "r0", "--id", "wf0", "--connect", ep))
    got: list[SendPosition] = []
    lock = threading.Lock()

    def on_sample(sample) -> None:
        key = str(sample.key_expr)
        msg = decode_message("send_position", key.rsplit("/", 1)[-1], sample.payload.to_bytes())
        with lock:
            got.append(msg.body)

    session = open_session(TransportArgs(connect=[ep]))
    try:
        sub = session.declare_subscriber("svc/send_position/*", on_sample)
        wait_until(lambda: "agents/wf0" in alive_agents(session), 60, "the agent's token agents/wf0")
        wait_until(lambda: len(got) >= 2, 30, "two send_position messages from the agent")
        first = got[0]
        assert first.robot == "r0" and first.frame in ("odom", "map")

        def moved() -> bool:
            with lock:
                last = got[-1]
            return math.hypot(last.x - first.x, last.y - first.y) > 0.2

        wait_until(moved, 60, "r0's published position to change by 0.2 m")
        assert sim.alive() and agent.alive()
        assert "[agent] starting WallfollowAgent wf0" in agent.output()

        agent.signal(signal.SIGTERM)
        wait_until(lambda: not agent.alive(), 15, "the agent process to exit after SIGTERM")
        assert agent.p.returncode == 0, agent.output()
        assert "[agent] wf0 stopped (SIGTERM)" in agent.output()
        assert "Traceback" not in agent.output()
        wait_until(lambda: "agents/wf0" not in alive_agents(session), 10, "the token agents/wf0 withdrawn")
        pos = fabric_factory(port).device("r0:position2d:0")
        n = pos.wait_for_data(10) and pos.count
        wait_until(lambda: pos.count > n and max(abs(v) for v in pos.latest.vel) < 1e-6, 10, "r0 stopped by the agent")
        sub.undeclare()
    finally:
        session.close()


def test_unknown_class_is_one_line_error(procs):
    p = procs(rsal_cmd("agent", "HunterAgent", "--robot", "r0", "--connect", f"tcp/127.0.0.1:{free_port()}"))
    wait_until(lambda: not p.alive(), 30, "the command to exit")
    out = p.output().strip()
    assert p.p.returncode == 1
    assert out.splitlines() == [out]
    assert "unknown agent class 'HunterAgent'" in out and "EscapeAgent" in out and "WallfollowAgent" in out


def test_robot_not_found_is_one_line_error(procs):
    ep = f"tcp/127.0.0.1:{free_port()}"  # nothing serves there
    p = procs(rsal_cmd("agent", "EscapeAgent", "--robot", "r9", "--startup-timeout", "1", "--connect", ep))
    wait_until(lambda: not p.alive(), 30, "the command to exit")
    lines = [line for line in p.output().splitlines() if not line.startswith("[agent] starting")]
    assert p.p.returncode == 1
    assert len(lines) == 1 and lines[0].startswith("rsal agent: robot 'r9'") and "1 s" in lines[0]


def test_robot_agents_take_the_thesis_arguments_index_pose_simulation():
    import pytest

    from agents.classes import WallfollowAgent

    a = WallfollowAgent("wf", robot="r0", index=1, pose=[1.0, 2.0, 90.0], simulation=True, laser=False)
    assert (a.index, a.simulation, a.laser) == (1, True, False)
    assert (a.start_pose.x, a.start_pose.y) == (1.0, 2.0) and abs(a.start_pose.yaw - math.pi / 2) < 1e-9
    for bad in ({"index": -1}, {"index": True}, {"index": 1.5}):
        with pytest.raises(ValueError, match="index"):
            WallfollowAgent("wf", robot="r0", **bad)
    with pytest.raises(ValueError, match=r"pose .* must be \[x, y, degrees\]"):
        WallfollowAgent("wf", robot="r0", pose=[1.0, 2.0])


def test_the_base_is_the_position2d_of_the_given_index():
    from agents.classes import WallfollowAgent
    from rsal.robot import RobotError

    class Dev:
        def __init__(self, interface, index):
            self.interface, self.index = interface, index

    a = WallfollowAgent("wf", robot="r0", index=2)
    import pytest

    with pytest.raises(RobotError, match="no position2d:2"):
        a.make_robot([Dev("position2d", 0), Dev("laser", 0)])
