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
