"""The per-host robot hub (agents/hub.py) over real Zenoh sessions on loopback: one hub per host,
one ``send_position`` subscription feeding the shared board and each listener once per message,
one control loop running the robots' cycles, closed by the last agent to detach."""

from __future__ import annotations

import pytest

from agents.hub import RobotHub
from agents.runtime import Agent, AgentHost
from agents.services import SendPosition
from rsal.transport import TransportArgs, open_session
from tests.conftest import LoopThread, free_port, wait_until


@pytest.fixture
def net():
    """A host on a listening session and a host on a connecting one (free loopback port)."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    a = open_session(TransportArgs(listen=[ep]))
    b = open_session(TransportArgs(connect=[ep]))
    lt = LoopThread()
    hosts = [AgentHost(a), AgentHost(b)]
    for h in hosts:
        lt.run(h.__aenter__())
    yield lt, hosts[0], hosts[1]
    for h in hosts:
        lt.run(h.stop())
    lt.close()
    b.close()
    a.close()


class Member(Agent):
    """Joins its host's hub in created() and leaves it in killed()."""

    def __init__(self, agent_id: str, listener=None):
        super().__init__(agent_id, period=0.05)
        self.listener = listener
        self.hub: RobotHub | None = None

    async def created(self) -> None:
        self.hub = RobotHub.attach(self._require_host(), self, period=0.02, board_timeout=7.0)
        self.hub.listen(self.listener)

    async def killed(self) -> None:
        self.hub.detach(self)


class CountingRobot:
    """What the control loop needs of a robot: ``name``, ``update()``, ``updates``."""

    def __init__(self, name: str):
        self.name = name
        self.updates = 0
        self.calls = 0

    def update(self) -> None:
        self.calls += 1
        if self.calls == 2:
            raise RuntimeError("a failing cycle is logged, not fatal")


def test_one_hub_per_host_fans_each_message_out_once(net):
    lt, host, other = net
    heard = []

    def listener(hub, msg, now):
        heard.append((hub, msg.sender, msg.body.robot, now >= msg.time - 1.0))

    a, b = Member("a", listener), Member("b", listener)  # the same listener twice: called once
    lt.run(host.start(a))
    lt.run(host.start(b))
    assert a.hub is b.hub and set(a.hub.agents) == {"a", "b"}
    assert a.hub.board_timeout == 7.0
    talker = Agent("talker")
    lt.run(other.start(talker))
    sent = 0

    def arrived() -> bool:
        nonlocal sent
        if not heard:  # the subscription may still be on its way: publish again until one arrives
            talker.publish(SendPosition.SERVICE, SendPosition("r9", 1.0, 2.0, 0.5, "map"))
            sent += 1
        return bool(heard)

    wait_until(arrived, 10.0, "a send_position message reaches the hub")
    wait_until(lambda: len(heard) >= sent, 5.0, "every message sent reaches the listener")
    assert len(heard) == sent  # once per message, not once per agent
    assert heard[0] == (a.hub, "talker", "r9", True)
    pose = a.hub.board.get("r9").position
    assert (pose.x, pose.y, pose.yaw) == (1.0, 2.0, 0.5)


def test_the_control_loop_runs_each_robot_until_removed_and_the_last_detach_closes(net):
    lt, host, _ = net
    a, b = Member("a"), Member("b")
    lt.run(host.start(a))
    lt.run(host.start(b))
    hub = a.hub
    r1, r2 = CountingRobot("r1"), CountingRobot("r2")
    hub.add_robot("r1", r1)
    hub.add_robot("r2", r2)
    wait_until(lambda: r1.updates >= 5 and r2.updates >= 5, 10.0, "both robots cycle in the shared loop")
    assert r1.calls == r1.updates + 1  # the failing cycle did not stop the loop
    assert hub.remove_robot("r1") is r1 and hub.remove_robot("r1") is None
    n = r1.calls
    wait_until(lambda: r2.updates >= n + 5, 10.0, "the other robot keeps cycling")
    assert r1.calls == n
    assert hub.cycles > 0 and 0.0 <= hub.load() < 1.0
    lt.run(host.kill(a.id))
    assert RobotHub._hubs.get(id(host)) is hub  # b still uses it
    lt.run(host.kill(b.id))
    assert id(host) not in RobotHub._hubs
    wait_until(lambda: hub._task.done(), 5.0, "the control loop ends with the hub")


def test_a_batch_step_runs_the_robots_it_takes_and_the_others_run_their_own_cycle(net):
    lt, host, _ = net
    a = Member("a")
    lt.run(host.start(a))
    hub = a.hub
    taken, own = CountingRobot("taken"), CountingRobot("own")
    own.calls = 5  # no failing cycle here
    batches: list[list[str]] = []

    def batch(robots):
        batches.append([r.name for r in robots])
        return [r for r in robots if r is not taken]

    hub.batch = batch
    hub.add_robot("taken", taken)
    hub.add_robot("own", own)
    wait_until(lambda: taken.updates >= 5 and own.updates >= 5, 10.0, "both robots cycle")
    assert taken.calls == 0  # its cycle was the batch's
    assert own.calls - 5 == own.updates  # its own update() every cycle
    assert all(set(b) <= {"taken", "own"} for b in batches) and ["taken", "own"] in batches

    def broken(robots):
        raise RuntimeError("a failing batch is logged; the robots run their own cycles from then on")

    hub.batch = broken
    n = taken.calls
    wait_until(lambda: taken.calls >= n + 3, 10.0, "the robot the batch took runs its own cycle")
    assert hub.batch is None
    lt.run(host.kill(a.id))


class MovingRobot(CountingRobot):
    """A robot whose pose the test sets (``position2d.latest.pose``), as the hub reads it."""

    def __init__(self, name: str, x: float, y: float):
        super().__init__(name)
        self.calls = 5  # no failing cycle here
        self.position2d = type("P", (), {})()
        self.move(x, y)

    def move(self, x: float, y: float) -> None:
        self.position2d.latest = type("M", (), {"pose": (x, y, 0.0)})()


class NearMember(Member):
    def __init__(self, agent_id: str, robot: str, listener=None, wildcard_above: int = 64):
        super().__init__(agent_id, listener)
        self.robot = robot
        self.wildcard_above = wildcard_above

    async def created(self) -> None:
        self.hub = RobotHub.attach(self._require_host(), self, period=0.02)
        self.hub.listen_near(2.0, 2.0, 0.5, 0.05, self.listener, wildcard_above=self.wildcard_above)


@pytest.mark.parametrize("wildcard_above", [64, 4], ids=["a subscriber per cell", "one wildcard subscriber"])
def test_neighbourhood_cells_follow_the_robots_and_reach_only_their_receivers(net, wildcard_above):
    from agents.cells import cell_of, cells_near

    lt, host, other = net
    heard = []
    a = NearMember("a", "ra", lambda hub, msg, now: heard.append(msg), wildcard_above)
    b = NearMember("b", "rb", wildcard_above=wildcard_above)
    lt.run(host.start(a))
    lt.run(host.start(b))
    hub = a.hub
    ra, rb = MovingRobot("ra", 0.5, 0.5), MovingRobot("rb", 20.5, 0.5)
    lt.run(_call(hub.add_robot, "ra", ra))  # watched at once
    lt.run(_call(hub.add_robot, "rb", rb))
    assert hub.agent_cells["a"] == frozenset(cells_near(0.5, 0.5, 2.5, 2.0))
    assert hub._cells.cells == set(cells_near(0.5, 0.5, 2.5, 2.0)) | set(cells_near(20.5, 0.5, 2.5, 2.0))
    # 18 cells: one per cell under the default threshold, one on every cell above 4
    assert hub._cells.subscribers == (1 if wildcard_above < 18 else 18) and hub._cells.wildcard == (wildcard_above < 18)
    talker = Agent("talker")
    lt.run(other.start(talker))

    def say(x: float) -> None:
        talker.publish(SendPosition.SERVICE, SendPosition("rt", x, 0.5, 0.0, "map"), cell=cell_of(x, 0.5, 2.0))

    def arrived(x: float):
        def check() -> bool:
            if not any(m.body.x == x for m in heard):
                say(x)
            return any(m.body.x == x for m in heard)

        return check

    wait_until(arrived(1.5), 10.0, "a message near ra reaches the hub")
    near_a = [m for m in heard if m.body.x == 1.5][0]
    assert hub.receivers(near_a) == [a]
    assert hub.near(0.5, 0.5, 2.0).tolist() == [[1.5, 0.5]] and len(hub.near(0.5, 0.5, 2.0, exclude="rt")) == 0
    # a message far from both robots is not even delivered to the host: sent before the ones below
    # from the same publisher, it would have arrived first
    for _ in range(5):
        say(11.5)
    rb.move(10.5, 0.5)  # rb drives there: within a re-watch period its cells follow
    wait_until(lambda: "c5_0" in hub.agent_cells["b"], 5.0, "b's cells follow its robot")
    wait_until(arrived(10.5), 10.0, "a message near rb's new place reaches the hub")
    assert not any(m.body.x == 11.5 for m in heard)
    assert hub.receivers([m for m in heard if m.body.x == 10.5][0]) == [b]
    with pytest.raises(ValueError, match="same neighbourhood"):
        hub.listen_near(3.0, 2.0, 0.5, 0.05)
    with pytest.raises(ValueError, match="neighbourhood"):
        hub.listen()


async def _call(fn, *args):
    return fn(*args)


def test_an_agents_reception_begins_when_its_robots_cells_are_first_watched(net):
    import time

    lt, host, _other = net
    a = NearMember("a", "ra")
    lt.run(host.start(a))
    hub = a.hub
    ra = MovingRobot("ra", 0.5, 0.5)
    ra.position2d.latest = None  # its pose not known yet: no cell of its can be watched
    lt.run(_call(hub.add_robot, "ra", ra))
    assert "a" not in hub.agent_cells and "a" not in hub.watched_since
    before = time.time()
    ra.move(0.5, 0.5)  # the pose arrives: the next re-watch places it
    wait_until(lambda: "a" in hub.watched_since, 5.0, "a's cells watched once its robot has a pose")
    assert hub.watched_since["a"] >= before
    assert hub.agent_cells["a"] and hub.agent_cells["a"] <= frozenset(hub._cells.cells)
