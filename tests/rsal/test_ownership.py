"""A device's rpc is answered only by the session that owns it (rsal.ownership, docs/security.md).

On an open fabric a stock zenoh-python peer (no project code) declares a queryable on a real
``rsal sim`` robot's ``rpc/describe`` and answers ``max_speed [50, 50]``: the project's rpc client
never takes it (20 of 20 requests give the simulator's own answer), counts it and logs one line.
A peer that also claims the device with an owner token of its own makes the rpc refuse both, with
one line naming both sessions. A device nobody claims (a server of another implementation, no owner
token) is answered by the one session that serves it.
"""

from __future__ import annotations

import logging

import pytest
import zenoh

from rsal import ownership
from rsal.client import query_rpc
from rsal.keys import parse_device
from rsal.msgs import ErrorCode, RpcError, ok_reply
from tests.conftest import ROOT, rsal_cmd, stock_session, wait_until

KEY = "rsal/r0/position2d/0/rpc/describe"


@pytest.fixture(scope="module")
def fabric(tmp_path_factory):
    from tests.conftest import Proc, free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    sim = Proc(rsal_cmd("sim", str(ROOT / "maps" / "testroom.world"), "--listen", ep, "--no-map"))
    rogue = stock_session(connect=ep)
    client = stock_session(connect=ep)
    try:
        wait_until(
            lambda: any(r.ok for r in client.liveliness().get("rsal/r0/position2d/0", timeout=1.0)),
            60,
            "r0's position2d",
        )
        yield {"rogue": rogue, "client": client, "sim": sim}
    finally:
        client.close()
        rogue.close()
        sim.close()


def ask(session, device: str = "r0:position2d:0"):
    got: list = []
    query_rpc(session, parse_device(device), "describe", None, 5.0, got.append)
    wait_until(lambda: got, 10, f"the describe of {device}")
    return got[0]


def test_a_rogue_responder_is_never_taken_and_logged_once(fabric, caplog):
    rogue, client = fabric["rogue"], fabric["client"]
    q = rogue.declare_queryable(KEY, lambda qu: qu.reply(qu.key_expr, ok_reply(node="r0", max_speed=[50, 50])))
    try:
        # the rogue's queryable reaches the client: a stock get with consolidation takes it sometimes
        wait_until(
            lambda: any(
                r.ok and b"max_speed" in r.ok.payload.to_bytes() and r.replier_id.zid == rogue.info.zid()
                for r in client.get(
                    KEY, target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE, timeout=3.0
                )
            ),
            20,
            "the rogue's reply at a stock client",
        )
        before = ownership.STATS["foreign"]
        with caplog.at_level(logging.WARNING, logger="rsal.ownership"):
            answers = [ask(client) for _ in range(20)]
        assert all(isinstance(a, dict) for a in answers), [a for a in answers if not isinstance(a, dict)]
        speeds = {tuple(a.get("max_speed") or ()) for a in answers}
        assert (50, 50) not in speeds and len(speeds) == 1, speeds
        assert ownership.STATS["foreign"] - before == 20
        lines = [r.getMessage() for r in caplog.records if "does not own" in r.getMessage()]
        assert len(lines) == 1 and str(rogue.info.zid()) in lines[0] and KEY in lines[0], lines
    finally:
        q.undeclare()


def test_a_second_claimant_makes_the_rpc_refuse_both(fabric):
    rogue, client = fabric["rogue"], fabric["client"]
    claim = ownership.DeviceToken(rogue, "rsal/r0/position2d/0")
    q = rogue.declare_queryable(KEY, lambda qu: qu.reply(qu.key_expr, ok_reply(node="r0", max_speed=[50, 50])))
    try:
        wait_until(
            lambda: len(list(client.liveliness().get(ownership.owners_query("rsal/r0/position2d/0"), timeout=2))) == 2,
            20,
            "both owner tokens",
        )
        got = ask(client)
        assert isinstance(got, RpcError) and got.code == ErrorCode.UNAVAILABLE, got
        assert "2 sessions answer for r0:position2d:0" in got.message and str(rogue.info.zid()) in got.message
    finally:
        q.undeclare()
        claim.undeclare()
    # the rogue gone, the owner's answer is taken again
    wait_until(lambda: isinstance(ask(client), dict), 20, "the owner's answer alone")


def test_a_device_nobody_claims_is_answered_by_its_one_server(fabric):
    other, client = fabric["rogue"], fabric["client"]
    token = other.liveliness().declare_token("rsal/x9/position2d/0")  # no owner token
    q = other.declare_queryable(
        "rsal/x9/position2d/0/rpc/describe", lambda qu: qu.reply(qu.key_expr, ok_reply(node="x9"))
    )
    try:
        got = ask(client, "x9:position2d:0")
        assert isinstance(got, dict) and got["node"] == "x9", got
    finally:
        q.undeclare()
        token.undeclare()


def test_zenohs_own_reply_speaks_for_no_session():
    """A reply without a replier id (the query's timeout, from Zenoh itself) is no second session:
    it is the answer only when no session answered."""
    timeout = RpcError(ErrorCode.TIMEOUT, "Timeout", KEY)
    assert ownership.choose(KEY, "r0:position2d:0", [(None, timeout)], {"a1"}, 5.0) is timeout
    assert ownership.choose(KEY, "r0:position2d:0", [(None, timeout), ("a1", {"ok": 1})], {"a1"}, 5.0) == {"ok": 1}
    assert ownership.choose(KEY, "r0:position2d:0", [("b2", {"ok": 2}), (None, timeout)], set(), 5.0) == {"ok": 2}
