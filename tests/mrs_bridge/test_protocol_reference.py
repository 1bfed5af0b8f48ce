"""Protocol truth for the Pioneer (P2OS/ARCOS SIP) and the Hokuyo (SCIP 2.0): the emulators' bytes
for known states equal reference packets written by hand from the manuals (one comment per field),
the driver's codec decodes those references to the documented meanings, and the ``p2os`` driver
reads the emulator's gripper, lift, break beams, bumpers, stall and battery right end to end over
the pseudo-terminal. The emulators (mrs_bridge/emulators/p2os.py, urg.py) import nothing of the
project, not even their own package: they and the driver meet only on the wire."""

from __future__ import annotations

import ast
import os
import select
import time
import tty

import pytest
from bridge_helpers import LiveServer

import mrs_bridge.drivers.p2os  # noqa: F401  (registers the driver)
from mrs_bridge.driver import DRIVERS
from mrs_bridge.emulators.p2os import PioneerEmulator, SipState, encode_sip, frame
from mrs_bridge.emulators.urg import HokuyoEmulator, answer, scan_block
from mrs_bridge.hw.p2os import decode_sip, gripper_state
from mrs_bridge.hw.scip import decode_scan, parse_fields, parse_frame, status_text
from tests.conftest import ROOT, free_port, wait_until


@pytest.mark.parametrize("name", ["__init__.py", "p2os.py", "urg.py"])
def test_the_emulators_import_nothing_of_the_project(name):
    tree = ast.parse((ROOT / "mrs_bridge" / "emulators" / name).read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    relative = [n for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level]
    ours = {m for m in imported if m.split(".")[0] in ("mrs_bridge", "rsal", "simulator", "agents")}
    assert not relative and not ours


# ---------------------------------------------------------------------------- P2OS standard SIP
# A P2DX at counters (1000, 2000), heading 1024 (a quarter turn), left wheel -100, right wheel
# +200 (turning left), battery 12.3 V, front bumper segment 1 pressed, motors on with sonar array 0,
# two sonar readings, the gripper closed and its lift up, the inner break beam broken and both
# paddles touching what they hold.
REFERENCE_SIP = bytes.fromhex(
    "fa fb"  # header
    "24"  # byte count: 34 payload bytes + 2 checksum bytes
    "33"  # TYPE: 0x33 moving (a wheel turns)
    "e8 03"  # XPOS 1000
    "d0 07"  # YPOS 2000
    "00 04"  # THPOS 1024 = 90 degrees
    "9c ff"  # L VEL -100
    "c8 00"  # R VEL 200
    "7b"  # BATTERY 123 = 12.3 V
    "00 02"  # STALL AND BUMPERS: bit 9 = front bumper segment 1; no wheel stalled
    "00 00"  # CONTROL
    "03 00"  # FLAGS: bit 0 motors enabled, bit 1 sonar array 0 on
    "00"  # COMPASS
    "02"  # SONAR COUNT 2
    "00 f4 01"  # sonar 0: 500
    "01 e8 03"  # sonar 1: 1000
    "00 12"  # TIMER: high byte = gripper state 0x12 = 0x02 paddles closed | 0x10 lift up
    "80"  # ANALOG 128
    "08"  # DIGIN: 0x08 inner beam broken; contacts 0x10, 0x20 low = both paddles touching
    "00"  # DIGOUT
    "7b 00"  # BATTERYX10 123 = 12.3 V
    "00"  # CHARGESTATE: not charging
    # checksum: the big-endian words 33e8 03d0 0700 049c ffc8 007b 0002 0000 0300 0002 00f4
    # 0101 e803 0012 8008 007b summed to 16 bits, the odd last byte 00 xor'd in
    "b1 28"
)

REFERENCE_STATE = SipState(
    xpos=1000,
    ypos=2000,
    thpos=1024,
    l_vel=-100,
    r_vel=200,
    battery=123,
    front_bumpers=0b1,
    flags=0b11,
    sonars=[(0, 500), (1, 1000)],
    grip=0x12,
    analog=128,
    digin=0x08,
    battery_x10=123,
)


def test_the_emulator_encodes_the_reference_sip():
    assert frame(encode_sip(REFERENCE_STATE)) == REFERENCE_SIP


def test_the_codec_decodes_the_reference_sip_to_the_documented_meanings():
    s = decode_sip(REFERENCE_SIP[3:-2])
    assert s.moving and (s.xpos, s.ypos, s.thpos, s.l_vel, s.r_vel) == (1000, 2000, 1024, -100, 200)
    assert s.volts == pytest.approx(12.3)
    assert s.front_bumpers == 0b1 and s.rear_bumpers == 0 and s.stall == (False, False) and not s.stalled
    assert s.motors_enabled and s.sonars == ((0, 500), (1, 1000))
    assert s.gripper == 0x12 and (s.analog, s.digin, s.digout, s.charge_state) == (128, 0x08, 0, 0)
    g = gripper_state(s.gripper, s.digin)
    assert (g.paddles, g.lift, g.beams, g.contacts) == ("closed", "up", 0b01, 0b11)


@pytest.mark.parametrize(
    ("grip", "digin", "expected"),
    [
        # the reading the issue feared: lift down (0x20) with no beam broken is not a broken beam
        (0x21, 0x30, ("open", "down", 0, 0)),
        (0x25, 0x30, ("opening", "down", 0, 0)),  # 0x04 moving with 0x01: opening
        (0x26, 0x34, ("closing", "down", 0b10, 0)),  # closing on something: outer beam broken
        (0x52, 0x0C, ("closed", "raising", 0b11, 0b11)),  # 0x40 lift moving with 0x10: raising
        (0x62, 0x30, ("closed", "lowering", 0, 0)),
        (0x32, 0x20, ("closed", "between", 0, 0b01)),  # up and down, not moving: stopped between
        (0x03, 0x30, ("error", "stalled", 0, 0)),  # open and closed, not moving: error
    ],
)
def test_gripper_state_bits(grip, digin, expected):
    g = gripper_state(grip, digin)
    assert (g.paddles, g.lift, g.beams, g.contacts) == expected


def test_stall_and_rear_bumpers_bits():
    s = decode_sip(encode_sip(SipState(stall_left=True, rear_bumpers=0b10100, battery=120)))
    assert s.stall_bumpers == 0b0010_1001  # bit 0 left stall, bits 3 and 5: rear segments 3 and 5
    assert s.stall == (True, False) and s.stalled and s.rear_bumpers == 0b10100 and not s.moving
    r = decode_sip(encode_sip(SipState(stall_right=True, front_bumpers=0b10000)))
    assert r.stall_bumpers == 0x0100 | 0b10000 << 9 and r.stall == (False, True) and r.front_bumpers == 0b10000


def test_an_older_sip_without_the_arcos_fields_still_reads_the_gripper():
    full = encode_sip(REFERENCE_STATE)
    s = decode_sip(full[:-3])  # ends after DIGOUT (P2OS): no BATTERYX10, no CHARGESTATE
    assert s.gripper == 0x12 and s.digin == 0x08 and s.battery_x10 is None and s.volts == pytest.approx(12.3)


# ---------------------------------------------------------------------------- P2OS end to end
CONFIG = """
[server]
node = "r0"

[[driver]]
name = "p2os"
provides = ["odometry::position2d:0", "power:0", "gripper::gripper:0", "lift::actarray:0", "dio:0"]
port = "{port}"
pulse = 0.2
timeout = 1.0
reconnect = 0.1
"""


@pytest.fixture
def robot_served(fabric_factory):
    emu = PioneerEmulator("P2DX")
    port = free_port()
    srv = LiveServer(CONFIG.format(port=emu.path), port=port, source="pioneer.toml", drivers=DRIVERS).start()
    fab = fabric_factory(port)
    yield emu, fab
    srv.close()
    emu.close()


def test_the_driver_reads_gripper_lift_beams_stall_and_battery_from_the_emulator(robot_served):
    emu, fab = robot_served
    grip, lift, pos = fab.device("r0:gripper:0"), fab.device("r0:actarray:0"), fab.device("r0:position2d:0")
    power, dio = fab.device("r0:power:0"), fab.device("r0:dio:0")
    g = grip.wait_for_data(15)
    # at rest: paddles open, lift down, no beam broken (the old reading took lift-down for a beam)
    assert (g.paddles, g.lift, g.beams, g.stored) == ("open", "down", 0, 0)
    assert lift.wait_for_data(10)["positions"] == [0.0]
    assert not pos.wait_for_data(10).stall
    power.wait_for_data(10)
    dio.wait_for_data(10)
    with emu.lock:  # an object between the paddles, the paddles closed on it, the lift up
        emu.paddles, emu.lift = "closed", "up"
        emu.inner_beam, emu.contacts = True, (True, True)
        emu.battery, emu.stall = 11.8, (True, False)
    wait_until(lambda: grip.latest.lift == "up", 10, "the gripper data to follow the robot")
    g = grip.latest
    assert (g.paddles, g.lift, g.beams, g.stored) == ("closed", "up", 0b01, 1)
    wait_until(lambda: lift.latest["positions"] == [1.0], 10, "the lift array up")
    assert lift.latest["states"] == ["idle"]
    wait_until(lambda: pos.latest.stall, 10, "the stall bit")
    wait_until(lambda: power.latest.volts == pytest.approx(11.8), 10, "the battery at 11.8 V")
    wait_until(lambda: dio.latest["bits"] == 0b1000_1001, 10, "DIGIN: user 0x81, inner beam, contacts low")
    with emu.lock:  # the lift goes down and only the outer beam is broken: still no inner beam
        emu.lift, emu.inner_beam, emu.outer_beam = "down", False, True
    wait_until(lambda: grip.latest.lift == "down", 10, "the lift down")
    assert grip.latest.beams == 0b10


def test_paddles_and_lift_report_their_motion(robot_served):
    emu, fab = robot_served
    grip, lift = fab.device("r0:gripper:0"), fab.device("r0:actarray:0")
    grip.wait_for_data(15)
    lift.wait_for_data(10)
    emu.paddle_time = emu.lift_time = 1.0
    grip.rpc("close")
    wait_until(lambda: grip.latest.paddles == "closing", 5, "the paddles reported closing")
    wait_until(lambda: grip.latest.paddles == "closed", 5, "the paddles reported closed")
    lift.rpc("set_position", joint=0, position=1.0)
    wait_until(lambda: lift.latest["states"] == ["moving"], 5, "the lift reported moving")
    assert grip.latest.lift == "raising"
    wait_until(lambda: lift.latest["states"] == ["idle"] and lift.latest["positions"] == [1.0], 5, "the lift up")


# ---------------------------------------------------------------------------- SCIP 2.0
def test_scip_reference_blocks():
    # GD/MD scan of three readings, time stamp 0x1234 = 4660 ms
    assert answer(b"MD0044004601000", b"99", scan_block(0x1234, [1000, 5432, 20])) == (
        b"MD0044004601000\n"  # echo (start 0044, end 0046, cluster 01, interval 0, scans 00)
        b"99b\n"  # status 99 (scan data), check 0x39 + 0x39 = 0x72 -> 0x32 + 0x30 = 'b'
        b"018dm\n"  # time stamp 4660 = 6-bit groups 0 1 8 52 -> '0' '1' '8' 'd'; check 0xfd -> 'm'
        b"0?X"  # 1000 = groups 0 15 40 -> '0' '?' 'X'
        b"1Dh"  # 5432 = groups 1 20 56 -> '1' 'D' 'h'
        b"00D"  # 20 = groups 0 0 20 -> '0' '0' 'D'
        b"8\n"  # check: the nine characters sum to 0x248 -> 0x08 + 0x30 = '8'
        b"\n"  # the empty line ending the block
    )
    assert answer(b"GD0100005001", b"05") == b"GD0100005001\n05U\n\n"  # 0x65 -> 0x25 + 0x30 = 'U'
    assert answer(b"XX", b"0E") == b"XX\n0Ee\n\n"  # undefined command: 0x75 -> 0x35 + 0x30 = 'e'


def _converse(emu: HokuyoEmulator, cmd: bytes, timeout: float = 5.0) -> bytes:
    """Write a command to the emulator's pty and read its reply block (up to the empty line)."""
    fd = os.open(emu.path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        os.write(fd, cmd + b"\n")
        out = b""
        deadline = time.monotonic() + timeout
        while b"\n\n" not in out:
            left = deadline - time.monotonic()
            assert left > 0, f"no complete answer to {cmd!r}: {out!r}"
            r, _, _ = select.select([fd], [], [], left)
            if r:
                out += os.read(fd, 4096)
        return out
    finally:
        os.close(fd)


@pytest.fixture
def urg():
    emu = HokuyoEmulator("URG-04LX", room_mm=1500)
    yield emu
    emu.close()


def test_scip_replies_over_the_pty_equal_the_references(urg):
    assert _converse(urg, b"VV") == (
        b"VV\n00P\n"  # echo, status 00 with its check 'P'
        b"VEND:Emulated Sensors;U\n"  # the sums stop before the ';': 0x7a5 -> 0x25 + 0x30 = 'U'
        b"PROD:URG-04LX;B\n"  # 0x392 -> 'B'
        b"FIRM:1.0.0;E\n"  # 0x255 -> 'E'
        b"PROT:SCIP 2.0;N\n"  # 0x35e -> 'N'
        b"SERI:EMU0001;E\n"  # 0x315 -> 'E'
        b"\n"
    )
    assert _converse(urg, b"PP") == (
        b"PP\n00P\n"
        b"MODL:URG-04LX(Emulated);;\n"  # 0x70b -> 0x0b + 0x30 = ';'
        b"DMIN:20;4\n"  # 20 mm
        b"DMAX:5600;_\n"  # 5600 mm
        b"ARES:1024;\\\n"  # 1024 steps per revolution
        b"AMIN:44;7\n"  # first measuring step
        b"AMAX:725;o\n"  # last measuring step
        b"AFRT:384;6\n"  # straight ahead
        b"SCAN:600;e\n"  # rpm
        b"\n"
    )
    assert _converse(urg, b"II") == b"II\n00P\nLASR:OFF;7\n\n"
    assert _converse(urg, b"GD0044072501") == b"GD0044072501\n10Q\n\n"  # laser off: 0x61 -> 'Q'
    assert _converse(urg, b"BM") == b"BM\n00P\n\n"
    assert _converse(urg, b"BM") == b"BM\n02R\n\n"  # already on: 0x62 -> 'R'
    assert _converse(urg, b"GD0100005001") == b"GD0100005001\n05U\n\n"  # end before start
    assert _converse(urg, b"GD0044080001") == b"GD0044080001\n04T\n\n"  # end beyond AMAX: 0x64 -> 'T'
    assert _converse(urg, b"XX") == b"XX\n0Ee\n\n"
    assert _converse(urg, b"QT") == b"QT\n00P\n\n"


def test_the_driver_codec_reads_the_emulators_scan_and_status_meanings(urg):
    _converse(urg, b"BM")
    fr = parse_frame(_converse(urg, b"GD0044005002").rstrip(b"\n"))
    assert (fr.echo, fr.status) == (b"GD0044005002", b"00")
    ts, mm = decode_scan(fr)
    # steps 44..50 in clusters of 2: (44, 45) (46, 47) (48, 49) (50); step 54 = amin + 10 not asked
    assert mm.tolist() == [1500, 1500, 1500, 1500] and 0 <= ts < 1 << 24
    fr = parse_frame(_converse(urg, b"GD0044006001").rstrip(b"\n"))
    assert decode_scan(fr)[1].tolist() == [1500] * 10 + [1] + [1500] * 6  # step 54: error code 1
    assert parse_fields(parse_frame(_converse(urg, b"II").rstrip(b"\n"))) == {"LASR": "ON"}
    assert status_text(b"GD", b"05") == "end step before the start step"
    assert status_text(b"GD", b"04") == "end step out of range"
    assert status_text(b"GD", b"10") == "the laser is off"
    assert status_text(b"BM", b"02") == "the laser was already on"
    assert status_text(b"MD", b"0E") == "undefined command (2)"
    assert status_text(b"MD", b"55") == "hardware trouble (laser, motor ...)"


def test_a_counted_md_counts_its_scans_down_in_the_echo_and_stops(urg):
    fd = os.open(urg.path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        os.write(fd, b"MD0044004600003\n")  # steps 44..46, cluster 00 (= 1), interval 0, 3 scans
        out = b""
        deadline = time.monotonic() + 5.0
        while out.count(b"\n\n") < 4:
            assert time.monotonic() < deadline, f"an answer and three scans expected: {out!r}"
            r, _, _ = select.select([fd], [], [], 0.1)
            if r:
                out += os.read(fd, 4096)
    finally:
        os.close(fd)
    blocks = out.split(b"\n\n")
    assert blocks[0] == b"MD0044004600003\n00P"  # accepted, no data
    frames = [parse_frame(b) for b in blocks[1:4]]
    assert [(f.echo, f.status) for f in frames] == [
        (b"MD0044004600002", b"99"),  # the scans left after this one
        (b"MD0044004600001", b"99"),
        (b"MD0044004600000", b"99"),
    ]
    assert all(decode_scan(f)[1].tolist() == [1500, 1500, 1500] for f in frames)
    wait_until(lambda: urg.md is None, 2, "the counted MD to end")
    scans = urg.scans_sent
    assert _converse(urg, b"QT") == b"QT\n00P\n\n" and urg.scans_sent == scans
