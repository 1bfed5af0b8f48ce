"""Multi-process integration: ``rsal sim`` in one process, a client in this one, real Zenoh.

(a) discover r0's devices by template, (b) drive a robot and see odometry change, (c) SIGKILL the
server and see every device reported lost within 2 s, (d) restart it and see them return,
(e) flood every cmd/rpc key with malformed payloads: the server keeps serving correct requests.
"""

from __future__ import annotations

import math
import time

import msgpack
import pytest

from rsal import keys
from rsal.keys import DeviceAddr
from rsal.msgs import ErrorCode, RpcError
from tests.conftest import MAPS, rsal_cmd, wait_until

WORLD = str(MAPS / "testroom.world")
R0 = {
    ("position2d", 0),
    ("ranger", 0),
    ("ranger", 1),
    ("sonar", 0),
    ("laser", 0),
    ("blobfinder", 0),
    ("gripper", 0),
    ("power", 0),
}


def start_sim(procs, port, *extra):
    return procs(rsal_cmd("sim", WORLD, "--listen", f"tcp/127.0.0.1:{port}", *extra))


def test_discover_drive_kill_restart(procs, port, fabric_factory):
    server = start_sim(procs, port)
    fab = fabric_factory(port)
    node = fab.node("r0:*:*")
    found = node.wait_for("r0:*:*", count=len(R0), timeout=30)
    assert {(a.interface, a.index) for a in found} == R0

    # describe answers with interface, index, geometry and driver
    d = fab.device("r0:laser:0").describe()
    assert (d.node, d.interface, d.index, d.driver) == ("r0", "laser", 0, "sim")
    assert d.geometry["sensors"][0]["samples"] == 682

    # (b) drive and see odometry change
    pos = node.device("r0:position2d:0")
    first = pos.wait_for_data(10)
    assert first.pose == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    pos.set_velocity(0.3, 0.0)
    wait_until(lambda: pos.latest.pose[0] > 0.2, 10, "odometry x to grow while driving")
    pos.stop()

    # the laser streams 682 ranges
    laser = node.device("r0:laser:0")
    scan = laser.wait_for_data(5)
    assert scan.ranges.shape == (682,) and 0.02 <= float(scan.ranges.min()) <= 5.6

    # (c) SIGKILL: every device is reported lost within 2 s
    lost: list = []
    node.on_leave(lost.append)
    t0 = time.monotonic()
    server.kill()
    wait_until(lambda: not node.devices(), 2.0, "all r0 devices to be reported lost")
    assert time.monotonic() - t0 <= 2.0
    wait_until(lambda: not pos.alive, 1.0, "the position2d proxy to be marked lost")

    # (d) restart: they come back, and the same proxy receives data again
    start_sim(procs, port)
    node.wait_for("r0:*:*", count=len(R0), timeout=30)
    wait_until(lambda: pos.alive, 5, "the proxy to be alive again")
    n = pos.count
    pos.wait_for_data(10, newer_than=n)


def test_malformed_input_never_kills_the_server(procs, port, fabric_factory):
    server = start_sim(procs, port)
    fab = fabric_factory(port)
    node = fab.node("**")
    devs = node.wait_for("**", count=len(R0) + 2, timeout=30)
    s = fab.session
    junk = [
        b"",
        b"\xc1\xff\x00garbage",
        msgpack.packb([1, 2, 3]),
        msgpack.packb("text"),
        msgpack.packb({"v": "fast", "w": 0}),
        msgpack.packb({"v": float("nan"), "w": 0.0}),
        msgpack.packb({"v": float("inf"), "w": 0.0}),
        msgpack.packb({"v": 99.0, "w": 0.0}),
        msgpack.packb({"w": 0.1}),
        msgpack.packb({"action": "explode"}),
        msgpack.packb({"name": 5, "pose": [1, 2]}),
        msgpack.packb({"pose": ["a", None, 3]}),
        bytes(range(256)) * 40,
    ]
    for _ in range(3):
        for a in devs:
            for j in junk:
                s.put(keys.cmd_key(a), j)
    # rpc: every op name the devices have, plus unknown ones, with junk payloads
    errors = []
    for a in devs:
        for op in ("describe", "set_odom", "set_pose", "get_pose", "get", "step", "nonsense"):
            for j in junk[1:6]:
                try:
                    fab.rpc(a, op, None, timeout=2.0) if j == b"" else _raw_rpc(s, a, op, j)
                except RpcError as e:
                    errors.append(e.code)
    assert server.alive()
    assert set(errors) <= {
        ErrorCode.BAD_REQUEST,
        ErrorCode.UNKNOWN_OP,
        ErrorCode.OUT_OF_RANGE,
        ErrorCode.NOT_FOUND,
        ErrorCode.UNAVAILABLE,
    }
    assert ErrorCode.BAD_REQUEST in errors and ErrorCode.UNKNOWN_OP in errors
    # the robot did not move from junk commands, and still obeys a correct one
    pos = node.device("r0:position2d:0")
    assert pos.wait_for_data(5).pose == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    pos.set_velocity(0.0, 0.5)
    wait_until(lambda: abs(pos.latest.pose[2]) > 0.3, 10, "the robot to turn on a valid command")
    pos.stop()
    assert fab.device("r0:laser:0").describe().interface == "laser"
    # an out-of-range rpc is a typed error, and the model survives a bad set_pose
    sim = node.device("sim:simulation:0")
    with pytest.raises(RpcError) as ei:
        sim.rpc("set_pose", name="nobody", pose=[0, 0, 0])
    assert ei.value.code == ErrorCode.NOT_FOUND
    with pytest.raises(RpcError) as ei:
        sim.rpc("set_pose", name="r0", pose=[0, math.nan, 0])
    assert ei.value.code == ErrorCode.BAD_REQUEST
    # get_poses: many true poses at one simulated instant; bad names are typed errors
    every = sim.rpc("get_poses")
    assert every["names"] == ["r0"] and every["poses"][0] == pytest.approx(sim.rpc("get_pose", name="r0")["pose"])
    assert sim.rpc("get_poses", names=["r0", "r0"])["poses"][1] == pytest.approx(every["poses"][0], abs=0.5)
    for bad, code in ((["nobody"], ErrorCode.NOT_FOUND), ("r0", ErrorCode.BAD_REQUEST), ([1], ErrorCode.BAD_REQUEST)):
        with pytest.raises(RpcError) as ei:
            sim.rpc("get_poses", names=bad)
        assert ei.value.code == code, bad
    assert server.alive()
    out = server.output()
    assert "Traceback" not in out


def _raw_rpc(session, addr: DeviceAddr, op: str, payload: bytes):
    from rsal.msgs import parse_reply

    key = keys.rpc_key(addr, op)
    for r in session.get(key, payload=payload, timeout=2.0):
        if r.ok is not None:
            return parse_reply(r.ok.payload.to_bytes(), key=key)
        return parse_reply(r.err.payload.to_bytes(), is_error=True, key=key)
    raise RpcError(ErrorCode.TIMEOUT, "no reply", key)
