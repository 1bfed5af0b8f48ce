"""``p2os`` driver: Pioneer 2/3 robots over a serial line (Player's p2os driver, thesis 3.3.2, A.2).

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

Threads: a reader thread owns the serial port: it connects (sync handshake with retries), writes
the commands the scheduler queued, sends the keep-alive pulse, reads and parses packets and hands
them over through a deque drained in ``update()``. The scheduler thread never touches the port.
When no SIP arrives for ``timeout`` seconds the robot counts as lost: its devices' tokens are
withdrawn and the thread reconnects with a growing back-off; tokens return with the first SIP.
Bytes that are no packet (noise, bad checksums, truncated packets) are skipped by re-synchronising
on 0xFA 0xFB, counted (``stats``) and reported at most every 5 s.

Provides ``position2d`` (odometry, VelocityCmd), ``sonar`` or ``ranger`` (the sonar ring),
``power``, ``gripper`` (GripperCmd), ``dio`` (digital in/out, DioCmd) and ``actarray`` (the gripper
lift as a one-joint array, Player's ``lift::actarray:0``).
"""

from __future__ import annotations

import collections
import math
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from rsal.geometry import wrap
from rsal.msgs import (
    ActArrayData,
    DioCmd,
    DioData,
    ErrorCode,
    GripperCmd,
    GripperData,
    MessageError,
    Position2dData,
    PowerData,
    RangerData,
    RpcError,
    VelocityCmd,
    get_bool,
    get_float,
    get_int,
    get_vec,
)

from ..baseguard import ESTOP_OPS, BaseGuard
from ..config import ConfigError
from ..driver import Driver, OutOfRange, register
from ..params import param, parse_params

__all__ = [
    "P2osDriver",
    "RobotModel",
    "MODELS",
    "Sip",
    "PacketReader",
    "checksum",
    "packet",
    "command",
    "decode_sip",
    "Odometry",
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


# ---------------------------------------------------------------------------- the serial link
class _Link(threading.Thread):
    """Owns the serial port: connect, write queued commands, pulse, read; events go to ``inbox``."""

    def __init__(self, port: str, baud: int, pulse: float, reconnect: float, timeout: float) -> None:
        super().__init__(name=f"p2os {port}", daemon=True)
        self.port, self.baud, self.pulse, self.reconnect, self.timeout = port, baud, pulse, reconnect, timeout
        # to the scheduler: ("connected", name, class, subclass) | ("sip", t, payload) | ("lost", why)
        self.inbox: collections.deque = collections.deque()
        self.outbox: collections.deque = collections.deque()  # framed commands to write
        self.reader = PacketReader()
        self.stop_event = threading.Event()
        self.connected = False
        self.sync_retries = 3
        self.sync_wait = 0.5  # s to wait for each echo
        self._ser = None

    # the scheduler side -------------------------------------------------------
    def send(self, data: bytes) -> None:
        if self.connected:
            self.outbox.append(data)

    def stop(self, final: list[bytes], timeout: float = 1.0) -> None:
        """Write ``final`` (if connected), then close the port and end the thread."""
        if self.connected:
            self.outbox.extend(final)
        self.stop_event.set()
        if self.is_alive():
            self.join(timeout)

    # the thread ---------------------------------------------------------------
    def run(self) -> None:
        backoff = self.reconnect
        while not self.stop_event.is_set():
            why = self._session()
            if self.stop_event.is_set():
                break
            if self.connected:
                self.connected = False
                backoff = self.reconnect
            self.inbox.append(("lost", why))
            self.stop_event.wait(backoff)
            backoff = min(backoff * 2, 8 * self.reconnect)
        self._flush_and_close()

    def _open(self):
        import serial

        return serial.Serial(self.port, self.baud, timeout=0.02, write_timeout=0.5)

    def _flush_and_close(self) -> None:
        ser = self._ser
        if ser is None:
            return
        try:
            while self.outbox:
                ser.write(self.outbox.popleft())
            ser.flush()
        except Exception:
            pass
        try:
            ser.close()
        except Exception:
            pass
        self._ser = None

    def _session(self) -> str:
        """Connect and serve until the robot is lost; return why."""
        try:
            self._ser = self._open()
        except Exception as e:  # SerialException, OSError: port missing, busy, no permission
            return f"cannot open {self.port}: {e}"
        try:
            self.outbox.clear()
            self.reader.buf.clear()  # counters survive reconnections
            ident = self._sync()
            if ident is None:
                return f"no answer to the sync handshake on {self.port} at {self.baud} baud"
            self.connected = True
            self.inbox.append(("connected", *ident))
            for c in (command(OPEN), command(SONAR, 1), command(ENABLE, 1), command(PULSE)):
                self._ser.write(c)
            last_sip = time.monotonic()
            last_pulse = last_sip
            while not self.stop_event.is_set():
                while self.outbox:
                    self._ser.write(self.outbox.popleft())
                now = time.monotonic()
                if now - last_pulse >= self.pulse:
                    self._ser.write(command(PULSE))
                    last_pulse = now
                data = self._ser.read(max(1, self._ser.in_waiting))
                now = time.monotonic()
                for p in self.reader.feed(data) if data else ():
                    if is_sip(p):
                        last_sip = now
                        self.inbox.append(("sip", now, p))
                if now - last_sip > self.timeout:
                    return f"no data from the robot for {self.timeout:g} s"
            return "stopped"
        except Exception as e:  # the port went away under us
            return f"{self.port}: {type(e).__name__}: {e}"
        finally:
            if not self.stop_event.is_set():
                self._close_quietly()

    def _close_quietly(self) -> None:
        try:
            self._ser.close()
        except Exception:
            pass
        self._ser = None

    def _expect(self, want: int) -> bytes | None:
        """Read packets for up to ``sync_wait`` s; the payload starting with ``want`` or None."""
        deadline = time.monotonic() + self.sync_wait
        sips = False
        while time.monotonic() < deadline and not self.stop_event.is_set():
            data = self._ser.read(max(1, self._ser.in_waiting))
            for p in self.reader.feed(data) if data else ():
                if p[0] == want and (want != SYNC0 or len(p) == 1):
                    return p
                sips = sips or is_sip(p)
        if sips:  # still open from an earlier client: close it before syncing again
            self._ser.write(command(CLOSE))
        return None

    def _sync(self) -> tuple[str, str, str] | None:
        for step in (SYNC0, SYNC1, SYNC2):
            for _ in range(self.sync_retries):
                self._ser.write(command(step))
                p = self._expect(step)
                if p is not None:
                    break
            else:
                return None
        strings = p[1:].split(b"\0")
        name, cls, sub = (
            (s.decode("ascii", "replace").strip() for s in strings[:3]) if len(strings) >= 3 else ("", "", "")
        )
        return name, cls, sub


# ---------------------------------------------------------------------------- the driver
@dataclass(frozen=True)
class P2osParams:
    """The ``p2os`` driver's parameters (module docstring)."""

    port: str = param(doc="the robot's serial device", example="/dev/ttyS0")
    baud: Literal[9600, 19200, 38400, 57600, 115200] = param(9600)
    model: str | None = param(None, choices=tuple(MODELS))
    pulse: float = param(0.5, min=0.05, max=1.5, unit="seconds")
    reconnect: float = param(1.0, min=0.05, max=60.0, unit="seconds")
    timeout: float = param(1.0, min=0.2, max=30.0, unit="seconds")
    sonars: Literal[8, 16] | None = param(None, expect="8 or 16 (transducers fitted)")
    cmd_timeout: Any = param(None, doc="s, read by the base guard (mrs_bridge.baseguard)")


WARN_INTERVAL = 5.0
POWER_EMPTY, POWER_FULL = 10.5, 13.0  # V: 0 % and 100 % of a 12 V lead-acid pack


@register("p2os")
class P2osDriver(Driver):
    interfaces = ("position2d", "sonar", "ranger", "power", "gripper", "dio", "actarray")
    default_rate = 20.0  # Hz: how often the SIPs received are drained and published
    data_types = {
        "position2d": "Position2dData",
        "sonar": "RangerData",
        "ranger": "RangerData",
        "power": "PowerData",
        "gripper": "GripperData",
        "dio": "DioData",
        "actarray": "ActArrayData",
    }
    cmd_types = {"position2d": "VelocityCmd", "gripper": "GripperCmd", "dio": "DioCmd"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        p = self.settings = parse_params(P2osParams, cfg)
        try:
            import serial  # noqa: F401
        except ImportError:
            raise ConfigError(
                f"{cfg.where}: the p2os driver needs pyserial; install it with: pip install pyserial"
            ) from None
        self.port, self.baud = p.port, p.baud
        self.pulse, self.reconnect, self.timeout = p.pulse, p.reconnect, p.timeout
        self.forced_model = MODELS[p.model] if p.model is not None else None
        self.sonar_override = p.sonars
        for a in cfg.provides:
            if a.index != 0:
                raise ConfigError(
                    f"{cfg.where}: a Pioneer has one {a.interface}; provide {a.interface}:0, not :{a.index}"
                )
        self.online = False  # tokens come with the robot's first SIP
        self.model: RobotModel | None = self.forced_model
        self.odom: Odometry | None = None
        self.ident: tuple[str, str, str] | None = None
        self.link: _Link | None = None
        self.last_sip: Sip | None = None
        self.sonar_ranges: np.ndarray | None = None
        self._sonar_fresh = False  # readings arrived since the last sonar publication
        self.stats = {"sips": 0, "skipped_bytes": 0, "bad_packets": 0, "bad_sips": 0, "reconnects": 0}
        self._reported = (0, 0)
        self._last_warn = -math.inf
        self._motors = True
        self._last_grip_cmd = ""
        self._lost_reason = ""
        self._t0 = time.monotonic()
        self.guard = BaseGuard.for_driver(self, cfg.provides[0].node)

    # ------------------------------------------------------------------ lifecycle
    def setup(self) -> None:
        self.online = False
        self.link = _Link(self.port, self.baud, self.pulse, self.reconnect, self.timeout)
        self.link.start()
        self.log.info("%s: connecting to the robot on %s at %d baud", self.cfg.where, self.port, self.baud)

    def shutdown(self) -> None:
        link = self.link
        if link is None:
            return
        link.stop([command(VEL, 0), command(RVEL, 0), command(ENABLE, 0), command(CLOSE)])
        self.link = None

    def update(self, now: float) -> None:
        link = self.link
        if link is None:
            return
        newest: Sip | None = None
        stamp = 0.0
        while link.inbox:
            item = link.inbox.popleft()
            kind = item[0]
            if kind == "sip":
                sip = self._on_sip(item[2])
                if sip is not None:
                    newest, stamp = sip, item[1]
            elif kind == "connected":
                self._on_connected(item[1], item[2], item[3])
            elif kind == "lost":
                self._on_lost(item[1])
        if self.guard.expired():  # the commander went silent: ARCOS would drive on while we pulse
            try:
                self._velocity(0.0, 0.0)
            except RpcError:
                pass  # not answering: ARCOS stops by itself without our pulse
        if newest is not None:
            self._publish(newest, stamp - self._t0)
        self._report_noise(now)

    def _on_connected(self, name: str, cls: str, sub: str) -> None:
        model = self.forced_model or model_for(sub)
        if model is None:
            raise ConfigError(
                f"{self.cfg.where}: the robot on {self.port} calls itself {cls!r} {sub!r}, a model this driver does "
                f"not know; set model = one of {', '.join(MODELS)}"
            )
        if self.model is not model or self.odom is None:
            self.model = model
            self.odom = Odometry(model)
            n = self.sonar_override or model.sonars
            self.sonar_ranges = np.full(n, model.sonar_range[1], dtype="<f4")
        self.odom.reset_reference()
        if self.ident is not None:
            self.stats["reconnects"] += 1
        self.ident = (name, cls, sub)
        self._motors = True
        self.log.info("%s: connected to %s (%s %s) on %s", self.cfg.where, name or "?", cls, sub, self.port)

    def _on_lost(self, why: str) -> None:
        if self.online:
            self.log.warning("%s: robot lost (%s); devices withdrawn, reconnecting", self.cfg.where, why)
            self.set_online(False)
        elif why != self._lost_reason:
            self.log.warning("%s: %s; retrying every %g s or more", self.cfg.where, why, self.reconnect)
        self._lost_reason = why

    def _on_sip(self, payload: bytes) -> Sip | None:
        if self.odom is None:
            return None
        try:
            sip = decode_sip(payload)
        except ValueError:
            self.stats["bad_sips"] += 1
            return None
        self.stats["sips"] += 1
        self.odom.update(sip)
        rng = self.sonar_ranges
        if sip.sonars and rng is not None:
            idx = np.array([s[0] for s in sip.sonars])
            val = np.array([s[1] for s in sip.sonars], dtype=np.float64) * (self.model.range_conv / 1000.0)
            ok = idx < len(rng)
            rng[idx[ok]] = np.clip(val[ok], 0.0, self.model.sonar_range[1])
            self._sonar_fresh = True
        self.last_sip = sip
        if not self.online:
            self.set_online(True)
            self._lost_reason = ""
            self.log.info("%s: robot answering; devices online", self.cfg.where)
        return sip

    def _report_noise(self, now: float) -> None:
        r = self.link.reader if self.link else None
        if r is None:
            return
        self.stats["skipped_bytes"] = r.skipped
        self.stats["bad_packets"] = r.bad
        cur = (self.stats["skipped_bytes"], self.stats["bad_packets"])
        if cur != self._reported and now - self._last_warn >= WARN_INTERVAL:
            self.log.warning(
                "%s: skipped %d byte(s) of line noise and %d bad packet(s) from %s (check cable and baud rate)",
                self.cfg.where,
                cur[0] - self._reported[0],
                cur[1] - self._reported[1],
                self.port,
            )
            self._reported = cur
            self._last_warn = now

    # ------------------------------------------------------------------ publishing
    def _t(self) -> float:
        return time.monotonic() - self._t0

    def _publish(self, sip: Sip, t: float) -> None:
        """Publish the newest SIP, stamped with its arrival (s since the driver started)."""
        m = self.model
        assert m is not None and self.odom is not None
        lv, rv = sip.l_vel * m.vel_conv, sip.r_vel * m.vel_conv  # mm/s
        v = (lv + rv) / 2000.0
        w = (rv - lv) * m.diff_conv / 2.0
        for a in self.cfg.provides:
            iface = a.interface
            if iface == "position2d":
                p = self.odom.pose
                g = self.guard
                self.publish(a, Position2dData(t, (p[0], p[1], p[2]), (v, 0.0, w), sip.stalled, g.timed_out, g.estop))
            elif iface in ("sonar", "ranger"):
                if self._sonar_fresh and self.sonar_ranges is not None:
                    self.publish(a, RangerData(t, self.sonar_ranges.copy(), 0.0, 0.0, *m.sonar_range))
            elif iface == "power":
                volts = sip.volts
                pct = min(100.0, max(0.0, 100.0 * (volts - POWER_EMPTY) / (POWER_FULL - POWER_EMPTY)))
                self.publish(a, PowerData(t, volts, pct, bool(sip.charge_state)))
            elif iface == "gripper" and sip.gripper is not None:
                self.publish(a, self._gripper_msg(t, sip.gripper))
            elif iface == "dio" and sip.digin is not None:
                self.publish(a, DioData(t, 8, sip.digin, sip.digout or 0))
            elif iface == "actarray" and sip.gripper is not None:
                self.publish(a, self._lift_msg(t, sip.gripper))
        self._sonar_fresh = False

    def _gripper_msg(self, t: float, g: int) -> GripperData:
        if g & 1:
            paddles = "open"
        elif g & 2:
            paddles = "closed"
        else:
            paddles = "closing" if self._last_grip_cmd == "close" else "opening"
        if g & 4:
            lift = "up"
        elif g & 8:
            lift = "down"
        else:
            lift = "lowering" if self._last_grip_cmd == "down" else "raising"
        beams = (g >> 4) & 3
        stored = 1 if (g & 2 and beams) else 0
        return GripperData(t, paddles, lift, beams, stored, None)

    @staticmethod
    def _lift_msg(t: float, g: int) -> ActArrayData:
        if g & 4:
            pos, state = 1.0, "idle"
        elif g & 8:
            pos, state = 0.0, "idle"
        else:
            pos, state = 0.5, "moving" if g & 0x80 else "stalled"
        return ActArrayData(t, (pos,), (0.0,), (state,))

    def publish_rate(self, addr) -> float:
        return 10.0  # the robot's SIP rate

    # ------------------------------------------------------------------ commands
    def _need_robot(self) -> _Link:
        if self.link is None or not self.link.connected or self.model is None:
            raise RpcError(ErrorCode.UNAVAILABLE, f"the robot on {self.port} is not answering")
        return self.link

    def _velocity(self, v: float, w: float) -> None:
        link = self._need_robot()
        link.send(command(VEL, int(round(v * 1000.0))))
        link.send(command(RVEL, int(round(math.degrees(w)))))

    def on_cmd(self, addr, msg):
        iface = addr.interface
        if iface == "position2d":
            try:
                self._command(VelocityCmd.from_dict(msg))
            except RpcError as e:
                raise MessageError(e.message) from None
        elif iface == "gripper":
            self._gripper(GripperCmd.from_dict(msg).action)
        elif iface == "dio":
            c = DioCmd.from_dict(msg)
            self._digout(c.bits, c.mask)
        else:
            raise MessageError(f"{addr} takes no commands")

    def _command(self, c: VelocityCmd, *, rpc: bool = False) -> None:
        m = self.model or self.forced_model
        if m is not None:
            vmax, wmax = m.max_speed
            if abs(c.v) > vmax + 1e-9 or abs(c.w) > wmax + 1e-9:
                raise OutOfRange(
                    f"v={c.v:g} m/s, w={c.w:g} rad/s exceeds the {m.name} limits |v| <= {vmax:g}, |w| <= {wmax:.3g}"
                )
        if c.vy != 0.0:
            raise OutOfRange(f"vy={c.vy:g}: a differential drive cannot move sideways")
        self.guard.check(rpc=rpc)
        if not self._motors:
            return
        self._velocity(c.v, c.w)
        self.guard.command(c.v, c.w)

    def _gripper(self, action: str) -> None:
        try:
            link = self._need_robot()
        except RpcError as e:
            raise MessageError(e.message) from None
        link.send(command(GRIPPER, GRIPPER_ARGS[action]))
        self._last_grip_cmd = action

    def _digout(self, bits: int, mask: int) -> None:
        self._need_robot().send(command(DIGOUT, (mask << 8) | bits))

    def ops(self, addr):
        i = addr.interface
        if i == "position2d":
            return ["set_odom", "motor_power", "stop", "status", *ESTOP_OPS]
        if i == "gripper":
            return ["open", "close", "up", "down", "stop"]
        if i in ("sonar", "ranger"):
            return ["get"]
        if i == "dio":
            return ["set"]
        if i == "actarray":
            return ["set_position", "home"]
        return []

    def on_rpc(self, addr, op, args):
        i = addr.interface
        if i == "position2d":
            if op == "set_odom":
                x, y, a = get_vec(args, "pose", 3)
                if self.odom is None:
                    raise RpcError(ErrorCode.UNAVAILABLE, f"the robot on {self.port} has not answered yet")
                self.odom.set_pose(x, y, a)
                return {"pose": [x, y, a]}
            if op == "motor_power":
                on = get_bool(args, "on")
                link = self._need_robot()
                if not on:
                    self._velocity(0.0, 0.0)
                link.send(command(ENABLE, 1 if on else 0))
                self._motors = on
                if not on:
                    self.guard.stopped()
                return {"on": on}
            if op == "stop":
                self._velocity(0.0, 0.0)
                self.guard.stopped()
                return {}
            if op == "set_velocity":
                self._command(VelocityCmd.from_dict(args), rpc=True)
                return {}
            if op == "estop":
                self.guard.press()  # latched even while the robot does not answer (ARCOS stops then)
                try:
                    self._velocity(0.0, 0.0)
                except RpcError:
                    pass
                return {"estop": True}
            if op == "release":
                self.guard.release()
                return {"estop": False}
            if op == "status":
                connected = self.link is not None and self.link.connected
                return {"connected": connected, "robot": list(self.ident or ()), **self.stats}
        if i == "gripper" and op in GRIPPER_ARGS:
            self._need_robot()
            self._gripper(op)
            return {"action": op}
        if i in ("sonar", "ranger") and op == "get":
            if self.sonar_ranges is None or self.model is None:
                raise RpcError(ErrorCode.UNAVAILABLE, "no sonar reading yet")
            return RangerData(self._t(), self.sonar_ranges.copy(), 0.0, 0.0, *self.model.sonar_range).to_dict()
        if i == "dio" and op == "set":
            self._digout(get_int(args, "bits", lo=0, hi=0xFF), get_int(args, "mask", 0xFF, lo=0, hi=0xFF))
            return {}
        if i == "actarray" and op in ("set_position", "home"):
            self._need_robot()
            if get_int(args, "joint", 0, lo=0, hi=0) != 0:
                raise OutOfRange("the lift has one joint, 0")
            pos = 0.0 if op == "home" else get_float(args, "position", lo=0.0, hi=1.0)
            self._gripper("up" if pos >= 0.5 else "down")
            return {"position": 1.0 if pos >= 0.5 else 0.0}
        return super().on_rpc(addr, op, args)

    def geometry(self, addr) -> dict[str, Any]:
        m = self.model or self.forced_model
        i = addr.interface
        base: dict[str, Any] = {"port": self.port, "model": m.name if m else ""}
        if self.ident:
            base["robot"] = {"name": self.ident[0], "class": self.ident[1], "subclass": self.ident[2]}
        if m is None:
            return base
        if i == "position2d":
            return {**base, "size": list(m.size), "max_speed": list(m.max_speed), "frame": "odom"}
        if i in ("sonar", "ranger"):
            n = self.sonar_override or m.sonars
            lo, hi = m.sonar_range
            fov = math.radians(15)
            return {
                **base,
                "kind": "sonar",
                "pose": [0.0, 0.0, 0.0],
                "sensors": [
                    {"pose": list(p), "fov": fov, "samples": 1, "range_min": lo, "range_max": hi}
                    for p in m.sonar_poses[:n]
                ],
            }
        if i == "actarray":
            return {**base, "actuators": [{"type": "linear", "min": 0.0, "max": 1.0, "name": "lift"}]}
        if i == "dio":
            return {**base, "inputs": 8, "outputs": 8}
        return base
