"""The ``p2os`` driver (mrs_bridge/drivers/p2os.py): the P2OS packet codec against hand-computed
frames, SIP decoding and odometry wrap-around, parameter validation, and the driver in a device
server on loopback Zenoh talking to a Pioneer emulator on a pseudo-terminal (mrs_bridge/emulators/p2os.py)."""

from __future__ import annotations

import logging
import math
import struct
import textwrap
import time
from pathlib import Path

import pytest
from bridge_helpers import LiveServer

from mrs_bridge.config import ConfigError, load_config, parse_config
from mrs_bridge.driver import DRIVERS
from mrs_bridge.drivers import p2os
from mrs_bridge.drivers.p2os import (
    MODELS,
    Odometry,
    P2osDriver,
    PacketReader,
    Sip,
    checksum,
    command,
    decode_sip,
    packet,
)
from mrs_bridge.emulators.p2os import PioneerEmulator
from rsal.interfaces.power import lead_acid_fraction
from rsal.keys import parse_device
from rsal.msgs import DioCmd, ErrorCode, GripperCmd, RpcError, VelocityCmd
from tests.conftest import ROOT, free_port, wait_until

WHERE = "p2os.toml: driver #1 (p2os)"


# ---------------------------------------------------------------------------- packets
@pytest.mark.parametrize(
    ("payload", "expected"),
    [
        (b"\x00", 0x0000),
        (b"\x01", 0x0001),
        (b"\x04\x3b\x01\x00", 0x053B),  # ENABLE 1: 0x043B + 0x0100
        (b"\x0b\x1b\x64\x00", 0x6F1B),  # VEL -100: 0x0B1B + 0x6400
        (b"\xff\xff\xff\xff\x01", 0xFFFF),  # 0xFFFF + 0xFFFF = 0x1FFFE -> 0xFFFE, xor 0x01
        (b"\x12\x34\x56", 0x1262),  # 0x1234, then 0x56 xor'd in
    ],
)
def test_checksum_known_values(payload, expected):
    assert checksum(payload) == expected


def test_commands_frame_exactly():
    assert command(p2os.SYNC0) == bytes.fromhex("fafb03000000")
    assert command(p2os.OPEN) == bytes.fromhex("fafb03010001")
    assert command(p2os.ENABLE, 1) == bytes.fromhex("fafb06043b0100053b")
    assert command(p2os.VEL, -100) == bytes.fromhex("fafb060b1b64006f1b")
    assert command(p2os.RVEL, 300) == bytes.fromhex("fafb06153b2c01") + (0x153B + 0x2C01).to_bytes(2, "big")
    assert command(7, "ab") == packet(b"\x07\x2b\x02ab")
    with pytest.raises(ValueError, match="does not fit in 2 bytes"):
        command(p2os.VEL, 70000)


def test_reader_resyncs_over_garbage_bad_checksums_and_truncated_frames():
    good = [packet(bytes([0x32, i, 2, 3])) for i in range(4)]
    bad = bytearray(good[1])
    bad[-1] ^= 0xFF
    truncated = good[2][:5]
    stream = b"\x13\x37\xfa" + good[0] + bytes(bad) + truncated + good[3] + b"\xfa\xfb\xff\x00"
    r = PacketReader()
    out = []
    for i in range(0, len(stream), 3):  # split at arbitrary places
        out += r.feed(stream[i : i + 3])
    assert out == [bytes([0x32, 0, 2, 3]), bytes([0x32, 3, 2, 3])]
    assert r.bad == 3  # bad checksum, truncated frame running into the next, impossible count 0xff
    assert r.skipped >= 3 + 2
    assert r.packets == 2


# ---------------------------------------------------------------------------- SIPs and odometry
def sip_bytes(x=0, y=0, th=0, lv=0, rv=0, batt=121, sb=0, flags=1, sonars=(), tail=True) -> bytes:
    b = struct.pack("<BHHhhhBHhHB", 0x33, x, y, th, lv, rv, batt, sb, 0, flags, 0)
    b += bytes([len(sonars)]) + b"".join(struct.pack("<BH", n, r) for n, r in sonars)
    if tail:
        b += bytes([0, 0b0101_0110, 200, 0xA5, 0x03]) + struct.pack("<H", 124) + b"\x01"  # TIMER high byte: gripper
    return b


def test_sip_decoding_by_hand():
    raw = bytes.fromhex("333412010000089cff640079010100000100000200f40107e803")
    s = decode_sip(raw + bytes([0, 0b0101_0110, 200, 0xA5, 0x03, 124, 0, 1]))  # TIMER (gripper in its high byte)
    assert (s.moving, s.xpos, s.ypos, s.thpos, s.l_vel, s.r_vel) == (True, 0x1234, 1, 0x800, -100, 100)
    assert s.battery == 121 and s.stalled and s.motors_enabled
    assert s.sonars == ((0, 500), (7, 1000))
    assert (s.gripper, s.analog, s.digin, s.digout, s.battery_x10, s.charge_state) == (0x56, 200, 0xA5, 3, 124, 1)
    assert s.volts == pytest.approx(12.4)
    short = decode_sip(raw)  # an older firmware ends after the sonars
    assert short.gripper is None and short.volts == pytest.approx(12.1)
    with pytest.raises(ValueError, match="announces 2 sonar readings"):
        decode_sip(raw[:-3])
    with pytest.raises(ValueError, match="not a standard SIP"):
        decode_sip(b"\x20" + raw[1:])


def test_odometry_is_continuous_over_counter_wrap_around():
    m = MODELS["p2dx"]
    odo = Odometry(m)
    odo.update(decode_sip(sip_bytes(x=32760, y=5, th=4090)))
    pose = odo.update(decode_sip(sip_bytes(x=5, y=32763, th=6)))  # +13 and -10 counts, +12 heading units
    assert pose[0] == pytest.approx(13 * m.dist_conv / 1000)
    assert pose[1] == pytest.approx(-10 * m.dist_conv / 1000)
    assert pose[2] == pytest.approx(12 * 2 * math.pi / 4096)
    odo.reset_reference()  # reconnected: the robot restarted its counters, the pose does not jump
    assert odo.update(decode_sip(sip_bytes(x=0, y=0, th=0))) == pose
    odo.set_pose(1.0, 2.0, math.pi / 2)  # turns the reported frame by pi/2 - yaw
    x, y, a = odo.update(decode_sip(sip_bytes(x=1000, y=0, th=0)))  # along the counters' x axis
    turn, d = math.pi / 2 - pose[2], 1000 * m.dist_conv / 1000
    assert (x, y, a) == pytest.approx((1.0 + d * math.cos(turn), 2.0 + d * math.sin(turn), math.pi / 2))


# ---------------------------------------------------------------------------- configuration
def make(params: str) -> P2osDriver:
    text = f'[[driver]]\nname = "p2os"\nprovides = ["r0:position2d:0"]\n{textwrap.dedent(params)}'
    return P2osDriver(parse_config(text, source="p2os.toml").drivers[0], object())


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        ("", "needs 'port', the robot's serial device (e.g. port = \"/dev/ttyS0\")"),
        ('port = "/dev/ttyS0"\nbuad = 9600', "unknown parameter 'buad'; did you mean 'baud'?"),
        ('port = "/dev/ttyS0"\nbaud = 1200', "baud = 1200 must be one of 9600, 19200, 38400, 57600, 115200"),
        ('port = "/dev/ttyS0"\nmodel = "p2dz"', "model = 'p2dz' must be one of p2dx, p3at; did you mean 'p2dx'?"),
        ('port = "/dev/ttyS0"\ntimeout = 0', "timeout = 0 must be a number of seconds in [0.2, 30]"),
        ('port = "/dev/ttyS0"\nsonars = 12', "sonars = 12 must be 8 or 16 (transducers fitted)"),
    ],
)
def test_bad_parameters_are_named_with_a_fix(params, expected):
    with pytest.raises(ConfigError) as ei:
        make(params)
    assert str(ei.value) == f"{WHERE}: {expected}"


def test_registered_and_the_pioneer_config_loads():
    import mrs_bridge.drivers  # noqa: F401

    assert DRIVERS["p2os"] is P2osDriver
    cfg = load_config(ROOT / "deploy" / "pioneer2dx-urg.toml")
    p = next(d for d in cfg.drivers if d.name == "p2os")
    assert {str(a.without_key()) for a in p.provides} == {
        f"r0:{i}:0" for i in ("position2d", "sonar", "power", "gripper", "dio", "actarray")
    }
    P2osDriver(p, object())  # parameters valid
    h = next(d for d in cfg.drivers if d.name == "hokuyo")
    assert h.params["model"] == "URG-04LX" and {a.interface for a in h.provides} == {"ranger"}


# ---------------------------------------------------------------------------- against the emulator
CONFIG = """
[server]
node = "r0"

[[driver]]
name = "p2os"
provides = ["odometry::position2d:0", "sonar:0", "power:0", "gripper::gripper:0", "lift::actarray:0", "dio:0"]
port = "{port}"
pulse = 0.2
timeout = 1.0
reconnect = 0.1
"""

DEVICES = [parse_device(f"r0:{i}:0") for i in ("position2d", "sonar", "power", "gripper", "actarray", "dio")]


@pytest.fixture
def robot():
    emu = PioneerEmulator("P2DX")
    yield emu
    emu.close()


@pytest.fixture
def served(robot, fabric_factory):
    port = free_port()
    srv = LiveServer(CONFIG.format(port=robot.path), port=port, source="pioneer.toml", drivers=DRIVERS).start()
    fab = fabric_factory(port)
    node = fab.node("r0/**")
    yield srv, fab, node
    srv.close()


def test_connects_and_publishes_every_device(robot, served):
    srv, fab, node = served
    node.wait_for("r0/**", count=len(DEVICES), timeout=15)
    assert set(node.devices()) == set(DEVICES)
    drv = srv.driver("p2os")
    assert drv.ident == ("emu", "Pioneer", "P2DX") and drv.model is MODELS["p2dx"]
    assert robot.motors and robot.sonar_on  # OPEN, SONAR 1, ENABLE 1 after the handshake
    wait_until(lambda: len(robot.commands(p2os.PULSE)) >= 4, 10, "keep-alive pulses every 0.2 s")
    sonar = fab.device("r0:sonar:0").wait_for_data(10)
    assert len(sonar.ranges) == 8
    assert sonar.ranges.tolist() == pytest.approx(robot.sonar_table)
    geo = fab.device("r0:sonar:0").describe().geometry
    assert geo["kind"] == "sonar" and len(geo["sensors"]) == 8
    assert geo["sensors"][0]["pose"] == pytest.approx([0.115, 0.130, math.pi / 2])
    power = fab.device("r0:power:0").wait_for_data(10)
    assert power.volts == pytest.approx(12.3) and 0 < power.percent < 100
    grip = fab.device("r0:gripper:0").wait_for_data(10)
    assert (grip.paddles, grip.lift) == ("open", "down")
    # user inputs 0x81; the gripper's paddle contacts released (bits 4, 5 high), no beam broken
    assert fab.device("r0:dio:0").wait_for_data(10)["bits"] == 0b1011_0001
    lift = fab.device("r0:actarray:0")
    assert lift.wait_for_data(10)["positions"] == [0.0]
    assert lift.rpc("set_position", joint=0, position=1.0) == {"ok": True, "position": 1.0}
    wait_until(lambda: lift.latest["positions"] == [1.0], 10, "the lift to be up")
    assert robot.commands(p2os.GRIPPER) == [p2os.LIFT_UP]


def test_power_charge_from_the_sip_voltage_and_the_low_battery_event(robot, served):
    """The charge comes from the SIP's battery voltage by the lead-acid curve the simulator uses;
    falling below ``low_battery`` (20 %) sends the low event once, charging sends recovered."""
    srv, fab, node = served
    power = fab.device("r0:power:0")
    events: list[dict] = []
    power.add_event_listener(events.append)
    first = power.wait_for_data(10)
    assert first.percent == pytest.approx(100 * lead_acid_fraction(12.3)) and not first.low
    robot.battery = 11.6  # 10 % by the curve
    wait_until(lambda: power.latest.low and power.latest.percent == pytest.approx(10.0, abs=0.5), 10, "low data")
    wait_until(lambda: [e["event"] for e in events] == ["low"], 10, "one low event")
    assert events[0]["threshold"] == 20.0 and events[0]["volts"] == pytest.approx(11.6)
    robot.battery = 12.5  # about 76 %
    wait_until(lambda: [e["event"] for e in events] == ["low", "recovered"], 10, "the recovered event")
    assert not power.latest.low


@pytest.mark.parametrize(("subclass", "sonars"), [("P3AT", 16), ("P2DE", None)])
def test_the_model_follows_the_announced_subclass(subclass, sonars, fabric_factory, caplog):
    emu = PioneerEmulator("P3AT" if sonars else "P2DX", sonars=sonars or 8)
    emu.subclass_announced = subclass
    port = free_port()
    srv = LiveServer(CONFIG.format(port=emu.path), port=port, source="pioneer.toml", drivers=DRIVERS).start()
    try:
        if sonars:
            fab = fabric_factory(port)
            sonar = fab.device("r0:sonar:0")
            assert len(sonar.wait_for_data(15).ranges) == 16
            assert srv.driver("p2os").model is MODELS["p3at"]
            assert len(sonar.describe().geometry["sensors"]) == 16
        else:  # a robot this driver has no parameters for: the driver fails with a fix
            wait_until(lambda: srv.slot_state("p2os") == "failed", 15, "the driver to fail")
            assert any("set model = one of p2dx, p3at" in r.message for r in caplog.records)
    finally:
        srv.close()
        emu.close()


def test_velocity_command_moves_the_odometry(robot, served):
    srv, fab, node = served
    node.wait_for("r0/position2d/0", timeout=15)
    pos = fab.device("r0:position2d:0")
    start = pos.wait_for_data(10)
    assert start.pose == pytest.approx((0.0, 0.0, 0.0))  # the counters start near their wrap: no jump
    pos.set_velocity(0.3, 0.0)  # held: re-sent inside the base's command timeout
    wait_until(lambda: pos.latest.pose[0] > 0.2, 10, "odometry to move 0.2 m forward")
    assert pos.latest.vel[0] == pytest.approx(0.3, abs=0.01) and abs(pos.latest.pose[1]) < 0.01
    assert 300 in robot.commands(p2os.VEL)
    pos.set_velocity(0.0, math.radians(45))
    wait_until(lambda: pos.latest.pose[2] > 0.3, 10, "odometry to turn")
    assert robot.commands(p2os.RVEL)[-1] == 45
    pos.send(VelocityCmd(5.0, 0.0))  # over the p2dx limit: rejected, nothing changes
    pos.stop()  # no longer held
    pos.rpc("stop")
    wait_until(lambda: robot.v == 0 and robot.w == 0, 10, "the robot to stop")
    assert 5000 not in robot.commands(p2os.VEL)
    assert srv.server.stats["rejected"] >= 1
    grip, dio = fab.device("r0:gripper:0"), fab.device("r0:dio:0")
    grip.wait_for_data(10)
    dio.wait_for_data(10)
    grip.send(GripperCmd("close"))
    wait_until(lambda: grip.latest.paddles == "closed", 10, "the paddles to close")
    assert robot.commands(p2os.GRIPPER) == [p2os.GRIP_CLOSE]
    dio.send(DioCmd(0b11, mask=0b11))
    wait_until(lambda: dio.latest["outputs"] == 0b11, 10, "digital outputs set")
    assert robot.commands(p2os.DIGOUT) == [0x0303]


def test_silent_robot_withdraws_devices_and_they_return(robot, served, caplog):
    caplog.set_level(logging.INFO, logger="mrs_bridge")
    srv, fab, node = served
    node.wait_for("r0/**", count=len(DEVICES), timeout=15)
    robot.silent = True
    for a in DEVICES:
        node.wait_gone(a, timeout=10)
    assert any("robot lost" in r.message for r in caplog.records)
    with pytest.raises(RpcError) as ei:
        fab.device("r0:position2d:0").rpc("stop")
    assert ei.value.code == ErrorCode.UNAVAILABLE
    robot.silent = False  # still open from before: the driver closes it and syncs again
    node.wait_for("r0/**", count=len(DEVICES), timeout=15)
    drv = srv.driver("p2os")
    assert drv.stats["reconnects"] >= 1
    assert srv.slot_state("p2os") == "running"


def test_garbage_and_bad_checksums_are_skipped_and_counted(robot, served, caplog):
    caplog.set_level(logging.WARNING, logger="mrs_bridge")
    srv, fab, node = served
    node.wait_for("r0/position2d/0", timeout=15)
    pos = fab.device("r0:position2d:0")
    pos.wait_for_data(10)
    drv = srv.driver("p2os")
    robot.inject_garbage(n=100)
    robot.corrupt = 3
    robot.truncate = 2
    wait_until(lambda: drv.stats["bad_packets"] >= 5 and drv.stats["skipped_bytes"] >= 50, 10, "noise to be counted")
    n = pos.count
    wait_until(lambda: pos.count > n + 3, 10, "data to keep flowing after the noise")
    assert node.devices() == sorted(DEVICES)  # nothing was withdrawn
    st = pos.rpc("status")
    assert st["connected"] and st["bad_packets"] >= 5 and st["robot"] == ["emu", "Pioneer", "P2DX"]
    noise = [r for r in caplog.records if "line noise" in r.message]
    assert 1 <= len(noise) <= 2  # rate-limited


def test_shutdown_stops_and_closes_the_robot(robot, served):
    srv, fab, node = served
    node.wait_for("r0/position2d/0", timeout=15)
    fab.device("r0:position2d:0").send(VelocityCmd(0.2, 0.1))
    wait_until(lambda: robot.v == 200, 10, "the robot to drive")
    srv.close()
    wait_until(lambda: not robot.open, 5, "CLOSE")
    with robot.lock:
        tail = robot.received[-4:]
    assert tail == [(p2os.VEL, 0), (p2os.RVEL, 0), (p2os.ENABLE, 0), (p2os.CLOSE, None)]
    assert robot.v == 0 and not robot.motors


def test_no_robot_on_the_port_keeps_devices_offline(tmp_path: Path, fabric_factory, caplog):
    caplog.set_level(logging.WARNING, logger="mrs_bridge")
    port = free_port()
    missing = tmp_path / "ttyUSB9"
    srv = LiveServer(CONFIG.format(port=missing), port=port, source="pioneer.toml", drivers=DRIVERS).start()
    try:
        wait_until(lambda: any("cannot open" in r.message for r in caplog.records), 10, "a warning")
        assert srv.slot_state("p2os") == "running"
        assert all(d.token is None for d in srv.server.devices.values())
        assert isinstance(srv.driver("p2os").stats, dict)
    finally:
        srv.close()


def test_sip_dataclass_properties():
    s = Sip(False, 0, 0, 0, 0, 0, 120, 0x0100, 0, ())
    assert s.stalled and not s.motors_enabled and s.volts == 12.0


def test_an_unrefreshed_command_times_out_and_the_driver_sends_zero(robot, served):
    srv, fab, node = served
    node.wait_for("r0/position2d/0", timeout=15)
    pos = fab.device("r0:position2d:0")
    pos.wait_for_data(10)
    pos.send(VelocityCmd(0.3, 0.0))  # once, never refreshed
    wait_until(lambda: robot.v == 300, 10, "the robot to drive")
    t0 = time.monotonic()
    wait_until(lambda: robot.v == 0 and robot.w == 0, 2, "the driver to send zero velocity after cmd_timeout")
    assert 0.4 <= time.monotonic() - t0 <= 0.5 + 0.3
    assert robot.commands(p2os.VEL)[-1] == 0 and robot.commands(p2os.RVEL)[-1] == 0
    wait_until(lambda: pos.latest.timed_out, 2, "the data to say timed_out")
    pos.send(VelocityCmd(0.2, 0.0))
    wait_until(lambda: robot.v == 200 and not pos.latest.timed_out, 2, "the next command to clear timed_out")
    pos.rpc("stop")


def test_emergency_stop_latches_refuses_and_releases(robot, served, caplog):
    caplog.set_level(logging.WARNING, logger="mrs_bridge")
    srv, fab, node = served
    node.wait_for("r0/position2d/0", timeout=15)
    pos = fab.device("r0:position2d:0")
    pos.wait_for_data(10)
    pos.set_velocity(0.3, 0.0)
    wait_until(lambda: robot.v == 300, 10, "the robot to drive")
    assert pos.estop() == {"ok": True, "estop": True}
    wait_until(lambda: robot.v == 0 and pos.latest.estop, 2, "the robot to stop and report estop")
    pos.send(VelocityCmd(0.3, 0.0))
    with pytest.raises(RpcError) as e:
        pos.rpc("set_velocity", v=0.3, w=0.0)
    assert e.value.code == ErrorCode.ESTOP
    wait_until(
        lambda: any("latched" in r.message and "rejected cmd" in r.message for r in caplog.records), 2, "a warning"
    )
    assert robot.v == 0
    assert pos.release_estop() == {"ok": True, "estop": False}
    pos.rpc("set_velocity", v=0.2, w=0.0)
    wait_until(lambda: robot.v == 200 and not pos.latest.estop, 2, "the robot to drive after the release")
    pos.stop()
