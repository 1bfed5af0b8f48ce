"""Pioneer P2OS / ARCOS packet codec: framing, checksum, client commands, SIP parsing (no I/O).

Spec: ActivMedia/MobileRobots "Pioneer 2 / PeopleBot Operations Manual" (P2OS client-server
protocol) and the ARCOS manual; the same protocol Player's ``p2os`` driver speaks (thesis 3.3.2,
A.2). Moved here from the driver unchanged: the bit meanings are the driver's as they were.

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

Standard server information packet (SIP), decoded by :func:`decode_sip`; offsets into the payload,
multi-byte values little-endian:

====== ===== =====================================================================================
offset bytes field
====== ===== =====================================================================================
0      1     type: 0x32 stopped, 0x33 moving
1      2     xpos: 15-bit counter of DistConv mm units, wraps around
3      2     ypos: likewise
5      2     thpos: heading, 4096 units per revolution (12 bits used, wraps around)
7      2     l_vel: left wheel, signed, VelConv mm/s
9      2     r_vel: right wheel, likewise
11     1     battery: 0.1 V
12     2     stall and bumpers: bit 0 left wheel stalled, bits 1-7 rear bumpers; bit 8 right wheel
             stalled, bits 9-15 front bumpers
14     2     control: servo heading set-point (not used)
16     2     flags: bit 0 motors enabled, bits 1-4 sonar arrays on
18     1     compass: 2 degree units (not used)
19     1     sonar readings n, followed by n times: sonar number (1 byte), range (2 bytes, RangeConv mm)
20+3n  1     gripper state: bit 0 paddles open, 1 paddles closed, 2 lift up, 3 lift down, 4 inner
             break beam, 5 outer break beam, 6 paddles moving, 7 lift moving
+1     1     analog port selected
+2     1     analog value (0..255 = 0..5 V)
+3     1     digital inputs
+4     1     digital outputs
+5     2     battery x10: 0.1 V (more precise firmwares; 0 = use the 1-byte value)
+7     1     charge state: 0 not charging, 1 bulk, 2 overcharge, 3 float
====== ===== =====================================================================================

Everything after the sonar readings is optional (older firmwares end there). Odometry integrates
the differences of the wrapping counters, so the pose is continuous across wrap-arounds and
reconnections; the conversion factors come from a per-model table (:data:`MODELS`) chosen by the
subclass the robot announces (or the ``model`` parameter).

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

# GRIPPER command arguments (Pioneer gripper manual)
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


@dataclass(frozen=True)
class Sip:
    """A decoded standard SIP in the robot's raw units (see the module docstring)."""

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
    gripper: int | None = None
    analog_port: int | None = None
    analog: int | None = None
    digin: int | None = None
    digout: int | None = None
    battery_x10: int | None = None
    charge_state: int | None = None

    @property
    def stalled(self) -> bool:
        return bool(self.stall_bumpers & 0x0101)

    @property
    def motors_enabled(self) -> bool:
        return bool(self.flags & 1)

    @property
    def volts(self) -> float:
        return (self.battery_x10 if self.battery_x10 else self.battery) / 10.0


_SIP_HEAD = struct.Struct("<BHHhhhBHhHBB")  # type .. sonar count: 20 bytes
_SIP_TAIL = struct.Struct("<BBBBBHB")  # gripper .. charge state: 8 bytes


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
    tail: tuple = (None,) * 7
    if len(payload) >= end + _SIP_TAIL.size:
        tail = _SIP_TAIL.unpack_from(payload, end)
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
