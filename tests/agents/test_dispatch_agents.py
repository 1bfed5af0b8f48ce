"""The dispatcher's agents on one AgentHost over a real Zenoh session on loopback: the
``DispatcherAgent`` with two stand-in robots (:class:`agents.dispatch.agent.FleetWorker` without a
simulator, each keeping a record of what it truly performed): the nearer robot is awarded, a
forfeited task is done by the other, a task cancelled while under way is abandoned (never reported
done), a malformed ``fleet`` message is dropped, and a robot agent killed with work queued loses
it to the other robot. Every task is performed exactly once (the robots' own records)."""

from __future__ import annotations

import asyncio
import math

from agents.dispatch.agent import DispatcherAgent
from agents.dispatch.tasks import TaskRequest, TaskStatus
from agents.runtime import Agent, AgentHost
from rsal.transport import TransportArgs
from tests.agents.standin import StandIn
from tests.conftest import free_port


async def _until(cond, timeout: float, what: str):
    deadline = asyncio.get_running_loop().time() + timeout
    while not cond():
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.02)


def test_dispatcher_agents_award_forfeit_cancel_and_loss():
    async def main():
        ep = f"tcp/127.0.0.1:{free_port()}"
        async with AgentHost.connect(TransportArgs(listen=[ep])) as host:
            a, b = StandIn("a", 0.0, 0.0), StandIn("b", 10.0, 0.0)
            user = Agent("user")
            states: list[dict] = []
            for ag in (a, b, user):
                await host.start(ag)
            user.subscribe(TaskStatus.SERVICE, lambda m: states.append(dict(m.body)))
            disp = await host.start(DispatcherAgent("dispatcher", window=0.5, retry=0.2, max_rounds=50))
            await _until(lambda: {"a", "b"} <= set(disp.core.robots), 10, "both robots' status")

            def submit(tid: str, x: float, **kw) -> None:
                task = {"id": tid, "kind": "go_to", "args": {"x": x, "y": 0.0}, **kw}
                user.publish(TaskRequest.SERVICE, TaskRequest("submit", task=task))

            def state(tid: str) -> str | None:
                return next((s["state"] for s in reversed(states) if s["task_id"] == tid), None)

            # the nearer robot is awarded
            submit("near-a", 1.0)
            submit("near-b", 9.0)
            await _until(lambda: state("near-a") == state("near-b") == "done", 10, "two tasks done")
            assert a.performed == ["near-a"] and b.performed == ["near-b"]
            # a forfeited task goes to the other robot
            a.hold.clear()  # a is busy with a long task, so 'give' waits in its queue
            submit("long", 1.5, robot="a")
            await _until(lambda: state("long") == "active", 5, "a busy")
            submit("give", 1.0, robot="a")
            await _until(lambda: any(t.id == "give" for t in a.queue), 5, "give queued at a")
            assert a.forfeit("give")
            await _until(lambda: state("give") == "done", 10, "the forfeited task done by b")
            assert "give" in b.performed and "give" not in a.performed
            # a task cancelled while a performs it is abandoned, never reported done
            user.publish(TaskRequest.SERVICE, TaskRequest("cancel", task_id="long"))
            await _until(lambda: a.abandoned == ["long"], 5, "the cancelled task abandoned")
            a.hold.set()
            # a malformed fleet message is dropped, the dispatcher goes on
            user.publish("fleet", {"op": "bid", "task_id": "x", "cost": "cheap"})
            await _until(lambda: ("fleet", "user") in disp._warned, 5, "the malformed message dropped")
            # b dies with work queued: a does it
            b.hold.clear()
            submit("b1", 9.5, robot="b")
            submit("b2", 9.0, robot="b")
            await _until(lambda: state("b1") == "active" and state("b2") == "assigned", 5, "b busy")
            await host.kill(b)
            await _until(lambda: state("b1") == state("b2") == "done", 10, "b's tasks done by a")
            await asyncio.sleep(0.5)  # a late double would show now
            return a, b, states

    a, b, states = asyncio.run(main())
    assert {"b1", "b2"} <= set(a.performed) and not {"b1", "b2"} & set(b.performed)
    assert "long" not in a.performed + b.performed
    done = [s["task_id"] for s in states if s["state"] == "done"]
    performed = a.performed + b.performed
    assert sorted(done) == sorted(performed) and len(set(performed)) == len(performed)
    assert math.isclose(a.pos[0], 9.0) or math.isclose(a.pos[0], 9.5)
