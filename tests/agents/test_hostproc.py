"""The agent-host process's start-up (agents/hostproc.py ``serve_agents``) over a real Zenoh session
on loopback: an agent that drives a robot is searched for its devices before it starts, unless its
host builds its robot (``robot_built_by_host``: a swarm agent, built through its host's hub)."""

from __future__ import annotations

import asyncio

from agents.hostproc import serve_agents
from agents.runtime import Agent
from agents.scenarios.swarm import SwarmAgent
from rsal.transport import TransportArgs
from tests.conftest import free_port


class Driver(Agent):
    """An agent with a robot to find; records the searches made for it."""

    robot_built_by_host = False

    def __init__(self, agent_id: str):
        super().__init__(agent_id)
        self.robot = "r0"
        self.pioneer = None
        self.searched = 0

    async def find_robot(self, fabric) -> None:
        self.searched += 1
        self.pioneer = object()

    async def body(self) -> None:
        await asyncio.sleep(30)


class HubBuilt(Driver):
    robot_built_by_host = True


def test_only_agents_whose_host_does_not_build_their_robot_are_searched_for_it():
    searched, built = Driver("searched"), HubBuilt("built")
    errors: list[str] = []
    targs = TransportArgs(listen=[f"tcp/127.0.0.1:{free_port()}"])
    code = asyncio.run(serve_agents([searched, built], targs, tag="[host t]", fail=errors.append, duration=0.3))
    assert code == 0 and not errors
    assert searched.searched == 1 and built.searched == 0
    assert SwarmAgent.robot_built_by_host  # the swarm's agents are built by their host's hub


class Idle(Agent):
    """An agent without a robot that waits to be stopped."""

    def __init__(self, agent_id: str, robot: str = ""):
        super().__init__(agent_id)
        self.robot = robot

    async def body(self) -> None:
        await asyncio.sleep(30)


def test_a_crowd_of_agents_is_started_and_stopped_in_a_line_each_for_all_and_each_with_v(capsys):
    crowd = [Idle(f"c{i}", f"r{i}") for i in range(12)] + [Idle("judge")]
    targs = TransportArgs(listen=[f"tcp/127.0.0.1:{free_port()}"])
    assert asyncio.run(serve_agents(crowd, targs, tag="[host t]", fail=print, duration=0.3)) == 0
    out = capsys.readouterr().out.splitlines()
    assert "[host t] starting 12 Idle c0..c11 for robots r0..r11 (period 0.1 s)" in out, out
    assert "[host t] starting 1 Idle judge (period 0.1 s)" in out
    assert "[host t] 13 agents running: c0..c11, judge, tokens agents/<id>" in out
    stopped = [line for line in out if " stopped (" in line]
    assert stopped[:3] == [f"[host t] c{i} stopped (duration 0.3 s): {crowd[i].state}" for i in range(3)], stopped
    assert stopped[3] == "[host t] 10 more agents stopped (duration 0.3 s): c3..c11, judge (-v: each one's status)"
    assert len(stopped) == 4

    few = [Idle(f"c{i}") for i in range(12)]
    targs = TransportArgs(listen=[f"tcp/127.0.0.1:{free_port()}"])
    assert asyncio.run(serve_agents(few, targs, tag="[host t]", fail=print, duration=0.3, each=True)) == 0
    out = capsys.readouterr().out.splitlines()
    assert sum(" running: Idle" in line for line in out) == 12
    assert sum(" stopped (duration" in line for line in out) == 12
