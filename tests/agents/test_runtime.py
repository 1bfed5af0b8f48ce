"""Tests of the agent runtime and services (thesis 3.6.1) over real Zenoh sessions on loopback.

Each test opens a listening session and a connecting one on a free loopback port (multicast off),
runs agent hosts on an asyncio loop in a background thread, and waits on conditions with deadlines
(``wait_until``), never on fixed sleeps.
"""

from __future__ import annotations

import asyncio
import logging
import threading

import msgpack
import pytest

from agents.runtime import Agent, AgentHost
from agents.services import Hello, Message, NewGoal, SendPosition, decode_message, encode_message, match
from rsal.msgs import MessageError
from rsal.transport import TransportArgs, open_session
from tests.conftest import LoopThread, free_port, wait_until


@pytest.fixture
def net():
    """Two sessions on a free loopback port: ``listen`` (listening) and ``connect``."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    a = open_session(TransportArgs(listen=[ep]))
    b = open_session(TransportArgs(connect=[ep]))
    lt = LoopThread()
    hosts: list[AgentHost] = []

    def host(session) -> AgentHost:
        h = AgentHost(session)
        lt.run(h.__aenter__())
        hosts.append(h)
        return h

    yield {"listen": a, "connect": b, "loop": lt, "host": host}
    for h in hosts:
        lt.run(h.stop())
    lt.close()
    b.close()
    a.close()


def alive_agents(session) -> set[str]:
    return {str(r.ok.key_expr) for r in session.liveliness().get("agents/*", timeout=1.0) if r.ok}


class Recorder(Agent):
    def __init__(self, agent_id: str, *, fail_at: int | None = None, **kw):
        super().__init__(agent_id, period=0.01, **kw)
        self.events: list[str] = []
        self.steps = 0
        self.fail_at = fail_at

    async def created(self):
        self.events.append("created")

    async def step(self):
        self.steps += 1
        if self.events[-1] != "step":
            self.events.append("step")
        if self.steps == self.fail_at:
            raise RuntimeError("step failed on purpose")

    async def killed(self):
        self.events.append("killed")


# ---------------------------------------------------------------------------- lifecycle
def test_lifecycle_order_and_token(net):
    host = net["host"](net["listen"])
    a = net["loop"].run(host.start(Recorder("rec1")))
    wait_until(lambda: a.steps >= 3, 5, "three steps")
    wait_until(lambda: "agents/rec1" in alive_agents(net["connect"]), 5, "the token seen by the other peer")
    net["loop"].run(host.kill(a))
    assert a.events == ["created", "step", "killed"]
    assert a.state == "killed" and "rec1" not in host.agents
    wait_until(lambda: "agents/rec1" not in alive_agents(net["connect"]), 5, "the token withdrawn")


def test_failing_step_kills_only_that_agent(net, caplog):
    host = net["host"](net["listen"])
    bad = net["loop"].run(host.start(Recorder("bad", fail_at=2)))
    good = net["loop"].run(host.start(Recorder("good")))
    with caplog.at_level(logging.ERROR, logger="agents.runtime"):
        net["loop"].run(host.wait_killed(bad, 5))
    assert bad.events == ["created", "step", "killed"]
    assert isinstance(bad.error, RuntimeError)
    assert any("bad" in r.getMessage() and r.exc_info for r in caplog.records)
    n = good.steps
    wait_until(lambda: good.steps > n + 2, 5, "the other agent to keep stepping")
    assert good.state == "running"
    wait_until(lambda: alive_agents(net["connect"]) == {"agents/good"}, 5, "only the good agent's token")
    # the host still starts agents
    late = net["loop"].run(host.start(Recorder("late")))
    wait_until(lambda: late.steps >= 1, 5, "a new agent to step")


def test_agent_kills_itself_from_step(net):
    class Once(Recorder):
        async def step(self):
            await super().step()
            self.kill()

    host = net["host"](net["listen"])
    a = net["loop"].run(host.start(Once("once")))
    net["loop"].run(host.wait_killed(a, 5))
    assert a.events == ["created", "step", "killed"] and a.steps == 1


def test_hundred_agents_one_host_then_stop(net):
    host = net["host"](net["connect"])
    agents = [Recorder(f"a{i:03d}") for i in range(100)]

    async def start_all():
        for a in agents:
            await host.start(a)

    net["loop"].run(start_all())
    want = {f"agents/a{i:03d}" for i in range(100)}
    wait_until(lambda: alive_agents(net["listen"]) >= want, 10, "100 tokens")
    wait_until(lambda: all(a.steps >= 2 for a in agents), 10, "every agent stepping")
    net["loop"].run(host.stop())
    assert all(a.events[-1] == "killed" and a.state == "killed" for a in agents)
    wait_until(lambda: not (alive_agents(net["listen"]) & want), 10, "every token withdrawn")


# ---------------------------------------------------------------------------- services
class Follower(Agent):
    """Receives send_position of robot r1 only."""

    def __init__(self, agent_id: str):
        super().__init__(agent_id, period=0.05)
        self.got: list[Message] = []

    async def created(self):
        self.subscribe("send_position", self.got.append, filter=match(robot="r1"))


class Reporter(Agent):
    """Publishes the pose of r0 and r1 every step."""

    def __init__(self, agent_id: str):
        super().__init__(agent_id, period=0.02, robot="r1", capabilities=("send_position",))
        self.n = 0

    async def step(self):
        self.n += 1
        self.publish("send_position", SendPosition("r0", 0.0, 0.0, 0.0))
        self.publish("send_position", SendPosition("r1", float(self.n), 2.0, 0.5, "map"))


def test_send_position_across_hosts_with_filter(net):
    h1 = net["host"](net["listen"])
    h2 = net["host"](net["connect"])
    b = net["loop"].run(h2.start(Follower("follow")))
    a = net["loop"].run(h1.start(Reporter("reporter")))
    wait_until(lambda: len(b.got) >= 5, 10, "five positions of r1")
    assert a.n >= 5
    for m in b.got:
        assert m.service == "send_position" and m.sender == "reporter" and m.conversation
        assert isinstance(m.body, SendPosition) and m.body.robot == "r1"
        assert (m.body.y, m.body.yaw, m.body.frame) == (2.0, 0.5, "map")
        assert m.time > 1.6e9


def test_malformed_payloads_dropped_host_keeps_working(net, caplog):
    h2 = net["host"](net["connect"])
    b = net["loop"].run(h2.start(Follower("follow")))
    raw = net["listen"]
    wait_until(lambda: "agents/follow" in alive_agents(raw), 5, "the follower's token")
    bad = [
        b"\xc1\xc1 not msgpack",
        msgpack.packb([1, 2, 3]),
        msgpack.packb({"sender": "x", "conversation": "c", "time": 1.0, "robot": "r1", "x": 0, "y": 0}),  # no yaw
        msgpack.packb({"sender": "x", "conversation": "c", "time": 1.0, "robot": "r1", "x": "a", "y": 0, "yaw": 0}),
        msgpack.packb(
            {"sender": "x", "conversation": "c", "time": 1.0, "robot": "r1", "x": float("nan"), "y": 0, "yaw": 0}
        ),
        encode_message("other", SendPosition("r1", 0, 0, 0), "c", 1.0),  # sender differs from the key
    ]
    with caplog.at_level(logging.WARNING, logger="agents.services"):
        for p in bad:
            raw.put("svc/send_position/x", p)
        wait_until(lambda: h2.services.dropped >= len(bad), 5, "every malformed message dropped")
        raw.put("svc/send_position/x", encode_message("x", SendPosition("r1", 1.0, 2.0, 3.0), "c9", 2.0))
        wait_until(lambda: len(b.got) == 1, 5, "the valid message after the malformed ones")
    assert b.got[0].body == SendPosition("r1", 1.0, 2.0, 3.0) and b.got[0].conversation == "c9"
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING and "malformed" in r.getMessage()]
    assert 1 <= len(warnings) < len(bad)  # logged, rate-limited per key
    assert b.state == "running"


def test_hello_answered_by_all(net):
    h1 = net["host"](net["listen"])
    h2 = net["host"](net["connect"])
    lt = net["loop"]
    lt.run(h1.start(Reporter("reporter")))
    for i in range(3):
        lt.run(h2.start(Recorder(f"nav{i}", robot=f"r{i}", capabilities=("new_goal",))))
    want = ["nav0", "nav1", "nav2", "reporter"]
    answers = wait_until(
        lambda: (x := lt.run(h1.who_is_there(1.0))) and [h.id for h in x] == want and x,
        10,
        "hello from all four agents",
    )
    assert answers[-1] == Hello("reporter", "Reporter", "r1", ("send_position",))
    assert answers[0] == Hello("nav0", "Recorder", "r0", ("new_goal",))
    from_other = lt.run(h2.who_is_there(1.0))
    assert [h.id for h in from_other] == want
    lt.run(h2.kill("nav1"))
    wait_until(
        lambda: [h.id for h in lt.run(h1.who_is_there(1.0))] == ["nav0", "nav2", "reporter"],
        10,
        "a killed agent no longer answering hello",
    )


def test_new_goal_to_one_agent_and_async_callback(net):
    got: list[NewGoal] = []

    class Nav(Agent):
        async def created(self):
            self.subscribe("new_goal", self.on_goal, filter=match(to=self.id))

        async def on_goal(self, msg: Message):
            await asyncio.sleep(0)
            got.append((self.id, msg.body))

    h1 = net["host"](net["listen"])
    h2 = net["host"](net["connect"])
    lt = net["loop"]
    for i in range(2):
        lt.run(h2.start(Nav(f"nav{i}")))
    boss = lt.run(h1.start(Agent("dispersion")))
    wait_until(lambda: len(alive_agents(net["listen"])) == 3, 5, "three tokens")
    wait_until(lambda: len(lt.run(h1.who_is_there(0.5))) == 3, 5, "hello from three agents")

    async def send():  # repeated until delivered: the peers' subscriptions may still be propagating
        boss.publish("new_goal", NewGoal("nav1", 3.0, -1.0, 1.5))
        return bool(got)

    wait_until(lambda: lt.run(send()), 5, "the goal delivered")
    assert set(got) == {("nav1", NewGoal("nav1", 3.0, -1.0, 1.5))}


# ---------------------------------------------------------------------------- codec units
def test_codec_roundtrip_and_validation():
    data = encode_message("a1", Hello("a1", "Nav", "r0", ("x",)), "conv", 5.0)
    m = decode_message("hello", "a1", data)
    assert m == Message("hello", "a1", "conv", 5.0, Hello("a1", "Nav", "r0", ("x",)))
    unknown = decode_message("chat", "a1", encode_message("a1", {"text": "hi"}, "c", 1.0))
    assert unknown.body == {"text": "hi"}
    with pytest.raises(MessageError, match="capabilities"):
        decode_message("hello", "a1", encode_message("a1", {"id": "a1", "cls": "A", "capabilities": [1]}, "c", 1.0))
    with pytest.raises(MessageError, match="conversation"):
        decode_message("hello", "a1", msgpack.packb({"sender": "a1", "time": 1.0}))
    with pytest.raises(ValueError, match="envelope"):
        encode_message("a1", {"sender": "b"}, "c", 1.0)
    with pytest.raises(ValueError, match="key chunk"):
        Agent("bad/id")
    assert match(robot={"r1", "r2"})(Message("send_position", "s", "c", 1.0, SendPosition("r2", 0, 0, 0)))
    assert not match(sender="t")(Message("send_position", "s", "c", 1.0, SendPosition("r2", 0, 0, 0)))


def test_calls_from_other_threads_run_on_the_loop_in_order_in_batches(net, caplog):
    host = net["host"](net["listen"])
    lt = net["loop"]
    ran: list[tuple[int, int, bool]] = []
    wakeups = 0
    real = host.services._run_soon

    def counting_run_soon():
        nonlocal wakeups
        wakeups += 1
        real()

    host.services._run_soon = counting_run_soon

    def call(thread: int, i: int) -> None:
        ran.append((thread, i, lt.loop.is_running() and asyncio.get_running_loop() is lt.loop))
        if (thread, i) == (0, 10):
            raise RuntimeError("a failing call on purpose")

    gate = threading.Event()
    blocked = threading.Event()

    def block():  # holds the loop while the threads queue their calls
        blocked.set()
        gate.wait(5)

    lt.loop.call_soon_threadsafe(block)
    assert blocked.wait(5)
    workers = [
        threading.Thread(target=lambda t=t: [host.services.call_soon(call, t, i) for i in range(500)]) for t in range(2)
    ]
    with caplog.at_level(logging.ERROR, logger="agents.services"):
        for w in workers:
            w.start()
        for w in workers:
            w.join()
        gate.set()
        wait_until(lambda: len(ran) == 1000, 5, "every call run")
    assert all(on_loop for _, _, on_loop in ran)  # on the host's loop, not the calling thread
    for t in range(2):
        assert [i for th, i, _ in ran if th == t] == list(range(500))  # each thread's calls in order
    assert wakeups < 10  # one wake-up for the calls queued while the loop was busy, not one each
    assert any("failed" in r.getMessage() and r.exc_info for r in caplog.records)  # logged, the rest ran
