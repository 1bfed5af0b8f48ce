"""The simulator's ``crowd`` device and publishing only what someone listens to.

An in-process simulator server (its world in this process, so ground truth is the world itself)
on a loopback Zenoh session; clients on a second session. Three robots: two Pioneer 2DX (8
sonars; r1 reports ground truth, ``localization = "gps"``) and a Pioneer 3AT (16 sonars).

- crowd ``data`` carries, row by row, exactly what the robots' own ``position2d:0`` and
  ``sonar:0`` samples of the same step carry;
- crowd ``cmd`` moves robots (ground truth), each row through its robot's safety path: the robot
  stops when crowd commands stop (command timeout), a latched emergency stop refuses its row;
  malformed commands are warned about, and the server serves on;
- a device's ``data`` is built and put only while a subscriber matches it: none is built without
  one, and a subscriber declared later receives data; a robot none of whose data devices is read
  is passed over by one flag (its battery still reports);
- declaring devices starts no thread per device (their callbacks run on Zenoh's threads), and
  their rpcs and commands still work.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import replace

import msgpack
import numpy as np
import pytest
from bridge_helpers import LiveServer

import mrs_bridge.drivers  # noqa: F401  (registers the built-in drivers)
from mrs_bridge.cli import sim_config
from mrs_bridge.drivers import simmsgs
from mrs_bridge.drivers.sim import WORLD_KEY
from rsal import keys
from rsal.interfaces.crowd import CrowdCmd, CrowdData, CrowdLayout
from rsal.interfaces.position2d import Position2dData
from rsal.interfaces.ranger import RangerData
from rsal.keys import DeviceAddr
from simulator.presets import pioneer2dx, pioneer3at
from simulator.spec import WorldSpec
from simulator.world import World
from tests.conftest import free_port, wait_until

CROWD = DeviceAddr("sim", "crowd", 0)


def _world() -> World:
    r0 = pioneer2dx("r0", (0.0, 0.0, 0.0))
    r1 = replace(pioneer2dx("r1", (3.0, 0.0, 1.0)), localization="gps")
    r2 = pioneer3at("r2", (0.0, 3.0, -1.0))
    return World(WorldSpec(models=[r0, r1, r2], interval_sim=0.1, speedup=4.0), seed=5)


@pytest.fixture
def sim():
    world, port = _world(), free_port()
    srv = LiveServer(sim_config(world, map_device=False), port=port, shared={WORLD_KEY: world})
    srv.world, srv.port = world, port
    srv.start()
    yield srv
    srv.close()


@pytest.fixture
def client(sim, fabric_factory):
    fab = fabric_factory(sim.port)
    # simulation, crowd; 3 robots x (position2d, ranger, sonar, power)
    fab.node("**").wait_for("**", count=2 + 3 * 4, timeout=20)
    return fab


def _collector(session, key: str):
    got: list[tuple[str, bytes]] = []
    lock = threading.Lock()

    def on(s):
        with lock:
            got.append((str(s.key_expr), s.payload.to_bytes()))

    sub = session.declare_subscriber(key, on)
    return got, lock, sub


def test_describe_lists_the_robots_in_order_with_their_ranger_geometry(sim, client):
    lay = client.device(CROWD).layout()
    assert lay.robots == ["r0", "r1", "r2"]
    assert lay.frames == ["odom", "gps", "odom"]
    assert lay.offsets == [0, 8, 16, 32]  # 8, 8 and 16 sonars
    for i, r in enumerate(lay.robots):  # the geometry each robot's own sonar:0 reports
        assert lay.rangers[lay.ranger_of[i]] == client.device(f"{r}:sonar:0").describe().geometry
    beams, rmax = lay.beams(2)
    assert beams.shape == (16, 4) and rmax == pytest.approx(5.0)


def test_crowd_data_equals_the_robots_own_samples_of_the_same_step(sim, client):
    crowd = client.device(CROWD)
    crowd.layout()
    crowd.command([0, 1, 2], [0.3, 0.2, 0.1], [0.2, -0.3, 0.4])  # moving, so that the steps differ
    got, lock, sub = _collector(client.session, "rsal/**/data")
    try:
        wait_until(lambda: sum(k.endswith("crowd/0/data") for k, _ in list(got)) >= 8, 20, "8 crowd messages")
        crowd.command([0, 1, 2], [0.0] * 3, [0.0] * 3)
    finally:
        sub.undeclare()
    with lock:
        samples = list(got)
    pos: dict[tuple[str, float], Position2dData] = {}
    scans: dict[tuple[str, float], RangerData] = {}
    crowds: list[CrowdData] = []
    for k, b in samples:
        node, iface = k.split("/")[1:3]
        if iface == "crowd":
            crowds.append(CrowdData.from_bytes(b))
        elif iface == "position2d":
            m = Position2dData.from_bytes(b)
            pos[(node, m.t)] = m
        elif iface == "sonar":
            m = RangerData.from_bytes(b)
            scans[(node, float(np.float32(m.t)))] = m
    compared = 0
    for c in crowds:
        for i, r in enumerate(("r0", "r1", "r2")):
            p = pos.get((r, c.t))
            if p is None:
                continue
            compared += 1
            np.testing.assert_array_equal(c.pose[i], np.float32(p.pose))
            np.testing.assert_array_equal(c.vel[i], np.float32((p.vel[0], p.vel[2])))
            assert bool(c.stall[i]) == p.stall
            s = scans[(r, float(c.scan_t[i]))]  # the sample of the scan the crowd row carries
            np.testing.assert_array_equal(c.scan(i), s.ranges)
    assert compared >= 12, f"only {compared} crowd rows had a position2d sample of the same step"
    assert any(abs(c.pose[0][0]) > 1e-3 for c in crowds), "r0 should have moved"


def test_crowd_cmd_moves_robots_and_they_stop_when_commands_stop(sim, client):
    crowd = client.device(CROWD)
    crowd.layout()
    w = sim.world
    start = {r: w.get_pose(r) for r in ("r0", "r1", "r2")}
    t_end = time.monotonic() + 1.0
    while time.monotonic() < t_end:  # a control cycle at 10 Hz for r0 and r2 only
        crowd.command([0, 2], [0.4, 0.4], [0.0, 0.0])
        time.sleep(0.1)
    moved = {r: math.dist(w.get_pose(r)[:2], start[r][:2]) for r in start}
    assert moved["r0"] > 0.3 and moved["r2"] > 0.3, moved
    assert moved["r1"] < 1e-6, moved
    # commands stop: the command timeout (0.5 simulated s) stops both robots
    wait_until(lambda: w.velocity("r0") == (0.0, 0.0) and w.velocity("r2") == (0.0, 0.0), 5, "robots to stop")
    assert sim.driver("sim").guard.timed_out  # the block of r0 comes first


def test_a_latched_estop_refuses_its_row_and_the_others_still_move(sim, client, caplog):
    crowd = client.device(CROWD)
    crowd.layout()
    client.device("r1:position2d:0").rpc("estop")
    w = sim.world
    start = {r: w.get_pose(r) for r in ("r0", "r1")}
    with caplog.at_level(logging.WARNING):
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end:
            crowd.command([0, 1], [0.4, 0.4], [0.0, 0.0])
            time.sleep(0.1)
        wait_until(lambda: "refused the row of r1" in caplog.text, 5, "a warning naming r1's row")
    assert math.dist(w.get_pose("r0")[:2], start["r0"][:2]) > 0.3
    assert math.dist(w.get_pose("r1")[:2], start["r1"][:2]) < 1e-6
    assert "emergency stop of r1 is latched" in caplog.text


def test_malformed_crowd_commands_are_warned_about_and_change_nothing(sim, client, caplog):
    crowd = client.device(CROWD)
    crowd.layout()
    key = keys.cmd_key(CROWD)
    bad = [
        b"\xc1",  # not msgpack
        msgpack.packb({"idx": b"\x00\x00\x00\x00", "v": b"\x00" * 8}),  # no w
        msgpack.packb({"idx": np.int32([7]).tobytes(), "v": np.float64([0.1]).tobytes(), "w": b"\x00" * 8}),
        msgpack.packb({"idx": np.int32([0]).tobytes(), "v": np.float64([math.nan]).tobytes(), "w": b"\x00" * 8}),
        msgpack.packb({"idx": np.int32([0]).tobytes(), "v": np.float64([9.0]).tobytes(), "w": b"\x00" * 8}),
    ]
    rejected = sim.server.stats["rejected"]
    with caplog.at_level(logging.WARNING):
        for b in bad:
            client.session.put(key, b)
        # the first four are rejected whole (one rate-limited warning per key), the last one's row is refused
        wait_until(lambda: sim.server.stats["rejected"] >= rejected + 4, 5, "four rejected commands")
        wait_until(lambda: "refused the row of r0: v=9 m/s" in caplog.text, 5, "a warning for the row over the limit")
    assert "rejected cmd on rsal/sim/crowd/0/cmd" in caplog.text
    assert sim.world.velocity("r0") == (0.0, 0.0)
    crowd.command([0], [0.2], [0.0])  # the server still serves
    wait_until(lambda: sim.world.velocity("r0")[0] == pytest.approx(0.2), 5, "r0 to take a good command")
    assert sim.thread.is_alive() and sim.error is None


def test_data_is_built_only_while_someone_listens(sim, client, monkeypatch):
    built = {"n": 0}
    real = simmsgs.ranger_data

    def counting(r):
        built["n"] += 1
        return real(r)

    monkeypatch.setattr(simmsgs, "ranger_data", counting)
    stats = sim.server.stats
    w = sim.world
    t0, p0 = w.time, stats["published"]
    wait_until(lambda: w.time >= t0 + 1.0, 10, "a simulated second")
    assert built["n"] == 0, "scans were built while nobody subscribed"
    assert stats["published"] == p0, "data was put while nobody subscribed"

    # a subscriber declared now gets data from the next steps on
    got, lock, sub = _collector(client.session, "rsal/r2/sonar/0/data")
    try:
        wait_until(lambda: len(got) >= 3, 10, "scans at the late subscriber")
    finally:
        sub.undeclare()
    assert built["n"] >= 3
    assert all(len(RangerData.from_bytes(b).ranges) == 16 for _, b in got)
    # it left: building stops again
    wait_until(lambda: not sim.server.devices[DeviceAddr("r2", "sonar", 0)].listened, 5, "the match to end")
    n = built["n"]
    t1 = w.time
    wait_until(lambda: w.time >= t1 + 0.5, 10, "half a simulated second")
    assert built["n"] == n


def test_crowd_layout_and_messages_round_trip():
    sonar = {"kind": "sonar", "pose": [0, 0, 0], "sensors": []}
    lay = CrowdLayout(["a", "b"], ["odom", "gps"], [sonar], [0, -1], [0, 0, 0], [[0.5, 1.0], [0.5, 1.0]])
    assert CrowdLayout.from_dict(msgpack.unpackb(msgpack.packb(lay.to_dict()))) == lay
    c = CrowdCmd(np.int32([1, 0]), np.float64([0.1, 0.2]), np.float64([0.0, -0.1]))
    back = CrowdCmd.from_bytes(c.to_msgpack())
    assert back.idx.tolist() == [1, 0] and back.v.tolist() == [0.1, 0.2] and back.w.tolist() == [0.0, -0.1]


def test_a_robot_nobody_reads_is_passed_over_by_one_flag_and_its_battery_still_reports(sim, client):
    from mrs_bridge.drivers.sim import SimDriver

    drv = {d.model: d for d in sim.server.drivers_of(SimDriver)}
    wait_until(lambda: all(d._heard is not None for d in drv.values()), 10, "the robots' first step")
    assert not any(d._heard.any for d in drv.values())
    got_p, _, sub_p = _collector(client.session, "rsal/r0/position2d/0/data")
    got_s, _, sub_s = _collector(client.session, "rsal/r0/sonar/0/data")
    got_b, _, sub_b = _collector(client.session, "rsal/r1/power/0/data")  # outside the flag: every step
    try:
        wait_until(lambda: len(got_p) >= 2 and len(got_s) >= 2, 10, "r0's pose and scans")
        assert drv["r0"]._heard.any and not drv["r1"]._heard.any and not drv["r2"]._heard.any
        wait_until(lambda: len(got_b) >= 1, 10, "r1's battery report (once per simulated second)")
        sub_p.undeclare()
        sub_p = None
        wait_until(lambda: not sim.server.devices[DeviceAddr("r0", "position2d", 0)].listened, 5, "the match to end")
        assert drv["r0"]._heard.any  # its sonar is still read
        n = len(got_s)
        wait_until(lambda: len(got_s) >= n + 2, 10, "scans after the pose's reader left")
    finally:
        for sub in (sub_p, sub_s, sub_b):
            if sub is not None:
                sub.undeclare()
    wait_until(lambda: not drv["r0"]._heard.any, 5, "r0's flag to drop with its last reader")


def test_declaring_devices_starts_no_thread_per_device(fabric_factory):
    import os

    robots = [pioneer2dx(f"r{i}", (1.5 * i, 0.0, 0.0)) for i in range(20)]
    world, port = World(WorldSpec(models=robots, interval_sim=0.1, speedup=4.0), seed=1), free_port()
    srv = LiveServer(sim_config(world, map_device=False), port=port, shared={WORLD_KEY: world})
    before = len(os.listdir("/proc/self/task"))
    srv.start()  # 82 devices, each with a cmd subscriber, an rpc queryable and a matching listener
    try:
        fab = fabric_factory(port)
        fab.node("**").wait_for("**", count=2 + 20 * 4, timeout=30)
        added = len(os.listdir("/proc/self/task")) - before
        # the scheduler thread and the client fabric's few; a thread per callback would be 246
        assert added < 40, added
        # the callbacks on Zenoh's threads still answer: an rpc and a command of the last robot
        pos = fab.device("r19:position2d:0")
        assert pos.describe().interface == "position2d"
        x0 = world.get_pose("r19")[0]
        wait_until(lambda: (pos.set_velocity(0.3, 0.0), world.get_pose("r19")[0] > x0 + 0.05)[1], 10, "r19 to move")
    finally:
        srv.close()
