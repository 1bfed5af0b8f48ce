"""Bundled cell broadcasts (agents/services.py "Bundles", agents/cellsub.py ``bundles``).

(a) A bundle round-trips its entries; a malformed bundle is refused whole with the reason, and a
malformed entry is left out with its own reason while the others are kept. (b) Over real Zenoh
sessions: a host that bundles puts several broadcasts per sample and none on its own cell key; the
other host's cell subscription delivers exactly the entries of its watched cells, each once, and a
plain ``svc/<service>/*/*`` subscriber sees no bundle. (c) A malformed bundle from a peer is
dropped and counted, and the receiver goes on taking the good ones.
"""

from __future__ import annotations

import math
import threading

import msgpack
import pytest

from agents.services import Message, SendPosition, bundle_key, decode_bundle, encode_bundle
from rsal.msgs import MessageError
from tests.conftest import wait_until


def _pos(name: str, x: float) -> SendPosition:
    return SendPosition(name, float(x), 0.5, 0.0)


def test_a_bundle_round_trips_and_refuses_what_is_malformed():
    entries = [("c0_0", "a1", "p0", 10.0, _pos("r1", 1.0)), ("c1_0", "a2", "p7", 10.5, _pos("r2", 4.0))]
    got, bad = decode_bundle("send_position", encode_bundle(entries))
    assert bad == []
    assert got == [
        ("c0_0", Message("send_position", "a1", "p0", 10.0, _pos("r1", 1.0))),
        ("c1_0", Message("send_position", "a2", "p7", 10.5, _pos("r2", 4.0))),
    ]
    cols = {"cells": ["c0_0"], "senders": ["a1"], "conversations": ["p0"], "times": [1.0], "bodies": [{}]}
    for broken, reason in (
        (b"\xc1", "not msgpack"),
        (msgpack.packb([1, 2]), "must be a msgpack map"),
        (msgpack.packb({k: v for k, v in cols.items() if k != "times"}), "'times' must be a list"),
        (msgpack.packb(cols | {"senders": ["a1", "a2"]}), "lists of one length"),
    ):
        with pytest.raises(MessageError, match=reason):
            decode_bundle("send_position", broken)
    good = _pos("r1", 1.0).to_dict()
    mixed = {
        "cells": ["c0_0", "c/1", "c0_0", "c0_0", "c0_0", "c0_0"],
        "senders": ["a1", "a2", "a*", "a4", "a5", "a6"],
        "conversations": ["p0", "p0", "p0", "p0", "p0", 7],
        "times": [1.0, 1.0, 1.0, math.nan, 1.0, 1.0],
        "bodies": [good, good, good, good, {"robot": "r5", "x": "far"}, good],
    }
    got, bad = decode_bundle("send_position", msgpack.packb(mixed))
    assert [m.sender for _c, m in got] == ["a1"]
    assert len(bad) == 5
    for word in ("cell 'c/1'", "sender 'a*'", "time nan", "'x' must be a number", "conversation 7"):
        assert any(word in b for b in bad), (word, bad)


class Log:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.got: list[tuple[str, int]] = []

    def __call__(self, msg: Message) -> None:
        with self.lock:
            self.got.append((msg.sender, int(msg.conversation)))

    def keys(self) -> list[tuple[str, int]]:
        with self.lock:
            return list(self.got)


def test_a_bundling_host_reaches_the_watched_cells_of_another_once_each(hosts):
    lt, recv_host, send_host = hosts
    log, plain = Log(), Log()

    async def listen():
        sub = recv_host.services.subscribe_cells("send_position", log, owner="test", bundles=True)
        sub.watch({"c0_0"})
        recv_host.services.subscribe("send_position", plain, owner="test")  # svc/send_position/*
        raw = recv_host.services.session.declare_subscriber("svc/send_position/*/*", lambda s: plain(None))
        return sub, raw

    sub, raw = lt.run(listen())
    svc = send_host.services
    svc.bundle("send_position", window=0.02)

    def heard() -> bool:
        svc.publish("send_position", _pos("probe", 1.0), sender="probe", conversation="-1", cell="c0_0")
        return ("probe", -1) in log.keys()

    wait_until(heard, 10, "a bundle at the receiving host", interval=0.05)
    sent = {"c0_0": [], "c1_0": []}

    async def talk():  # on the host's loop, as agents publish
        for seq in range(200):
            sender = f"a{seq % 5}"
            cell = "c0_0" if seq % 3 else "c1_0"
            svc.publish("send_position", _pos(sender, 1.0), sender=sender, conversation=str(seq), cell=cell)
            sent[cell].append((sender, seq))

    lt.run(talk())

    def mine() -> list[tuple[str, int]]:
        return sorted(k for k in log.keys() if k[0] != "probe")

    wait_until(lambda: mine() == sorted(sent["c0_0"]), 10, "every broadcast of the watched cell")
    svc.flush_bundles()
    assert mine() == sorted(sent["c0_0"])  # once each, none of the other cell, nothing late
    assert svc.publishers_declared == 0  # nothing went out on a cell key of its own
    assert svc.bundled_messages >= 200 and svc.bundles_sent < svc.bundled_messages / 5, (
        svc.bundles_sent,
        svc.bundled_messages,
    )
    assert plain.keys() == []  # '@bundle' is a verbatim chunk: no wildcard subscriber sees bundles
    assert sub.bundle_entries == len(log.keys())
    raw.undeclare()


def test_a_malformed_bundle_is_dropped_and_the_good_ones_still_arrive(hosts):
    lt, recv_host, send_host = hosts
    log = Log()

    async def listen():
        sub = recv_host.services.subscribe_cells("send_position", log, owner="test", bundles=True)
        sub.watch({"c0_0"})
        return sub

    lt.run(listen())
    key = bundle_key("send_position", "peer1")
    good = encode_bundle([("c0_0", "a1", "1", 1.0, _pos("r1", 1.0))])
    dropped = recv_host.services.dropped
    for payload in (b"\xc1", msgpack.packb({"cells": "c0_0"})):
        send_host.session.put(key, payload)

    def arrived() -> bool:
        send_host.session.put(key, good)
        return ("a1", 1) in log.keys()

    wait_until(arrived, 10, "the good bundle after the bad ones", interval=0.05)
    wait_until(lambda: recv_host.services.dropped >= dropped + 2, 10, "both bad bundles counted as dropped")
