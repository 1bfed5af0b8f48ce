"""rsal.client.Fabric's subscription callbacks: a thread per subscription (Zenoh's default) or run
on Zenoh's network threads (``direct_callbacks``), with real Zenoh sessions on loopback."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
import zenoh

from rsal import keys
from rsal.client import Fabric
from rsal.msgs import RangerData, encode
from rsal.transport import TransportArgs
from tests.conftest import free_port, wait_until

N = 20


@pytest.fixture
def publisher():
    port = free_port()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    s = zenoh.open(conf)
    yield s, f"tcp/127.0.0.1:{port}"
    s.close()


def _threads_for_proxies(fab: Fabric) -> int:
    before = threading.active_count()
    for i in range(N):
        fab.device(f"s{i}:sonar:0")
    return threading.active_count() - before


def _scan(t: float) -> RangerData:
    return RangerData(t, np.full(8, 1.5, dtype="<f4"), 0.0, 0.0, 0.1, 5.0)


@pytest.mark.parametrize("direct", [False, True])
def test_proxies_receive_data_with_either_kind_of_callback(publisher, direct):
    s, ep = publisher
    session = zenoh.open(_client_conf(ep))
    fab = Fabric(session, direct_callbacks=direct)
    try:
        added = _threads_for_proxies(fab)
        if direct:
            assert added == 0, f"{added} threads for {N} proxies with direct callbacks"
        else:
            assert added >= N, f"Zenoh's default runs each subscription on a thread of its own ({added})"
        sonar = fab.device("s7:sonar:0")
        key = keys.data_key(sonar.addr)
        n = 0

        def arrived() -> bool:
            nonlocal n
            n += 1
            s.put(key, encode(_scan(float(n))))  # until the subscription is matched
            return sonar.latest is not None

        wait_until(arrived, 10, "a scan at the proxy")
        got = []
        sonar.add_listener(got.append)  # an ordinary listener: the dispatcher thread
        s.put(key, encode(_scan(1000.0)))
        wait_until(lambda: got and got[-1].t == 1000.0, 5, "the listener to see the last scan")
        assert sonar.latest.t == 1000.0 and float(sonar.ranges[0]) == 1.5
        assert fab.device("s8:sonar:0").latest is None  # only its own key
    finally:
        fab.close()
        session.close()


def _client_conf(ep: str) -> zenoh.Config:
    from rsal.transport import make_config

    return make_config(TransportArgs(connect=[ep]))
