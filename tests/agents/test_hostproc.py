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
