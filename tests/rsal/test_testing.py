"""The in-memory fabric (rsal/testing.py): key-expression matching, queries, liveliness, and a
device server and a client proxy talking through it without a network."""

from __future__ import annotations

import zenoh

from rsal import keys, msgs
from rsal.keys import parse_device
from rsal.msgs import Position2dData
from rsal.testing import FakeFabric, FakeServer, FakeSession


def test_put_reaches_subscribers_whose_key_expression_intersects():
    s = FakeSession()
    got: dict[str, list[str]] = {"one": [], "star": [], "all": [], "other": []}
    s.declare_subscriber("rsal/r0/laser/0/data", lambda smp: got["one"].append(str(smp.key_expr)))
    s.declare_subscriber("rsal/*/laser/*/data", lambda smp: got["star"].append(str(smp.key_expr)))
    sub = s.declare_subscriber("rsal/**", lambda smp: got["all"].append(smp.payload.to_bytes()))
    s.declare_subscriber("rsal/r1/**", lambda smp: got["other"].append(str(smp.key_expr)))
    s.put("rsal/r0/laser/0/data", b"x")
    assert got == {"one": ["rsal/r0/laser/0/data"], "star": ["rsal/r0/laser/0/data"], "all": [b"x"], "other": []}
    assert s.last["rsal/r0/laser/0/data"] == b"x"
    sub.undeclare()
    s.declare_publisher("rsal/r0/sonar/0/data").put(b"y")
    assert got["all"] == [b"x"] and s.last["rsal/r0/sonar/0/data"] == b"y"


def test_get_asks_matching_queryables_and_hands_replies_to_a_zenoh_callback():
    s = FakeSession()
    s.declare_queryable("rsal/r0/position2d/0/rpc/*", lambda q: q.reply(q.key_expr, q.payload.to_bytes() + b"!"))
    s.declare_queryable("rsal/r1/**", lambda q: q.reply_err(b"no"))
    replies, done = [], []
    s.get(
        "rsal/r0/position2d/0/rpc/describe",
        zenoh.handlers.Callback(replies.append, lambda: done.append(1)),
        payload=b"a",
    )
    assert [r.ok.payload.to_bytes() for r in replies] == [b"a!"] and done == [1]
    (err,) = s.get("rsal/r1/position2d/0/rpc/x")
    assert err.ok is None and err.err.payload.to_bytes() == b"no"
    assert s.get("rsal/r9/x/0/rpc/y") == []  # nobody answers: no reply, as a timeout


def test_liveliness_tokens_history_and_loss():
    s = FakeSession()
    tok = s.liveliness().declare_token("rsal/r0/laser/0")
    seen = []
    s.liveliness().declare_subscriber(
        "rsal/r0/**", lambda smp: seen.append((str(smp.key_expr), smp.kind)), history=True
    )
    assert seen == [("rsal/r0/laser/0", zenoh.SampleKind.PUT)]
    s.liveliness().declare_token("rsal/r1/laser/0")  # not matched
    assert [str(r.ok.key_expr) for r in s.liveliness().get("rsal/*/laser/0")] == ["rsal/r0/laser/0", "rsal/r1/laser/0"]
    tok.undeclare()
    assert seen[-1] == ("rsal/r0/laser/0", zenoh.SampleKind.DELETE)
    assert s.tokens == ["rsal/r0/laser/0", "rsal/r1/laser/0"]


def test_a_silent_session_delivers_nothing():
    s = FakeSession(silent=True)
    got = []
    s.declare_subscriber("**", got.append)
    s.liveliness().declare_subscriber("**", got.append, history=True)
    s.declare_queryable("**", lambda q: q.reply(q.key_expr, b""))
    s.liveliness().declare_token("rsal/r0/laser/0")
    s.put("a/b", b"x")
    assert got == [] and s.get("a/b") == [] and s.tokens == ["rsal/r0/laser/0"]


def test_fake_fabric_pushes_data_to_a_real_proxy_and_records_commands():
    from rsal.devices import Position2d

    fab = FakeFabric()
    pos = fab.device(Position2d, "r0:position2d:0", {"max_speed": [0.3, 0.5]})
    fab.push(pos, Position2dData(1.0, (1.0, 2.0, 0.5), (0.0, 0.0, 0.0)))
    assert pos.count == 1 and tuple(pos.latest.pose) == (1.0, 2.0, 0.5)
    assert fab.rpc(pos.addr, "describe")["geometry"] == {"max_speed": [0.3, 0.5]}
    fab.send(pos.addr, msgs.VelocityCmd(0.1, 0.0))
    assert fab.velocities() == [(0.1, 0.0)]


def test_fake_server_records_what_a_driver_does():
    srv = FakeServer()
    a = parse_device("r0:position2d:0")
    srv.send(a, "cmd")
    srv.publish(a, "data")
    srv.request(None, a, "describe", None, 5.0)
    srv._warn("k", "careful")
    assert srv.sent == [("r0:position2d:0", "cmd")] and srv.data() == ["data"]
    assert srv.requested() == [("r0:position2d:0", "describe")] and srv.warnings == ["careful"]
    assert keys.data_key(a) == "rsal/r0/position2d/0/data"
