"""A rogue rpc responder on an open fabric is ignored (docs/security-receivers.md; issue 14).

A real ``rsal sim`` serves ``r0``; a stock Zenoh peer (no project code) declares a queryable on
``rsal/r0/position2d/0/rpc/describe`` answering ``max_speed [50, 50]``. Before the check the rogue
won about one request in ten; now every one of 20 describes made through :class:`rsal.client.Fabric`
comes from the session that owns the device's liveliness token, and the rogue is logged once.
"""

from __future__ import annotations

import json
import logging

import msgpack
import zenoh

from rsal import keys
from rsal.client import Fabric
from rsal.transport import TransportArgs
from tests.conftest import MAPS, Proc, free_port, rsal_cmd, wait_until

WORLD = str(MAPS / "testroom.world")


def test_twenty_describes_all_come_from_the_real_device(caplog):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    sim = Proc(rsal_cmd("sim", WORLD, "--listen", ep))
    try:
        c = zenoh.Config()
        c.insert_json5("scouting/multicast/enabled", "false")
        c.insert_json5("connect/endpoints", json.dumps([ep]))
        rogue_answers = []

        def rogue(q: zenoh.Query) -> None:
            rogue_answers.append(1)
            q.reply(q.key_expr, msgpack.packb({"ok": True, "max_speed": [50.0, 50.0]}))

        with zenoh.open(c) as outsider, Fabric.connect(TransportArgs(connect=[ep])) as fab:
            addr = keys.parse_device("r0:position2d:0")
            wait_until(
                lambda: any(r.ok for r in fab.session.liveliness().get(keys.device_key(addr), timeout=1.0)),
                60,
                "the simulator's r0 position2d token",
            )
            q = outsider.declare_queryable(keys.rpc_key(addr, "describe"), rogue)
            # the rogue is reachable: a stock query that asks every queryable gets its answer
            wait_until(
                lambda: any(
                    r.ok and msgpack.unpackb(r.ok.payload.to_bytes()).get("max_speed") == [50.0, 50.0]
                    for r in outsider.get(
                        keys.rpc_key(addr, "describe"),
                        target=zenoh.QueryTarget.ALL,
                        consolidation=zenoh.ConsolidationMode.NONE,
                        timeout=2.0,
                    )
                ),
                10,
                "the rogue queryable to answer",
            )
            with caplog.at_level(logging.WARNING, logger="rsal.client"):
                got = [fab.rpc(addr, "describe", timeout=3.0) for _ in range(20)]
            q.undeclare()
        assert len(rogue_answers) >= 20  # the rogue was asked every time, and answered
        assert all("max_speed" not in g for g in got), got[0]  # no reply of the rogue's was taken
        assert all(g == got[0] for g in got) and got[0]["interface"] == "position2d", got[0]
        warned = [r.getMessage() for r in caplog.records if "does not own the device's token" in r.getMessage()]
        assert len(warned) == 1, warned  # logged once for 20 rogue replies
    finally:
        sim.close()
