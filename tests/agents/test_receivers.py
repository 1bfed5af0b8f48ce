"""Receivers check what they can on an open fabric (docs/security.md, "Open fabric"): forged agent
messages put by a stock Zenoh session (no project code on the sending side) change nothing.

(a) A service message whose envelope ``sender`` is not the key's sender chunk is dropped, counted
as forged and reported by one warning naming the key and the claimed sender; genuine messages
after it still arrive. (b) The contract net's "ghost" forgery: a forged call for
proposals for an unknown prey and a forged award do not make a participant chase anything.
"""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from agents.contractnet import ACCEPT, CFP, Participant
from agents.runtime import Agent, AgentHost
from agents.scenarios.hunt.agents import FollowAgent
from agents.services import SendPosition, encode_message
from rsal.data import Position
from rsal.transport import TransportArgs, open_session
from tests.conftest import LoopThread, free_port, stock_session, wait_until


@pytest.fixture
def fabric():
    ep = f"tcp/127.0.0.1:{free_port()}"
    ours = open_session(TransportArgs(listen=[ep]))
    outsider = stock_session(connect=ep)
    lt = LoopThread()
    host = AgentHost(ours)
    lt.run(host.__aenter__())
    yield {"host": host, "loop": lt, "outsider": outsider, "session": ours}
    lt.run(host.stop())
    lt.close()
    outsider.close()
    ours.close()


class Listener(Agent):
    def __init__(self, agent_id: str, **kw):
        super().__init__(agent_id, **kw)
        self.got: list = []

    async def created(self):
        self.subscribe("send_position", self.got.append)


def test_forged_envelope_is_dropped_counted_and_warned_once(fabric, caplog):
    host, out = fabric["host"], fabric["outsider"]
    a = fabric["loop"].run(host.start(Listener("listener")))
    wait_until(lambda: any(True for _ in out.liveliness().get("agents/listener", timeout=1.0)), 5, "the listener")
    forged = encode_message("prey0", SendPosition("r0", 9.0, 9.0, 0.0), "c", 1.0)
    with caplog.at_level(logging.WARNING, logger="agents.services"):
        for _ in range(5):  # the intruder publishes under its own key, claiming to be prey0
            out.put("svc/send_position/intruder", forged)
        wait_until(lambda: host.services.forged >= 5, 5, "the five forged messages to be counted")
        out.put("svc/send_position/prey0", encode_message("prey0", SendPosition("r0", 1.0, 2.0, 0.0), "c", 2.0))
        wait_until(lambda: len(a.got) == 1, 5, "the genuine message after the forged ones")
    assert a.got[0].sender == "prey0" and (a.got[0].body.x, a.got[0].body.y) == (1.0, 2.0)
    assert host.services.dropped >= 5
    warnings = [r.getMessage() for r in caplog.records if "claims sender" in r.getMessage()]
    assert len(warnings) == 1, warnings
    assert "svc/send_position/intruder" in warnings[0] and "'prey0'" in warnings[0]


class Bidder(Agent):
    """A contract-net participant that answers only ``boss``; bids 1.0 for anything."""

    def __init__(self, agent_id: str):
        super().__init__(agent_id, period=1.0)
        self.performed: list[dict] = []

    async def created(self):
        self.cnp = Participant(self, initiators={"boss"})

    def bid(self, task: dict):
        return 1.0

    def perform(self, task: dict) -> bool:
        self.performed.append(task)
        return True


def cnp(sender: str, conv: str, performative: str, **body) -> bytes:
    return encode_message(sender, {"performative": performative, **body}, conv, time.time())


def test_ghost_call_and_forged_awards_commit_no_participant(fabric, caplog):
    """The "ghost" forgery: a forged call for proposals for a prey named ghost plus forged awards,
    put by a stock session. The participant does not bid, does not perform, logs each kind of
    forgery once per sender, and still serves its genuine initiator afterwards."""
    host, out = fabric["host"], fabric["outsider"]
    w = fabric["loop"].run(host.start(Bidder("hunter3")))
    proposals: list[str] = []
    sub = out.declare_subscriber("svc/contract_net/hunter3", lambda s: proposals.append(s.payload.to_bytes()))
    ghost = {"prey": "ghost", "x": 0.0, "y": 0.0}
    forgeries = [
        ("svc/contract_net/intruder", cnp("intruder", "g1", CFP, to="", task=ghost, reply_by=time.time() + 5)),
        ("svc/contract_net/intruder", cnp("intruder", "g1", ACCEPT, to="hunter3", task=ghost)),
        ("svc/contract_net/boss", cnp("boss", "g2", ACCEPT, to="hunter3", task=ghost)),  # no proposal before
    ]
    with caplog.at_level(logging.WARNING, logger="agents.contractnet"):
        wait_until(lambda: any(True for _ in out.liveliness().get("agents/hunter3", timeout=1.0)), 5, "hunter3")
        for _ in range(2):
            for key, payload in forgeries:
                out.put(key, payload)
        wait_until(lambda: w.cnp.ignored >= 6, 5, "the six forged messages to be ignored")
        assert w.performed == [] and proposals == []
        assert not ({"g1", "g2"} & set(w.cnp.outcomes))
        # the genuine initiator's call is still answered and its award performed
        out.put("svc/contract_net/boss", cnp("boss", "c1", CFP, to="", task={"prey": "r0"}, reply_by=time.time() + 5))
        wait_until(lambda: w.cnp.outcomes.get("c1") == "proposed", 5, "a proposal to boss's genuine call")
        out.put("svc/contract_net/boss", cnp("boss", "c1", ACCEPT, to="hunter3", task={"prey": "r0"}))
        wait_until(lambda: w.performed == [{"prey": "r0"}], 5, "boss's genuine award performed")
    sub.undeclare()
    warnings = [r.getMessage() for r in caplog.records if "ignored" in r.getMessage()]
    assert len(warnings) == 3, warnings  # (cfp, intruder), (award, intruder), (award, boss): once each
    assert sum("call for proposals from a sender that is no initiator" in m and "intruder" in m for m in warnings) == 1
    assert sum("no proposal of mine" in m and "from boss" in m for m in warnings) == 1


class _Nav:
    position = Position(0.0, 0.0, 0.0)


def test_hunter_bids_only_for_prey_it_knows_and_answers_only_the_auctioneer():
    h = FollowAgent("hunter3", allocation="contract_net", robot="r3")
    h.pioneer = _Nav()  # what .nav reads
    h.hunters = ["hunter2", "hunter3"]
    h.prey_robots = {"r0"}
    h.positions["r0"] = SendPosition("r0", 3.0, 4.0, 0.0)
    assert h._bid({"prey": "ghost", "x": 1.0, "y": 0.0}) is None  # nobody offered a prey named ghost
    assert h._bid({"prey": "r0", "x": 3.0, "y": 4.0}) == 5.0
    assert h._is_auctioneer("hunter2") and not h._is_auctioneer("intruder") and not h._is_auctioneer("hunter3")
    assert asyncio.run(h._perform({"prey": "ghost"})) is False and h.prey == ""
