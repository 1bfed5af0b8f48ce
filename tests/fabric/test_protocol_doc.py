"""docs/protocol.md against a real server: what the page promises, a stock Zenoh client gets.

One ``rsal sim maps/testroom.world`` process serves the module. (a) The page's example client,
extracted verbatim and run in a subprocess, reads r0's laser and drives r0; the test checks the
scan's shape against ``rpc/describe`` and the robot's motion against the simulator's ground truth.
(b) Requests the page calls malformed get the error replies it documents. (c) A malformed ``cmd``
is dropped with the documented warning and moves nothing. (d) A robot removed from the simulation
answers ``unavailable`` until a reset. The tests talk to the server with ``zenoh`` and ``msgpack``
only, as a client that knows nothing but the page would.
"""

from __future__ import annotations

import ast
import json
import math
import re
import subprocess
import sys

import msgpack
import pytest
import zenoh

from rsal.msgs import ErrorCode
from tests.conftest import MAPS, ROOT, Proc, free_port, rsal_cmd, wait_until

DOC = ROOT / "docs" / "protocol.md"
WORLD = str(MAPS / "testroom.world")
MARKER = "<!-- stock-client-example"
STDLIB_OK = {"__future__", "argparse", "json", "math", "struct", "sys", "time"}


def doc_example() -> str:
    """The fenced python block right after the example marker in docs/protocol.md."""
    text = DOC.read_text(encoding="utf-8")
    at = text.index(MARKER)
    m = re.compile(r"```python\n(.*?)```", re.S).search(text, at)
    assert m is not None, "docs/protocol.md: no ```python block after the example marker"
    return m.group(1)


def unpack(payload) -> dict:
    return msgpack.unpackb(payload.to_bytes())


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def server():
    port = free_port()
    proc = Proc(rsal_cmd("sim", WORLD, "--listen", f"tcp/127.0.0.1:{port}"))
    try:
        yield proc, port
    finally:
        proc.close()


@pytest.fixture(scope="module")
def session(server):
    """A bare Zenoh session, configured as docs/protocol.md tells a stock client to."""
    _, port = server
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    with zenoh.open(conf) as s:
        wanted = {"rsal/r0/laser/0", "rsal/r0/position2d/0", "rsal/sim/simulation/0"}

        def alive():
            return wanted <= {str(r.ok.key_expr) for r in s.liveliness().get("rsal/**", timeout=1.0) if r.ok}

        wait_until(alive, 30, "r0's devices and the simulation to be alive")
        yield s


def call(session, key: str, payload: bytes = b"") -> tuple[bool, dict]:
    """One raw query: (was it an error reply, decoded payload)."""
    replies = list(session.get(key, payload=payload, timeout=5.0))
    assert len(replies) == 1, f"{key}: expected one reply, got {len(replies)}"
    r = replies[0]
    return (False, unpack(r.ok.payload)) if r.ok is not None else (True, unpack(r.err.payload))


def latest(sub, what: str, timeout: float = 5.0) -> dict:
    return unpack(wait_until(sub.try_recv, timeout, what).payload)


# ---------------------------------------------------------------------------- (a) the example
def test_example_uses_only_zenoh_and_msgpack():
    tree = ast.parse(doc_example())
    top = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            top |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            top.add((node.module or "").split(".")[0])
    assert top - STDLIB_OK == {"zenoh", "msgpack"}


def test_stock_client_reads_the_laser_and_drives_r0(server, session, tmp_path):
    proc, port = server
    laser = call(session, "rsal/r0/laser/0/rpc/describe")[1]
    sensor = laser["geometry"]["sensors"][0]
    start = call(session, "rsal/sim/simulation/0/rpc/get_pose", msgpack.packb({"name": "r0"}))[1]["pose"]

    script = tmp_path / "stock_client.py"
    script.write_text(doc_example(), encoding="utf-8")
    out = subprocess.run(
        [sys.executable, str(script), "--connect", f"tcp/127.0.0.1:{port}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr

    # the scan it read has the laser's shape: one range per beam, spanning the field of view
    m = re.search(r"samples=(\d+) angle_min=(\S+) angle_step=(\S+) nearest=(\S+)", out.stdout)
    assert m, out.stdout
    n, amin, step, nearest = int(m[1]), float(m[2]), float(m[3]), float(m[4])
    assert n == sensor["samples"] == 682
    assert amin == pytest.approx(-sensor["fov"] / 2, abs=1e-4)
    assert amin + (n - 1) * step == pytest.approx(sensor["fov"] / 2, abs=1e-3)
    assert sensor["range_min"] <= nearest <= sensor["range_max"]

    # odometry changed by the requested 0.2 m, and the robot really moved in the world
    m = re.search(r"before=\((\S+), (\S+), (\S+)\) after=\((\S+), (\S+), (\S+)\)", out.stdout)
    assert m, out.stdout
    before, after = [float(x) for x in m.groups()[:3]], [float(x) for x in m.groups()[3:]]
    assert math.dist(before[:2], after[:2]) >= 0.2
    now = call(session, "rsal/sim/simulation/0/rpc/get_pose", msgpack.packb({"name": "r0"}))[1]["pose"]
    assert now[0] - start[0] > 0.15

    # its rpc/stop stopped the robot
    with session.declare_subscriber("rsal/r0/position2d/0/data", zenoh.handlers.RingChannel(1)) as sub:
        wait_until(lambda: (s := sub.try_recv()) and unpack(s.payload)["vel"][0] == 0.0, 5, "r0 to stand still")
    assert proc.alive()


# ---------------------------------------------------------------------------- (b) rpc errors
def test_error_codes_in_the_doc_are_the_implemented_ones():
    text = DOC.read_text(encoding="utf-8")
    table = text[text.index("### Error codes") : text.index("## Malformed input")]
    documented = set(re.findall(r"^\| `([a-z_]+)` \|", table, re.M))
    assert documented == {c.value for c in ErrorCode}


@pytest.mark.parametrize(
    ("key", "payload", "code", "words"),
    [
        ("rsal/r0/position2d/0/rpc/fly", b"", "unknown_op", ["fly", "describe", "set_odom", "motor_power", "stop"]),
        ("rsal/r0/laser/0/rpc/describe", b"\xc1", "bad_request", ["not msgpack"]),
        ("rsal/r0/laser/0/rpc/get", msgpack.packb([1, 2]), "bad_request", ["map"]),
        ("rsal/r0/position2d/0/rpc/set_odom", msgpack.packb({"pose": [1, 2]}), "bad_request", ["pose"]),
        ("rsal/r0/position2d/0/rpc/motor_power", msgpack.packb({"on": 1}), "bad_request", ["on"]),
        ("rsal/sim/simulation/0/rpc/step", msgpack.packb({"n": 0}), "bad_request", ["'n'"]),
        ("rsal/sim/simulation/0/rpc/get_pose", msgpack.packb({"name": "nobody"}), "not_found", ["nobody"]),
    ],
)
def test_rpc_errors_are_the_documented_envelope(session, key, payload, code, words):
    is_err, reply = call(session, key, payload)
    assert is_err, f"{key} answered {reply}"
    assert set(reply) == {"ok", "code", "message"}
    assert reply["ok"] is False and reply["code"] == code
    assert isinstance(reply["message"], str) and "\n" not in reply["message"]
    for w in words:
        assert w in reply["message"]


def test_wildcard_op_is_answered_as_describe(session):
    replies = list(session.get("rsal/r0/**", timeout=5.0, target=zenoh.QueryTarget.ALL))
    keys = sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)
    assert "rsal/r0/laser/0/rpc/describe" in keys and "rsal/r0/position2d/0/rpc/describe" in keys
    assert all(k.startswith("rsal/r0/") and k.endswith("/rpc/describe") for k in keys)
    for r in replies:
        d = unpack(r.ok.payload)
        assert d["ok"] is True and d["node"] == "r0" and d["protocol"] == 1 and d["ops"][0] == "describe"


# ---------------------------------------------------------------------------- (c) malformed cmd
def test_malformed_cmd_is_dropped_with_a_warning_and_changes_nothing(server, session):
    proc, _ = server
    base = "rsal/r0/position2d/0"
    assert call(session, f"{base}/rpc/stop") == (False, {"ok": True})
    with session.declare_subscriber(f"{base}/data", zenoh.handlers.RingChannel(1)) as sub:
        wait_until(lambda: (s := sub.try_recv()) and unpack(s.payload)["vel"] == [0.0, 0.0, 0.0], 5, "r0 at rest")
        rest = latest(sub, "position2d data")

        junk = [
            b"\xc1\xff garbage",
            msgpack.packb([0.3, 0.0]),
            msgpack.packb({"v": "fast", "w": 0.0}),
            msgpack.packb({"v": float("nan"), "w": 0.0}),
            msgpack.packb({"w": 0.5}),
            msgpack.packb({"v": 99.0, "w": 0.0}),
            msgpack.packb({"v": 0.3, "w": 0.0, "vy": 0.2}),
        ]
        for j in junk:
            session.put(f"{base}/cmd", j)
        wait_until(lambda: f"rejected cmd on {base}/cmd:" in proc.output(), 5, "the documented warning")

        # a full simulated second later the robot has not moved
        later = wait_until(
            lambda: (s := sub.try_recv()) and (m := unpack(s.payload))["t"] >= rest["t"] + 1.0 and m,
            5,
            "a position2d sample one simulated second later",
        )
        assert later["pose"] == rest["pose"] and later["vel"] == [0.0, 0.0, 0.0]

        # the server keeps serving: a well-formed command turns the robot
        def turned():
            session.put(f"{base}/cmd", msgpack.packb({"v": 0.0, "w": 0.5}))
            s = sub.try_recv()
            return s is not None and abs(unpack(s.payload)["pose"][2] - rest["pose"][2]) > 0.1

        wait_until(turned, 5, "r0 to turn on a valid command", interval=0.1)
    assert call(session, f"{base}/rpc/stop") == (False, {"ok": True})
    assert proc.alive() and "Traceback" not in proc.output()


# ---------------------------------------------------------------------------- (d) removed robot
def test_a_removed_robot_answers_unavailable_until_reset(session):
    sim = "rsal/sim/simulation/0/rpc"
    assert call(session, f"{sim}/remove_model", msgpack.packb({"name": "r0"})) == (False, {"ok": True})
    try:
        assert call(session, f"{sim}/models")[1]["robots"] == []
        for key in ("rsal/r0/laser/0/rpc/get", "rsal/r0/position2d/0/rpc/stop", "rsal/r0/gripper/0/rpc/open"):
            is_err, reply = call(session, key)
            assert is_err and reply["code"] == "unavailable" and "removed" in reply["message"], key
        # its devices are withdrawn (docs/protocol.md: "their tokens go (clients see them lost)")
        alive = {str(r.ok.key_expr) for r in session.liveliness().get("rsal/r0/**", timeout=1.0) if r.ok}
        assert alive == set()
    finally:
        assert call(session, f"{sim}/reset")[0] is False
    assert call(session, f"{sim}/models")[1]["robots"] == ["r0"]
    assert call(session, "rsal/r0/position2d/0/rpc/stop") == (False, {"ok": True})
    alive = {str(r.ok.key_expr) for r in session.liveliness().get("rsal/r0/**", timeout=1.0) if r.ok}
    assert "rsal/r0/laser/0" in alive
