"""Cell broadcasts' publishers and cell subscriptions (agents/services.py, agents/cellsub.py).

(a) The publisher cache, over real Zenoh sessions: a sender crossing a cell border publishes
through one declared publisher per cell it is in, the old one undeclared when it moves on, and a
subscriber of each cell receives exactly the messages sent from that cell; an agent's publishers
are undeclared when it ends.
(b) The wildcard switch, over real Zenoh sessions: a receiver watching more cells than its
threshold holds one subscriber, receives every message of its cells and none of the others; while
senders publish without pause the receiver switches to the wildcard and back, and every message of
the cells watched throughout arrives exactly once. (c) A message received twice in a switch's
overlap reaches the callback once. (d) A subscriber asked for arrival times gets the time a sample
reached the session, not the later time a busy loop served it (the swarm judge's send times).
(e) With loopback, a host's own broadcasts reach its cell subscription once, in process, and only
from watched cells; the other host's still arrive through Zenoh.
"""

from __future__ import annotations

import threading
import time
from collections import Counter

import pytest

from agents.cells import cell_of
from agents.cellsub import DEFAULT_WILDCARD_ABOVE, CellSubscription
from agents.runtime import Agent, AgentHost
from agents.services import Message, SendPosition, Subscription
from rsal.testing import FakeSession
from tests.conftest import LoopThread, wait_until


class Log:
    """What one cell subscription received: (sender, sequence number, x)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.got: list[tuple[str, int, float]] = []

    def __call__(self, msg: Message) -> None:
        with self.lock:
            self.got.append((msg.sender, int(msg.conversation), msg.body.x))

    def keys(self) -> list[tuple[str, int]]:
        with self.lock:
            return [(s, k) for s, k, _x in self.got]


def _subscribe(lt, host: AgentHost, cells: set[str], log: Log, **kw) -> CellSubscription:
    async def go():
        sub = host.services.subscribe_cells("send_position", log, owner="test", **kw)
        sub.watch(cells)
        return sub

    return lt.run(go())


def _pos(name: str, x: float, y: float = 0.5) -> SendPosition:
    return SendPosition(name, float(x), float(y), 0.0)


def _until_heard(svc, log: Log, sender: str, x: float, cell: str) -> None:
    """Publish a probe (sequence -1) until the receiver's subscriber reached the sending session."""

    def heard() -> bool:
        svc.publish("send_position", _pos(sender, x), sender=sender, conversation="-1", cell=cell)
        return (sender, -1) in log.keys()

    wait_until(heard, 10, f"the subscriber of {cell} at the sending host", interval=0.05)


def test_a_sender_crossing_a_cell_border_publishes_through_one_publisher_per_cell(hosts):
    lt, recv_host, send_host = hosts
    size = 3.0
    west, east = Log(), Log()
    _subscribe(lt, recv_host, {"c0_0"}, west)
    _subscribe(lt, recv_host, {"c1_0"}, east)
    svc = send_host.services
    _until_heard(svc, west, "probe", 1.0, "c0_0")
    _until_heard(svc, east, "probe", 4.0, "c1_0")
    declared = svc.publishers_declared
    sent: dict[str, list[int]] = {"c0_0": [], "c1_0": []}
    held = []
    x = 0.05
    for seq in range(60):  # west to east across the border at x = 3
        cell = cell_of(x, 0.5, size)
        svc.publish("send_position", _pos("walker", x), sender="walker", conversation=str(seq), cell=cell)
        sent[cell].append(seq)
        assert svc.publishers("walker") == {("send_position", "walker"): f"svc/send_position/{cell}/walker"}
        pub = svc._pubs[("send_position", "walker")][1]
        if not held or held[-1] is not pub:
            held.append(pub)
        x += 0.1
    assert sent["c0_0"] and sent["c1_0"]
    # one publisher per cell visited; the first was undeclared when the walker left its cell
    assert svc.publishers_declared - declared == 2 and len(held) == 2
    with pytest.raises(Exception):  # noqa: B017 -- zenoh raises its own error on an undeclared publisher
        held[0].put(b"")

    def only(log: Log) -> list[int]:
        return sorted(k for s, k in log.keys() if s == "walker")

    wait_until(lambda: only(west) == sent["c0_0"] and only(east) == sent["c1_0"], 10, "each cell's messages")
    time.sleep(0.2)  # nothing else arrives late
    assert only(west) == sent["c0_0"] and only(east) == sent["c1_0"]
    assert all(x < 3.0 for s, _k, x in west.got if s == "walker")
    assert all(x >= 3.0 for s, _k, x in east.got if s == "walker")


def test_an_agents_cell_publishers_are_undeclared_when_it_ends(hosts):
    lt, _recv_host, send_host = hosts
    talker = lt.run(send_host.start(Agent("talker")))

    async def say():
        talker.publish("send_position", _pos("talker", 1.0), cell="c0_0")

    lt.run(say())
    svc = send_host.services
    assert svc.publishers("talker") == {("send_position", "talker"): "svc/send_position/c0_0/talker"}
    pub = svc._pubs[("send_position", "talker")][1]
    lt.run(send_host.kill(talker))
    assert svc.publishers("talker") == {}
    with pytest.raises(Exception):  # noqa: B017
        pub.put(b"")


def test_many_cells_share_one_wildcard_subscriber_and_switches_lose_and_double_nothing(hosts):
    lt, recv_host, send_host = hosts
    log = Log()
    kept = {f"c{i}_0" for i in range(3)}  # watched throughout
    extra = {f"c{i}_0" for i in range(3, 6)}  # watched only while the wildcard stands
    never = {f"c{i}_0" for i in range(6, 10)}
    sub = _subscribe(lt, recv_host, kept, log, wildcard_above=4)
    assert sub.subscribers == 3 and not sub.wildcard
    svc = send_host.services
    for c in sorted(kept):
        _until_heard(svc, log, f"p{c}", 1.0, c)
    # one sender per cell publishes without pause while the receiver switches
    senders = {c: f"s{c}" for c in sorted(kept | extra | never)}
    sent: dict[str, list[tuple[int, float]]] = {c: [] for c in senders}  # (seq, monotonic time sent)
    stop = threading.Event()

    def publish() -> None:
        seq = 0
        while not stop.is_set():
            for c, name in senders.items():
                t0 = time.monotonic()
                svc.publish("send_position", _pos(name, 1.0), sender=name, conversation=str(seq), cell=c)
                sent[c].append((seq, t0))
            seq += 1
            time.sleep(0.002)

    t = threading.Thread(target=publish, daemon=True)
    t.start()

    async def watch(cells):
        sub.watch(cells)
        return sub.subscribers, sub.wildcard

    try:
        time.sleep(0.3)
        assert lt.run(watch(kept | extra)) == (1, True)  # 6 cells > 4: one wildcard subscriber
        wait_until(lambda: any(s == senders["c4_0"] for s, _k in log.keys()), 10, "a message of a cell added")
        time.sleep(0.3)
        assert lt.run(watch(kept | {"c3_0", "c4_0", "c5_0"} - {"c5_0"})) == (1, True)  # 5: still above
        time.sleep(0.2)
        assert lt.run(watch(kept)) == (3, False)  # 3 <= 4 * 3 // 4: a subscriber per cell again
        back = time.monotonic()
        time.sleep(0.3)
    finally:
        stop.set()
        t.join(5)
    assert sub.switches == 2
    wait_until(lambda: sub.retiring == 0, 5, "the old subscribers undeclared after the grace period")

    def of(cell: str) -> list[int]:
        return [k for s, k in log.keys() if s == senders[cell]]

    for c in sorted(kept):  # every message of the cells watched throughout, exactly once
        want = [k for k, _t in sent[c]]
        deadline = time.monotonic() + 10
        while len(of(c)) < len(want) and time.monotonic() < deadline:
            time.sleep(0.05)
        missing = sorted(set(want) - set(of(c)))
        assert sorted(of(c)) == want, (c, len(want), len(of(c)), missing[:10], sub.duplicates)
    got = Counter(k for k in log.keys() if k[1] >= 0)  # not the probes, repeated until heard
    assert max(got.values()) == 1, [k for k, n in got.items() if n > 1][:5]
    assert all(of(c) for c in extra)  # the added cells were heard while watched
    assert not any(of(c) for c in never)  # cells never watched: nothing, whichever subscriber
    for c in sorted(extra):  # nothing of a cell put after it stopped being watched
        late = {k for k, t in sent[c] if t > back}
        assert late and not (late & set(of(c))), c
    assert sub.received == len(log.keys())


def test_a_message_received_twice_in_a_switchs_overlap_reaches_the_callback_once():
    lt = LoopThread()
    host = AgentHost(FakeSession())
    try:
        lt.run(host.__aenter__())
        got: list[Message] = []

        async def go():
            sub = host.services.subscribe_cells("send_position", got.append)
            assert sub.wildcard_above == DEFAULT_WILDCARD_ABOVE == 64
            sub.wildcard_above, sub.overlap = 2, 30.0
            sub.watch({"c0_0", "c1_0", "c2_0"})  # a switch: declared before the old go
            msg = Message("send_position", "a", "7", 1.5, _pos("a", 1.0))
            sub._on_message(msg)
            sub._on_message(msg)  # through the other subscriber in the overlap
            sub._on_message(Message("send_position", "a", "8", 1.6, _pos("a", 1.0)))
            return sub

        sub = lt.run(go())
        assert [m.conversation for m in got] == ["7", "8"] and sub.duplicates == 1 and sub.received == 2
    finally:
        lt.run(host.stop())
        lt.close()


def test_an_arrival_time_is_when_the_sample_reached_the_session_not_when_the_busy_loop_served_it(hosts):
    lt, recv_host, send_host = hosts
    got: list[tuple[int, float, float]] = []  # (sequence number, arrival, served)
    lock = threading.Lock()

    def on(msg: Message, arrived: float) -> None:  # the receiving host's loop
        with lock:
            got.append((int(msg.conversation), arrived, time.time()))

    async def sub():
        return Subscription(
            recv_host.services, "send_position", on, None, "judge", keyexpr="svc/send_position/*/*", arrival=True
        )

    lt.run(sub())
    busy = threading.Event()  # set while the receiving loop is held
    quick: list[tuple[int, bool, bool]] = []  # (seq, the loop busy then, on the loop's thread)

    def on_thread(msg: Message, arrived: float) -> None:  # Zenoh's thread
        quick.append((int(msg.conversation), busy.is_set(), threading.current_thread() is lt.t))

    async def sub_on_thread():
        return Subscription(
            recv_host.services,
            "send_position",
            on_thread,
            None,
            "quick",
            keyexpr="svc/send_position/*/*",
            arrival=True,
            on_thread=True,
        )

    lt.run(sub_on_thread())
    svc = send_host.services

    def heard() -> bool:
        svc.publish("send_position", _pos("probe", 1.0), sender="probe", conversation="-1", cell="c0_0")
        with lock:
            return any(k == -1 for k, _a, _s in got)

    wait_until(heard, 10, "the judge's subscriber at the sending host", interval=0.05)
    blocked = threading.Event()

    def block() -> None:  # the loop busy for a second, as when a host starts a crowd
        busy.set()
        blocked.set()
        time.sleep(1.0)
        busy.clear()

    lt.loop.call_soon_threadsafe(block)
    assert blocked.wait(5)
    sent_at = time.time()
    svc.publish("send_position", _pos("walker", 1.0), sender="walker", conversation="7", cell="c0_0")
    wait_until(lambda: any(k == 7 for k, _a, _s in got), 10, "the broadcast served")
    (arrived, served) = next((a, s) for k, a, s in got if k == 7)
    assert sent_at <= arrived < sent_at + 0.5  # taken on Zenoh's thread, at once
    assert served - arrived >= 0.5  # the loop served it only after its busy second
    assert (7, True, False) in quick  # on_thread: served at once, off the busy loop


def test_a_hosts_own_broadcasts_reach_its_loopback_subscription_once_in_process(hosts):
    lt, recv_host, send_host = hosts
    log = Log()
    sub = _subscribe(lt, recv_host, {"c0_0"}, log, loopback=True)
    me = lt.run(recv_host.start(Agent("me")))
    _until_heard(send_host.services, log, "other", 1.0, "c0_0")  # the other host reaches it by Zenoh

    async def say(seq: int, x: float, cell: str):
        me.publish("send_position", _pos("me", x), conversation=str(seq), cell=cell)

    for seq in range(20):
        lt.run(say(seq, 1.0, "c0_0"))
    lt.run(say(99, 4.0, "c1_0"))  # a cell the subscription does not watch
    for seq in range(5):
        other = _pos("other", 1.0)
        send_host.services.publish("send_position", other, sender="other", conversation=str(seq), cell="c0_0")
    wait_until(lambda: sum(1 for s, k in log.keys() if s == "other" and k >= 0) == 5, 10, "the other host's five")
    time.sleep(0.3)  # any Zenoh copy of the host's own would have arrived by now
    mine = [k for s, k in log.keys() if s == "me"]
    assert mine == list(range(20))  # each once, in order, none from the unwatched cell
    assert sub.local_received == 20
    assert "me" in recv_host.services.local_senders
    # nor did their Zenoh copies reach its subscriber's callback: that takes other sessions' only
    assert sum(z.skipped for z in sub._subs.values()) == 0
    lt.run(_call(sub.close))
    assert recv_host.services._loopback.get("send_position") == []


async def _call(fn, *args):
    return fn(*args)
