"""Pioneer P2OS / ARCOS packet codec: framing, checksum, client commands, SIP parsing (no I/O).

Spec: ActivMedia/MobileRobots "Pioneer 2 / PeopleBot Operations Manual" (P2OS client-server
protocol) and the ARCOS manual; the same protocol Player's ``p2os`` driver speaks (thesis 3.3.2,
A.2). The tables below are taken from the manuals named with them.

The robot's microcontroller (P2OS, later ARCOS) speaks a packet protocol on its serial port:

    0xFA 0xFB  count  payload[count - 2]  checksum_hi checksum_lo

``count`` is the payload length plus the two checksum bytes (at most 200); the checksum is the sum
of the payload's 16-bit big-endian words, an odd last byte xor'd in, truncated to 16 bits and sent
high byte first (:func:`checksum`).

Client commands (:func:`command`) are a payload of the command number, optionally an argument:
type byte 0x3B (positive integer), 0x1B (negative integer) with the absolute value as 2 bytes
little-endian, or 0x2B (string) with a length byte and the text. Those used here: SYNC0/1/2 (0, 1,
2), OPEN (1), CLOSE (2), PULSE (0), ENABLE (4, 1 = motors on), VEL (11,
mm/s), RVEL (21, deg/s), SONAR (28, 1 = on), DIGOUT (30, mask << 8 | bits), GRIPPER (33).

Connecting: SYNC0, SYNC1, SYNC2 are each echoed by the robot; the SYNC2 echo carries the robot's
name, class and subclass as NUL-terminated strings. Then OPEN, SONAR 1, ENABLE 1, and PULSE at
least every ``pulse`` seconds (the robot stops its motors when it hears nothing for about 2 s).

Standard server information packet (SIP), decoded by :func:`decode_sip`. Sources: the
"Pioneer 2 / PeopleBot Operations Manual" (ActivMedia Robotics), chapter "P2OS", section "Server
Information Packets" (the standard SIP table), and the "Pioneer 3 Operations Manual" chapter
"ARCOS", section "Standard SIP" (which adds the fields after DIGOUT). Offsets into the payload
(after the byte count), multi-byte values little-endian ("integer" = 2 bytes):

====== ===== ============= ==========================================================================
offset bytes name          meaning
====== ===== ============= ==========================================================================
0      1     TYPE          0x32 stopped, 0x33 moving (0x3S: S = 2 or 3)
1      2     XPOS          15-bit wrapping counter of DistConv mm units
3      2     YPOS          likewise
5      2     THPOS         heading, 4096 units per revolution (12 bits used, wraps around)
7      2     L VEL         left wheel, signed, VelConv mm/s
9      2     R VEL         right wheel, likewise
11     1     BATTERY       0.1 V
12     2     STALL AND     bit 0 left wheel stalled, bits 1-7 rear bumper segments 1-7; bit 8 right
             BUMPERS       wheel stalled, bits 9-15 front bumper segments 1-7 (a P2DX has 5 each)
14     2     CONTROL       the heading servo's set-point, signed angle units (not used)
16     2     FLAGS         bit 0 motors enabled, bits 1-4 sonar arrays 0-3 on (more bits on ARCOS)
18     1     COMPASS       2-degree units (not used)
19     1     SONAR COUNT   n readings follow, each NUMBER (1 byte) and RANGE (2 bytes, RangeConv mm)
20+3n  2     TIMER         P2OS: the user timer; its high byte (offset 21+3n) is the gripper state
                           byte (table below); ARCOS names these two bytes GRIP_STATE and ANPORT
22+3n  1     ANALOG        user analog input, 0..255 = 0..5 V
23+3n  1     DIGIN         user digital inputs (the gripper's break beams and paddle contacts, below)
24+3n  1     DIGOUT        user digital outputs
25+3n  2     BATTERYX10    ARCOS: battery, 0.1 V (0 or absent: use BATTERY)
27+3n  1     CHARGESTATE   ARCOS: 0 not charging, 1 bulk, 2 overcharge, 3 float
====== ===== ============= ==========================================================================

Everything from TIMER on is optional (older firmwares end after the sonars).

The Pioneer gripper. The operations manuals name the bytes but not their gripper bits; the bit
table is the one Player's ``p2os`` driver decodes (``sip.cc``, the standard SIP's gripper and lift
state; Player was the thesis's driver), read for its meaning, and the break-beam bits are those
ARIA's ``ArGripper`` reads from DIGIN for a gripper on the user I/O port. The **gripper state
byte** (TIMER high byte, :data:`GRIP_BITS`):

==== ===== ============================================================================
bit  mask  meaning
==== ===== ============================================================================
0    0x01  paddles open (while 0x04: they are opening)
1    0x02  paddles closed (while 0x04: they are closing); 0x01 and 0x02 without 0x04: error
2    0x04  paddles moving
4    0x10  lift up (while 0x40: raising)
5    0x20  lift down (while 0x40: lowering); 0x10 and 0x20 without 0x40: stopped between
6    0x40  lift moving
==== ===== ============================================================================

and the **break beams and paddle contacts in DIGIN** (:data:`DIGIN_BITS`): bit 2 (0x04) outer
break beam broken, bit 3 (0x08) inner break beam broken, bit 4 (0x10) left and bit 5 (0x20) right
paddle contact, active low (0 = touching). ARIA's ``ArGripper`` reads a different bit table from
the same byte for the older "general I/O" gripper wiring (switch levels, active low); this codec
follows the table above; ARCOS names the TIMER's first byte GRIP_STATE, which no client reads
here. Gripper commands (GRIPPER, 33; the same numbers in ARIA's ``ArGripperCommands``): 1 open,
2 close, 3 stop paddles, 4 lift up, 5 lift down, 6 stop lift.

The robot model table (:data:`MODELS`: conversion factors, sonar poses, limits) and the odometry
that integrates the wrapping counters (:class:`Odometry`) are pure computations on SIPs and live
here too.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from rsal.geometry import wrap

__all__ = [
    "DIGIN_BITS",
    "GRIP_BITS",
    "GripperState",
    "HEADER",
    "MAX_COUNT",
    "MODELS",
    "Odometry",
    "PacketReader",
    "RobotModel",
    "Sip",
    "checksum",
    "command",
    "decode_sip",
    "gripper_state",
    "is_sip",
    "model_for",
    "packet",
]

# ---------------------------------------------------------------------------- protocol
HEADER = b"\xfa\xfb"
MAX_COUNT = 200  # largest byte count a P2OS packet may announce

SYNC0, SYNC1, SYNC2 = 0, 1, 2
PULSE, OPEN, CLOSE = 0, 1, 2
ENABLE, VEL, RVEL, SONAR, DIGOUT, GRIPPER = 4, 11, 21, 28, 30, 33
ARG_INT, ARG_NINT, ARG_STR = 0x3B, 0x1B, 0x2B

# GRIPPER command arguments (module docstring)
GRIP_OPEN, GRIP_CLOSE, GRIP_STOP, LIFT_UP, LIFT_DOWN, LIFT_STOP = 1, 2, 3, 4, 5, 6
GRIPPER_ARGS = {"open": GRIP_OPEN, "close": GRIP_CLOSE, "stop": GRIP_STOP, "up": LIFT_UP, "down": LIFT_DOWN}

SIP_STOPPED, SIP_MOVING = 0x32, 0x33


def checksum(payload: bytes) -> int:
    """P2OS checksum: 16-bit big-endian word sum (odd last byte xor'd in), truncated to 16 bits."""
    n = len(payload)
    even = np.frombuffer(payload, dtype=">u2", count=n // 2) if n >= 2 else np.zeros(0, ">u2")
    c = int(even.sum(dtype=np.uint64)) & 0xFFFF
    if n & 1:
        c ^= payload[-1]
    return c


def packet(payload: bytes) -> bytes:
    """A framed packet: header, count, payload, checksum (high byte first)."""
    if not 0 < len(payload) <= MAX_COUNT - 2:
        raise ValueError(f"payload of {len(payload)} bytes; a P2OS packet holds 1..{MAX_COUNT - 2}")
    return HEADER + bytes([len(payload) + 2]) + payload + checksum(payload).to_bytes(2, "big")


def command(cmd: int, arg: int | str | None = None) -> bytes:
    """A framed client command with an optional integer (|arg| < 65536) or string argument."""
    if arg is None:
        return packet(bytes([cmd]))
    if isinstance(arg, str):
        raw = arg.encode("ascii")
        return packet(bytes([cmd, ARG_STR, len(raw)]) + raw)
    if not -0xFFFF <= arg <= 0xFFFF:
        raise ValueError(f"argument {arg} of command {cmd} does not fit in 2 bytes")
    return packet(bytes([cmd, ARG_INT if arg >= 0 else ARG_NINT]) + abs(arg).to_bytes(2, "little"))


class PacketReader:
    """Incremental packet parser: :meth:`feed` bytes, get whole payloads back. Bytes that do not
    form a packet are skipped by searching for the next 0xFA 0xFB; ``skipped`` counts those bytes,
    ``bad`` the frames dropped for a bad checksum or an impossible byte count."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.skipped = 0
        self.bad = 0
        self.packets = 0

    def feed(self, data: bytes) -> list[bytes]:
        self.buf += data
        out: list[bytes] = []
        buf = self.buf
        while True:
            i = buf.find(HEADER)
            if i < 0:
                keep = 1 if buf[-1:] == b"\xfa" else 0  # a header may be split across reads
                self.skipped += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if i:
                self.skipped += i
                del buf[:i]
            if len(buf) < 3:
                break
            count = buf[2]
            if count < 3 or count > MAX_COUNT:
                self.bad += 1
                self.skipped += 2
                del buf[:2]
                continue
            if len(buf) < 3 + count:
                break
            payload = bytes(buf[3 : 1 + count])
            if checksum(payload) != int.from_bytes(buf[1 + count : 3 + count], "big"):
                # perhaps a truncated frame ran into the next one: resync just after this header
                self.bad += 1
                self.skipped += 2
                del buf[:2]
                continue
            del buf[: 3 + count]
            self.packets += 1
            out.append(payload)
        return out


# gripper state byte (the TIMER high byte) and the DIGIN bits of the gripper: module docstring
GRIP_OPEN_BIT, GRIP_CLOSED_BIT, GRIP_MOVING_BIT = 0x01, 0x02, 0x04
LIFT_UP_BIT, LIFT_DOWN_BIT, LIFT_MOVING_BIT = 0x10, 0x20, 0x40
GRIP_BITS = {
    "paddles_open": GRIP_OPEN_BIT,
    "paddles_closed": GRIP_CLOSED_BIT,
    "paddles_moving": GRIP_MOVING_BIT,
    "lift_up": LIFT_UP_BIT,
    "lift_down": LIFT_DOWN_BIT,
    "lift_moving": LIFT_MOVING_BIT,
}
DIGIN_OUTER_BEAM, DIGIN_INNER_BEAM, DIGIN_LEFT_CONTACT, DIGIN_RIGHT_CONTACT = 0x04, 0x08, 0x10, 0x20
DIGIN_BITS = {
    "outer_beam": DIGIN_OUTER_BEAM,  # 1 = broken
    "inner_beam": DIGIN_INNER_BEAM,  # 1 = broken
    "left_contact": DIGIN_LEFT_CONTACT,  # 0 = touching
    "right_contact": DIGIN_RIGHT_CONTACT,  # 0 = touching
}
# STALL AND BUMPERS and FLAGS bits
STALL_LEFT, STALL_RIGHT = 0x0001, 0x0100
FLAG_MOTORS = 0x0001


@dataclass(frozen=True)
class Sip:
    """A decoded standard SIP in the robot's raw units (the table in the module docstring)."""

    moving: bool
    xpos: int
    ypos: int
    thpos: int
    l_vel: int
    r_vel: int
    battery: int  # 0.1 V
    stall_bumpers: int
    flags: int
    sonars: tuple[tuple[int, int], ...]  # (number, raw range)
    timer: int | None = None  # 2 bytes; the high byte is the gripper state byte
    analog: int | None = None
    digin: int | None = None
    digout: int | None = None
    battery_x10: int | None = None
    charge_state: int | None = None

    @property
    def stalled(self) -> bool:
        return bool(self.stall_bumpers & (STALL_LEFT | STALL_RIGHT))

    @property
    def stall(self) -> tuple[bool, bool]:
        """(left wheel, right wheel) stalled."""
        return bool(self.stall_bumpers & STALL_LEFT), bool(self.stall_bumpers & STALL_RIGHT)

    @property
    def front_bumpers(self) -> int:
        """Front bumper segments pressed: bit i = segment i + 1."""
        return (self.stall_bumpers >> 9) & 0x7F

    @property
    def rear_bumpers(self) -> int:
        """Rear bumper segments pressed: bit i = segment i + 1."""
        return (self.stall_bumpers >> 1) & 0x7F

    @property
    def gripper(self) -> int | None:
        """The gripper state byte (TIMER high byte), None when the SIP ends after the sonars."""
        return None if self.timer is None else self.timer >> 8

    @property
    def motors_enabled(self) -> bool:
        return bool(self.flags & FLAG_MOTORS)

    @property
    def volts(self) -> float:
        return (self.battery_x10 if self.battery_x10 else self.battery) / 10.0


@dataclass(frozen=True)
class GripperState:
    """The Pioneer gripper as a SIP reports it (module docstring tables).

    ``paddles``: "open", "closed", "opening", "closing", "moving" (direction not reported),
    "between" (stopped, neither open nor closed) or "error"; ``lift``: "up", "down", "raising",
    "lowering", "moving", "between" (stopped between its ends) or "stalled" (neither at an end nor
    moving); ``beams``: bit 0 inner, bit 1 outer broken; ``contacts``: bit 0 left, bit 1 right
    paddle touching."""

    paddles: str
    lift: str
    beams: int
    contacts: int


def gripper_state(grip: int, digin: int) -> GripperState:
    """Decode the gripper state byte and DIGIN (module docstring)."""
    opened, closed = bool(grip & GRIP_OPEN_BIT), bool(grip & GRIP_CLOSED_BIT)
    if grip & GRIP_MOVING_BIT:
        paddles = "opening" if opened and not closed else "closing" if closed and not opened else "moving"
    elif opened and closed:
        paddles = "error"
    else:
        paddles = "open" if opened else "closed" if closed else "between"
    up, down = bool(grip & LIFT_UP_BIT), bool(grip & LIFT_DOWN_BIT)
    if grip & LIFT_MOVING_BIT:
        lift = "raising" if up and not down else "lowering" if down and not up else "moving"
    elif up and down:
        lift = "between"
    else:
        lift = "up" if up else "down" if down else "stalled"
    beams = (1 if digin & DIGIN_INNER_BEAM else 0) | (2 if digin & DIGIN_OUTER_BEAM else 0)
    contacts = (0 if digin & DIGIN_LEFT_CONTACT else 1) | (0 if digin & DIGIN_RIGHT_CONTACT else 2)
    return GripperState(paddles, lift, beams, contacts)


_SIP_HEAD = struct.Struct("<BHHhhhBHhHBB")  # TYPE .. SONAR COUNT: 20 bytes
_SIP_TAIL = struct.Struct("<HBBBHB")  # TIMER .. CHARGESTATE: 8 bytes
_SIP_IO = struct.Struct("<HBBB")  # TIMER .. DIGOUT: a P2OS SIP without the ARCOS fields


def is_sip(payload: bytes) -> bool:
    return len(payload) > 0 and payload[0] in (SIP_STOPPED, SIP_MOVING)


def decode_sip(payload: bytes) -> Sip:
    """Decode a standard SIP payload; raises ``ValueError`` if it is not one or is too short."""
    if not is_sip(payload):
        raise ValueError(f"not a standard SIP (type 0x{payload[0]:02x})" if payload else "empty payload")
    if len(payload) < _SIP_HEAD.size:
        raise ValueError(f"SIP of {len(payload)} bytes is shorter than the {_SIP_HEAD.size} fixed bytes")
    typ, x, y, th, lv, rv, batt, sb, _control, flags, _compass, n = _SIP_HEAD.unpack_from(payload)
    end = _SIP_HEAD.size + 3 * n
    if len(payload) < end:
        raise ValueError(f"SIP announces {n} sonar readings but ends after {(len(payload) - _SIP_HEAD.size) // 3}")
    sonars = tuple(struct.iter_unpack("<BH", payload[_SIP_HEAD.size : end]))
    tail: tuple = (None,) * 6
    if len(payload) >= end + _SIP_TAIL.size:
        tail = _SIP_TAIL.unpack_from(payload, end)
    elif len(payload) >= end + _SIP_IO.size:
        tail = (*_SIP_IO.unpack_from(payload, end), None, None)
    return Sip(typ == SIP_MOVING, x & 0x7FFF, y & 0x7FFF, th & 0xFFF, lv, rv, batt, sb, flags, sonars, *tail)


# ---------------------------------------------------------------------------- robot models
def _ring(front: list[tuple[float, float, float]]) -> tuple[tuple[float, float, float], ...]:
    """Sonar poses (m, m, rad) from (mm, mm, deg) rows."""
    return tuple((x / 1000.0, y / 1000.0, math.radians(a)) for x, y, a in front)


_P2DX_SONARS = [
    (115, 130, 90), (155, 115, 50), (190, 80, 30), (210, 25, 10),
    (210, -25, -10), (190, -80, -30), (155, -115, -50), (115, -130, -90),
    (-115, -130, -90), (-155, -115, -130), (-190, -80, -150), (-210, -25, -170),
    (-210, 25, 170), (-190, 80, 150), (-155, 115, 130), (-115, 130, 90),
]  # fmt: skip
_P3AT_SONARS = [
    (147, 136, 90), (193, 119, 50), (227, 79, 30), (245, 27, 10),
    (245, -27, -10), (227, -79, -30), (193, -119, -50), (147, -136, -90),
    (-144, -136, -90), (-189, -119, -130), (-223, -79, -150), (-241, -27, -170),
    (-241, 27, 170), (-223, 79, 150), (-189, 119, 130), (-144, 136, 90),
]  # fmt: skip


@dataclass(frozen=True)
class RobotModel:
    """Per-model robot parameters (the values of the robot's parameter file)."""

    name: str
    dist_conv: float  # mm per position count
    angle_conv: float  # rad per heading unit
    vel_conv: float  # mm/s per wheel velocity unit
    range_conv: float  # mm per sonar unit
    diff_conv: float  # rad/s per mm/s of (r_vel - l_vel), times 2
    sonar_poses: tuple[tuple[float, float, float], ...]  # m, m, rad; robot frame
    sonars: int  # transducers fitted by default
    max_speed: tuple[float, float]  # m/s, rad/s
    size: tuple[float, float]  # m
    sonar_range: tuple[float, float] = (0.1, 5.0)  # m


MODELS: dict[str, RobotModel] = {
    "p2dx": RobotModel(
        "p2dx", 0.840, 2 * math.pi / 4096, 1.0, 1.0, 0.0056, _ring(_P2DX_SONARS), 8,
        (0.75, math.radians(100)), (0.44, 0.38),
    ),
    "p3at": RobotModel(
        "p3at", 1.0, 2 * math.pi / 4096, 1.0, 1.0, 0.0034, _ring(_P3AT_SONARS), 16,
        (0.7, math.radians(140)), (0.626, 0.505),
    ),
}  # fmt: skip


def model_for(subclass: str) -> RobotModel | None:
    """The model for the subclass string a robot announces ("P2DX", "p3at", "P2DXe" ...)."""
    s = subclass.strip().lower()
    if s in MODELS:
        return MODELS[s]
    for k, m in MODELS.items():
        if s.startswith(k):
            return m
    return None


class Odometry:
    """Continuous pose from the wrapping 15-bit position and 12-bit heading counters."""

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self.pose = [0.0, 0.0, 0.0]  # m, m, rad
        self._last: tuple[int, int, int] | None = None
        self._frame = 0.0  # rotation of the reported frame against the robot's counters

    def reset_reference(self) -> None:
        """Forget the counters (after a reconnect the robot starts them again); the pose stays."""
        self._last = None

    def set_pose(self, x: float, y: float, yaw: float) -> None:
        self._frame += wrap(yaw - self.pose[2])
        self.pose = [x, y, wrap(yaw)]

    def update(self, sip: Sip) -> tuple[float, float, float]:
        cur = (sip.xpos, sip.ypos, sip.thpos)
        if self._last is not None:
            m = self.model
            dx = _wrap_count(cur[0] - self._last[0], 15) * m.dist_conv / 1000.0
            dy = _wrap_count(cur[1] - self._last[1], 15) * m.dist_conv / 1000.0
            dth = _wrap_count(cur[2] - self._last[2], 12) * m.angle_conv
            c, s = math.cos(self._frame), math.sin(self._frame)
            self.pose[0] += c * dx - s * dy
            self.pose[1] += s * dx + c * dy
            self.pose[2] = wrap(self.pose[2] + dth)
        self._last = cur
        return (self.pose[0], self.pose[1], self.pose[2])


def _wrap_count(d: int, bits: int) -> int:
    half = 1 << (bits - 1)
    return (d + half) % (1 << bits) - half
