"""rsal.transport's Zenoh runtime setting (docs/deployment.md, "Leases and cut links"): a process
that opens its session with :func:`rsal.transport.open_session` runs Zenoh with rsal's
``ZENOH_RUNTIME`` (Zenoh accepts it: the session opens), unless its environment already names one.
What it does for cut links is judged across network namespaces in tests/fabric/test_multihost.py."""

from __future__ import annotations

import os
import subprocess
import sys

from rsal.transport import ZENOH_RUNTIME
from tests.conftest import ROOT

OPEN = (
    "import os\n"
    "from rsal.transport import TransportArgs, open_session\n"
    "s = open_session(TransportArgs(listen=['tcp/127.0.0.1:0']))\n"
    "print(os.environ.get('ZENOH_RUNTIME', ''))\n"
    "s.close()\n"
)


def _runtime_of_a_session(env: dict[str, str]) -> str:
    r = subprocess.run([sys.executable, "-c", OPEN], env=env, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout.strip()


def test_sessions_run_rsals_receive_runtime_unless_the_environment_names_one():
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    assert _runtime_of_a_session(env) == ZENOH_RUNTIME
    own = "(rx: (worker_threads: 3))"
    assert _runtime_of_a_session({**env, "ZENOH_RUNTIME": own}) == own


def _listen(**kw) -> list[str] | dict:
    import json

    from rsal.transport import TransportArgs, make_config

    return json.loads(make_config(TransportArgs(**kw)).get_json("listen/endpoints"))


def test_a_peer_that_only_connects_on_this_machine_listens_on_loopback_not_every_interface():
    for ep in ("tcp/127.0.0.1:7447", "tcp/localhost:7447", "tcp/[::1]:7447", "unixsock-stream//tmp/f.sock"):
        assert _listen(connect=[ep]) == ["tcp/127.0.0.1:0"], ep
    assert _listen() == ["tcp/127.0.0.1:0"]  # no flags: it connects to the default endpoint
    assert _listen(connect=["tcp/127.0.0.1:7447"], listen=["tcp/127.0.0.1:7500"]) == ["tcp/127.0.0.1:7500"]
    # another machine: peers there must reach it, so Zenoh's default (every interface) stays
    assert "[::]" in str(_listen(connect=["tcp/10.1.2.3:7447"]))
    assert "[::]" in str(_listen(connect=["tcp/127.0.0.1:7447", "tcp/robot1.lab:7447"]))


def test_peers_that_only_connect_to_one_server_on_loopback_still_link_to_each_other_directly():
    from rsal.transport import TransportArgs, open_session
    from tests.conftest import free_port, wait_until

    ep = f"tcp/127.0.0.1:{free_port()}"
    server = open_session(TransportArgs(listen=[ep]))
    a = open_session(TransportArgs(connect=[ep]))
    b = open_session(TransportArgs(connect=[ep]))
    try:  # each knows the server and the other (by gossip, then its loopback listener)
        wait_until(lambda: b.info.zid() in set(a.info.peers_zid()), 20, "the two peers to link directly")
        assert server.info.zid() in set(a.info.peers_zid())
    finally:
        for s in (b, a, server):
            s.close()
