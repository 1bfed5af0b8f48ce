"""Receivers check what they can on an open fabric (docs/security-receivers.md): forged agent
messages put by a stock Zenoh session (no project code on the sending side) change nothing.

(a) A service message whose envelope ``sender`` is not the key's sender chunk is dropped, counted
as forged and reported by one warning naming the key and the claimed sender; genuine messages
after it still arrive. (b) The contract net's "ghost" forgery of issue 14: a forged call for
proposals for an unknown prey and a forged award do not make a participant chase anything.
"""

from __future__ import annotations

import json
import logging

import pytest
import zenoh

from agents.runtime import Agent, AgentHost
from agents.services import SendPosition, encode_message
from rsal.transport import TransportArgs, open_session
from tests.conftest import LoopThread, free_port, wait_until


def stock_session(endpoint: str) -> zenoh.Session:
    """A plain zenoh-python peer, as an outsider would open it: loopback, multicast scouting off."""
    c = zenoh.Config()
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(c)


@pytest.fixture
def fabric():
    ep = f"tcp/127.0.0.1:{free_port()}"
    ours = open_session(TransportArgs(listen=[ep]))
    outsider = stock_session(ep)
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
