"""The device server (mrs_bridge/server/) in this process on loopback Zenoh, with small drivers
defined here: tokens, describe, rpc errors, malformed commands, failure isolation, ``requires``."""

from __future__ import annotations

import logging
import math
import time

import msgpack
import numpy as np
import pytest
from bridge_helpers import LiveServer

from mrs_bridge.driver import Driver, OutOfRange
from mrs_bridge.drivers.rangertolaser import RangerToLaser
from mrs_bridge.drivers.replay import ReplayDriver
from mrs_bridge.server import ServerError
from rsal import keys
from rsal.keys import DeviceAddr, parse_device
from rsal.msgs import ErrorCode, RangerData, RpcError, VelocityCmd, encode, get_float, parse_reply
from tests.conftest import ROOT, free_port, wait_until


class Counter(Driver):
    """Publishes ``{"n": k}`` on every provided device; takes VelocityCmd; ``rpc/scale`` doubles ``k``."""

    driver_name = "counter"
    default_rate = 50.0
    data_types = {"dio": "Count"}
    cmd_types = {"dio": "VelocityCmd"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        self.n = 0
        self.cmd: VelocityCmd | None = None
        self.shut = False

    def update(self, now):
        self.n += 1
        for a in self.cfg.provides:
            self.publish(a, {"n": self.n})

    def on_cmd(self, addr, msg):
        self.cmd = VelocityCmd.from_dict(msg)

    def ops(self, addr):
        return ["scale", "crash"]

    def on_rpc(self, addr, op, args):
        if op == "crash":
            raise ZeroDivisionError("division by zero")
        k = get_float(args, "k")
        if k > 10:
            raise OutOfRange(f"k = {k:g} is over 10")
        return {"result": 2 * k}

    def geometry(self, addr):
        return {"pose": [0.1, 0.0, 0.0], "label": self.cfg.param("label", "")}

    def shutdown(self):
        self.shut = True


class Flaky(Counter):
    """A Counter whose update() raises once the test sets ``server.shared["boom"]``; takes no commands."""

    driver_name = "flaky"
    cmd_types = {}

    def update(self, now):
        if self.server.shared.get("boom"):
            raise RuntimeError("sensor unplugged")
        super().update(now)

    def on_cmd(self, addr, msg):
        return Driver.on_cmd(self, addr, msg)


DRIVERS = {"counter": Counter, "flaky": Flaky, "replay": ReplayDriver, "rangertolaser": RangerToLaser}


@pytest.fixture
def servers():
    made: list[LiveServer] = []

    def make(text: str, *, port: int | None = None, **kw) -> LiveServer:
        s = LiveServer(text, port=port or free_port(), **{"drivers": DRIVERS, **kw})
        made.append(s)
        return s

    yield make
    for s in reversed(made):
        s.close()


@pytest.fixture
def caplog_bridge(caplog):
    caplog.set_level(logging.INFO, logger="mrs_bridge")
    return caplog


TWO_COUNTERS = """
[server]
node = "r0"

[[driver]]
name = "counter"
provides = ["dio:0", "dio:1"]
label = "front"

[[driver]]
name = "counter"
node = "r1"
provides = ["dio:0"]
rate = 20
"""


def raw_rpc(session, addr: DeviceAddr, op: str, payload: bytes) -> dict:
    key = keys.rpc_key(addr, op)
    for r in session.get(key, payload=payload, timeout=5.0):
        if r.ok is not None:
            return parse_reply(r.ok.payload.to_bytes(), key=key)
        return parse_reply(r.err.payload.to_bytes(), is_error=True, key=key)
    raise RpcError(ErrorCode.TIMEOUT, "no reply", key)


# ---------------------------------------------------------------------------- tokens and describe
def test_a_token_per_device_and_withdrawn_on_close(servers, port, fabric_factory):
    srv = servers(TWO_COUNTERS, port=port).start()
    fab = fabric_factory(port)
    node = fab.node("**")
    expected = {parse_device(t) for t in ("r0:dio:0", "r0:dio:1", "r1:dio:0")}
    node.wait_for("**", count=3, timeout=10)
    assert set(node.devices()) == expected
    assert set(srv.server.devices) == expected
    srv.close()
    for a in expected:
        node.wait_gone(a, timeout=5)


def test_describe_says_what_the_device_is(servers, port, fabric_factory):
    servers(TWO_COUNTERS, port=port).start()
    fab = fabric_factory(port)
    fab.node("**").wait_for("**", count=3, timeout=10)
    d = fab.device("r0:dio:1").describe()
    assert (d.node, d.interface, d.index, d.driver) == ("r0", "dio", 1, "counter")
    assert d.rate == 50.0
    assert d.geometry == {"pose": [0.1, 0.0, 0.0], "label": "front"}
    assert d.ops == ["describe", "scale", "crash"]
    assert (d.cmd, d.data, d.protocol) == ("VelocityCmd", "Count", 1)
    assert fab.device("r1:dio:0").describe().rate == 20.0  # the block's own rate


def test_running_drivers_keep_publishing(servers, port, fabric_factory):
    servers(TWO_COUNTERS, port=port).start()
    fab = fabric_factory(port)
    fab.node("**").wait_for("**", count=3, timeout=10)
    dev = fab.device("r0:dio:0")
    first = dev.wait_for_data(5)["n"]
    later = dev.wait_for_data(5, newer_than=dev.count + 4)["n"]
    assert later >= first + 5


class SlowStart(Counter):
    """A Counter whose first update() takes ``server.shared["first_step"]`` seconds (a kernel being
    compiled) and which is not ready until ``server.shared["ready"]`` is set (a map still to come)."""

    driver_name = "slowstart"

    def update(self, now):
        if self.n == 0:
            self.server.shared["first_began"] = time.monotonic()
            time.sleep(self.server.shared.get("first_step", 0.0))  # the slow step itself, not a wait
            self.server.shared["first_done"] = time.monotonic()
        super().update(now)

    def ready(self):
        return self.server.shared.get("ready", True)


def _token_seen(port, fabric_factory, addr: str) -> float:
    fab = fabric_factory(port)
    node = fab.node("**")
    node.wait_for(addr, 1, timeout=20)
    return time.monotonic()


def test_a_token_only_after_the_first_slow_update(servers, port, fabric_factory):
    srv = servers('[[driver]]\nname = "slowstart"\nprovides = ["r0:dio:0"]\n', port=port)
    srv.server.registry = {**DRIVERS, "slowstart": SlowStart}
    srv.server.shared["first_step"] = 1.5
    srv.start()
    seen = _token_seen(port, fabric_factory, "r0:dio:0")
    assert seen >= srv.server.shared["first_done"], "token declared before the first update finished"
    fab = fabric_factory(port)
    t0 = time.monotonic()
    assert fab.device("r0:dio:0").describe(timeout=2).driver == "slowstart"  # answers at once
    assert time.monotonic() - t0 < 1.0


def test_a_token_only_once_the_driver_is_ready(servers, port, fabric_factory):
    srv = servers('[[driver]]\nname = "slowstart"\nprovides = ["r0:dio:0"]\n', port=port)
    srv.server.registry = {**DRIVERS, "slowstart": SlowStart}
    srv.server.shared["ready"] = False
    srv.start()
    fab = fabric_factory(port)
    node = fab.node("**")
    wait_until(lambda: srv.driver("slowstart").n >= 10, 10, "the driver updating")
    assert not node.is_alive(parse_device("r0:dio:0"))
    srv.server.shared["ready"] = True
    node.wait_for("r0:dio:0", 1, timeout=10)


# ---------------------------------------------------------------------------- rpc
def test_rpc_replies_and_typed_errors(servers, port, fabric_factory):
    srv = servers(TWO_COUNTERS, port=port).start()
    fab = fabric_factory(port)
    fab.node("**").wait_for("**", count=3, timeout=10)
    a = parse_device("r0:dio:0")
    assert fab.rpc(a, "scale", {"k": 2}) == {"ok": True, "result": 4.0}

    def code_of(op, args=None, raw: bytes | None = None) -> RpcError:
        with pytest.raises(RpcError) as ei:
            if raw is not None:
                raw_rpc(fab.session, a, op, raw)
            else:
                fab.rpc(a, op, args)
        return ei.value

    e = code_of("fly")
    assert e.code == ErrorCode.UNKNOWN_OP
    assert e.message == "r0:dio:0 has no operation 'fly'; it has: describe, scale, crash"
    e = code_of("scale", {"k": "two"})
    assert e.code == ErrorCode.BAD_REQUEST and "'k' must be a number" in e.message
    e = code_of("scale", {"k": math.nan})
    assert e.code == ErrorCode.BAD_REQUEST and "'k' must be finite" in e.message
    e = code_of("scale", {})
    assert e.code == ErrorCode.BAD_REQUEST and "'k' is missing" in e.message
    e = code_of("scale", raw=b"\xc1not msgpack")
    assert e.code == ErrorCode.BAD_REQUEST and "not msgpack" in e.message
    e = code_of("scale", raw=msgpack.packb([1, 2]))
    assert e.code == ErrorCode.BAD_REQUEST and "must be a msgpack map" in e.message
    e = code_of("scale", {"k": 50})
    assert e.code == ErrorCode.OUT_OF_RANGE and e.message == "k = 50 is over 10"
    e = code_of("crash")
    assert e.code == ErrorCode.INTERNAL and e.message == "ZeroDivisionError: division by zero"
    # none of that hurt the driver
    assert srv.slot_state("counter") == "running"
    assert fab.rpc(a, "scale", {"k": 1.5})["result"] == 3.0
    assert srv.server.stats["rejected"] == 7  # every error reply but the internal one


# ---------------------------------------------------------------------------- cmd
JUNK_CMDS = [
    b"\xc1\xff\x00garbage",  # not msgpack
    msgpack.packb([0.1, 0.2]),  # not a map
    msgpack.packb("v=0.1"),
    b"",  # empty: no 'v'
    msgpack.packb({"speed": 0.1}),  # wrong fields
    msgpack.packb({"v": "fast", "w": 0.0}),  # wrong type
    msgpack.packb({"v": True, "w": 0.0}),
    msgpack.packb({"v": math.nan, "w": 0.0}),  # NaN
    msgpack.packb({"v": 0.1, "w": math.inf}),  # inf
]


def test_malformed_commands_change_nothing_and_the_server_keeps_serving(servers, port, fabric_factory, caplog_bridge):
    srv = servers(TWO_COUNTERS, port=port).start()
    fab = fabric_factory(port)
    node = fab.node("**")
    node.wait_for("**", count=3, timeout=10)
    a = parse_device("r0:dio:0")
    drv = srv.driver("counter")
    for junk in JUNK_CMDS:
        fab.session.put(keys.cmd_key(a), junk)
    wait_until(lambda: srv.server.stats["rejected"] == len(JUNK_CMDS), 5, "every malformed command to be rejected")
    assert drv.cmd is None
    assert srv.slot_state("counter") == "running"
    assert node.is_alive(a)
    # one warning for the burst, not one per command
    warnings = [r for r in caplog_bridge.records if "rejected cmd on rsal/r0/dio/0/cmd" in r.getMessage()]
    assert len(warnings) == 1
    # still serving: data flows, rpc answers, a valid command is taken
    dev = fab.device(a)
    dev.wait_for_data(5, newer_than=dev.count)
    assert fab.rpc(a, "scale", {"k": 1})["result"] == 2.0
    fab.send(a, VelocityCmd(0.2, -0.1))
    wait_until(lambda: drv.cmd is not None, 5, "the valid command to reach the driver")
    assert drv.cmd == VelocityCmd(0.2, -0.1)


def test_a_command_to_a_device_that_takes_none_is_rejected(servers, port, fabric_factory):
    srv = servers('[[driver]]\nname = "flaky"\nprovides = ["r0:dio:0"]\n', port=port).start()
    fab = fabric_factory(port)
    fab.node("**").wait_for("r0:dio:0", timeout=10)
    fab.send(parse_device("r0:dio:0"), VelocityCmd(0.1, 0.0))
    wait_until(lambda: srv.server.stats["rejected"] == 1, 5, "the command to be rejected")
    assert srv.slot_state("flaky") == "running"


# ---------------------------------------------------------------------------- failure isolation
FLAKY_AND_COUNTER = """
[[driver]]
name = "flaky"
provides = ["r0:dio:0"]

[[driver]]
name = "counter"
provides = ["r1:dio:0"]
"""


def test_a_driver_that_raises_in_update_is_withdrawn_and_the_others_go_on(servers, port, fabric_factory, caplog_bridge):
    srv = servers(FLAKY_AND_COUNTER, port=port).start()
    fab = fabric_factory(port)
    node = fab.node("**")
    node.wait_for("**", count=2, timeout=10)
    flaky, healthy = parse_device("r0:dio:0"), parse_device("r1:dio:0")
    srv.server.shared["boom"] = True
    node.wait_gone(flaky, timeout=5)
    assert srv.slot_state("flaky") == "failed"
    assert srv.driver("flaky").shut  # its actuators were stopped
    assert flaky not in srv.server.devices
    # the other driver keeps publishing and answering
    assert node.is_alive(healthy)
    dev = fab.device(healthy)
    dev.wait_for_data(5, newer_than=dev.count + 3)
    assert fab.rpc(healthy, "scale", {"k": 3})["result"] == 6.0
    assert srv.error is None and srv.thread.is_alive()
    msgs = [r.getMessage() for r in caplog_bridge.records if r.levelno == logging.ERROR]
    assert msgs == [
        "test.toml: driver #1 (flaky): driver failed in update: RuntimeError: sensor unplugged; "
        "its devices are withdrawn"
    ]


# ---------------------------------------------------------------------------- requires
def test_a_required_device_that_never_appears_fails_the_driver(servers, caplog_bridge):
    text = """
    [[driver]]
    name = "rangertolaser"
    requires = ["r9:ranger:0"]
    provides = ["r9:laser:0"]
    """
    srv = servers(text, require_timeout=0.3)
    t0 = time.monotonic()
    srv.server.start()
    assert srv.slot_state("rangertolaser") == "waiting"
    with pytest.raises(ServerError, match="no driver is working any more"):
        srv.server.run(until=t0 + 10)
    assert 0.3 <= time.monotonic() - t0 < 5
    assert srv.slot_state("rangertolaser") == "failed"
    assert srv.server.devices == {}
    errors = [r.getMessage() for r in caplog_bridge.records if r.levelno == logging.ERROR]
    assert errors == [
        "test.toml: driver #1 (rangertolaser): required device(s) r9:ranger:0 did not appear within 0.3 s; "
        "start the server that provides them, or check the 'requires' names"
    ]


def test_requires_satisfied_by_a_second_server_starts_the_driver(servers, fabric_factory):
    port_a, port_b = free_port(), free_port()
    ranger = servers(
        """
        [[driver]]
        name = "replay"
        provides = ["r0:ranger:0"]
        rate = 20
        samples = 90
        fov = 180
        value = 2.5
        """,
        port=port_a,
    )
    laser = servers(
        """
        [[driver]]
        name = "rangertolaser"
        requires = ["r0:ranger:0"]
        provides = ["r0:laser:0"]
        """,
        port=port_b,
        connect=(port_a,),
    ).start()
    assert laser.slot_state("rangertolaser") == "waiting"  # nothing provides r0:ranger:0 yet
    assert laser.server.devices == {}
    ranger.start()
    fab = fabric_factory(port_a)
    node = fab.node("**")
    node.wait_for("r0:laser:0", timeout=10)
    assert laser.slot_state("rangertolaser") == "running"
    scan = fab.device("r0:laser:0").wait_for_data(5)
    assert scan.ranges.shape == (90,)
    assert scan.ranges.tolist() == [2.5] * 90
    assert scan.angle_min == pytest.approx(-math.pi / 2)
    assert scan.angle_step == pytest.approx(math.pi / 89)
    d = fab.device("r0:laser:0").describe()
    assert d.driver == "rangertolaser" and d.geometry["source"] == "r0:ranger:0"
    assert laser.driver("rangertolaser").count >= 1


def test_a_required_device_that_comes_and_goes_is_waited_for_again(servers):
    """A device seen and then lost before the others arrive is still missing."""
    text = """
    [[driver]]
    name = "counter"
    requires = ["r9:ranger:0", "r9:ranger:1"]
    provides = ["r9:dio:0"]
    """
    srv = servers(text)
    srv.server.start()
    slot = srv.server.slots[0]
    a, b = parse_device("r9:ranger:0"), parse_device("r9:ranger:1")
    for addr, alive in ((a, True), (a, False), (b, True)):
        srv.server._handle(("live", slot, addr, alive))
    assert slot.state == "waiting" and slot.missing == {a}
    srv.server._handle(("live", slot, a, True))
    assert slot.state == "running"
    assert set(srv.server.devices) == {parse_device("r9:dio:0")}


def test_data_from_a_required_device_reaches_the_driver_and_bad_data_is_dropped(servers, fabric_factory):
    port = free_port()
    srv = servers(
        """
        [[driver]]
        name = "rangertolaser"
        requires = ["r5:ranger:0"]
        provides = ["r5:laser:0"]
        """,
        port=port,
    ).start()
    fab = fabric_factory(port)
    # this process plays the ranger: a token and hand-made scans
    with fab.session.liveliness().declare_token(keys.device_key(parse_device("r5:ranger:0"))):
        fab.node("**").wait_for("r5:laser:0", timeout=10)
        drv = srv.driver("rangertolaser")
        data_key = keys.data_key(parse_device("r5:ranger:0"))
        good = RangerData(1.0, np.array([1.0, 2.0]), -0.1, 0.1, 0.02, 4.0)
        laser = fab.device("r5:laser:0")
        for payload in (b"\xc1junk", encode({"t": 1.0, "ranges": [1, 2]}), encode(good)):
            fab.session.put(data_key, payload)
        scan = laser.wait_for_data(5)
        assert scan.ranges.tolist() == [1.0, 2.0] and scan.t == 1.0
        assert drv.count == 1
        assert srv.slot_state("rangertolaser") == "running"


# ---------------------------------------------------------------------------- in-process dependencies
def test_a_failed_driver_takes_the_drivers_that_depend_on_it_along(servers, port, fabric_factory, caplog_bridge):
    """The sim drivers depend on the simulation driver's world: when the simulation fails (here its
    world step raises MemoryError), every robot device is withdrawn too, not left alive and silent;
    a driver that depends on nothing (the counter) keeps serving."""
    import mrs_bridge.drivers  # noqa: F401  (registers the sim drivers)
    from mrs_bridge.driver import DRIVERS as REGISTRY

    text = f"""
    [server]
    node = "sim"

    [[driver]]
    name = "simulation"
    provides = ["simulation:0"]
    worldfile = "{ROOT / "maps" / "testroom.world"}"

    [[driver]]
    name = "sim"
    model = "r0"
    provides = ["r0:position2d:0", "r0:laser:0"]

    [[driver]]
    name = "counter"
    provides = ["c0:dio:0"]
    """
    srv = servers(text, port=port, drivers={**REGISTRY, **DRIVERS}).start()
    fab = fabric_factory(port)
    node = fab.node("**")
    node.wait_for("**", count=4, timeout=10)
    world = srv.server.shared["simulator.world"]

    def explode():
        raise MemoryError("cannot allocate the circle index")

    world.advance = explode
    for a in ("sim:simulation:0", "r0:position2d:0", "r0:laser:0"):
        node.wait_gone(parse_device(a), timeout=5)
    assert srv.slot_state("simulation") == "failed" and srv.slot_state("sim") == "failed"
    assert node.is_alive(parse_device("c0:dio:0"))
    assert fab.rpc(parse_device("c0:dio:0"), "scale", {"k": 1})["result"] == 2.0
    errors = [r.getMessage() for r in caplog_bridge.records if r.levelno == logging.ERROR]
    assert any("withdrawn because" in m and "simulation" in m for m in errors), errors


def test_a_full_inbox_drops_cmds_and_answers_rpcs_busy():
    """Zenoh's callbacks never wait and never queue more than INBOX_MAX items from the network."""
    import textwrap

    from mrs_bridge.config import parse_config
    from mrs_bridge.server import INBOX_MAX, DeviceServer
    from rsal.testing import FakeSession

    class Query:
        payload = None

        def __init__(self):
            self.errors = []

        def reply_err(self, payload):
            self.errors.append(msgpack.unpackb(payload))

        def drop(self):
            pass

    class Payload(bytes):
        def to_bytes(self):
            return bytes(self)

    srv = DeviceServer(parse_config(textwrap.dedent(TWO_COUNTERS), source="t.toml"), FakeSession(), drivers=DRIVERS)
    a = parse_device("r0:dio:0")
    cmd = Payload(encode(VelocityCmd(0.1, 0.0)))
    for _ in range(INBOX_MAX + 10):
        srv._on_sample(("cmd", a), cmd, 1024)
    assert srv.inbox.qsize() == INBOX_MAX and srv.stats["dropped"] == 10
    q = Query()
    srv._on_query(a, q)
    assert [e["code"] for e in q.errors] == [ErrorCode.BUSY] and srv.stats["busy"] == 1
    srv._on_sample(("cmd", a), Payload(b"x" * 2048), 1024)  # over the limit: not even queued
    assert srv.stats["too_large"] == 1 and srv.inbox.qsize() == INBOX_MAX
    srv.stop()  # the server's own items still get in
    assert srv.inbox.qsize() == INBOX_MAX + 1


def test_data_from_a_required_device_waits_as_its_latest_sample_only():
    """A newer data sample replaces one still waiting in the inbox (latest wins); events queue in
    order, every one; a scheduler that keeps up sees every sample."""
    import textwrap

    from mrs_bridge.config import parse_config
    from mrs_bridge.server import DeviceServer
    from rsal.testing import FakeSession

    class Payload(bytes):
        def to_bytes(self):
            return bytes(self)

    srv = DeviceServer(parse_config(textwrap.dedent(TWO_COUNTERS), source="t.toml"), FakeSession(), drivers=DRIVERS)
    from types import SimpleNamespace

    slot = SimpleNamespace(state="running", driver=SimpleNamespace(on_input=None))
    other = SimpleNamespace(state="running", driver=SimpleNamespace(on_input=None))
    a = parse_device("r0:dio:0")
    seen = []
    srv._call = lambda s, fn, addr, channel, msg: seen.append((s is slot, channel, msg))
    for i in range(5):  # five samples while the scheduler is busy: one item, the newest payload
        srv._on_sample(("input", slot, a, "data"), Payload(msgpack.packb({"i": i})), 1 << 20)
    srv._on_sample(("input", other, a, "data"), Payload(msgpack.packb({"i": 9})), 1 << 20)  # another driver's
    for i in range(3):
        srv._on_sample(("input", slot, a, "event"), Payload(msgpack.packb({"e": i})), 1 << 20)
    assert srv.inbox.qsize() == 5 and srv.stats["superseded"] == 4
    import rsal.interfaces as itf

    decode = itf.decode_data
    itf.decode_data = lambda iface, payload: msgpack.unpackb(payload)
    try:
        while not srv.inbox.empty():
            srv._handle(srv.inbox.get_nowait())
        srv._on_sample(("input", slot, a, "data"), Payload(msgpack.packb({"i": 5})), 1 << 20)  # kept up
        srv._handle(srv.inbox.get_nowait())
    finally:
        itf.decode_data = decode
    assert seen == [
        (True, "data", {"i": 4}),
        (False, "data", {"i": 9}),
        (True, "event", {"e": 0}),
        (True, "event", {"e": 1}),
        (True, "event", {"e": 2}),
        (True, "data", {"i": 5}),
    ]
