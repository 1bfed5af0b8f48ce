"""An emulated Pioneer robot on a pseudo-terminal: the ``p2os`` driver without hardware.

Written from the manuals, independently of the driver: nothing here is imported from the project
(not the driver, not its codec :mod:`mrs_bridge.hw.p2os`). The packet layout is this module's own
tables (:data:`SIP_HEAD`, :data:`SIP_TAIL`, :data:`GRIP`, :data:`DIGIN`), taken from the "Pioneer 2
/ PeopleBot Operations Manual" chapter "P2OS", section "Server Information Packets" (standard SIP),
the "Pioneer 3 Operations Manual" chapter "ARCOS", section "Standard SIP" (BATTERYX10, CHARGESTATE);
the gripper's bits, which the manuals leave out, as Player's ``p2os`` decodes them (the gripper
state byte in the TIMER high byte) and ARIA's ``ArGripper`` reads its break beams from DIGIN (read
for their meaning, not copied). :func:`encode_sip` turns a :class:`SipState` (raw units) into a
payload; :func:`frame` frames it (header, count, payload, checksum).

:class:`PioneerEmulator` opens ``os.openpty()``; the driver opens the slave side by its path
(:attr:`PioneerEmulator.path`) like a serial port. A thread answers the P2OS sync handshake
(SYNC0/1/2 echoed, the SYNC2 echo carrying name, class and subclass), obeys OPEN, CLOSE, PULSE,
ENABLE, VEL, RVEL, SONAR, DIGOUT and GRIPPER, integrates a unicycle model of the commanded speeds
(stopping when no command arrived for 2 s, as the real watchdog does) and, once opened, sends
standard SIPs at 10 Hz with sonar ranges from a fixed table, a battery voltage, bumpers and wheel
stalls as set by the test, and a gripper whose paddles and lift take ``paddle_time`` and
``lift_time`` seconds to move (reported as moving meanwhile) and whose break beams and paddle
contacts the test sets (:attr:`inner_beam`, :attr:`outer_beam`, :attr:`contacts`).

The robot's body is the emulator's own unicycle by default. Given a ``body`` (:class:`Body`: any
object with ``drive``, ``gripper`` and ``sense``), the emulator is only the microcontroller: the
speeds it would drive (zero while the motors are off or the watchdog has fired) go to
``body.drive(v, w)`` (m/s, rad/s), GRIPPER commands to ``body.gripper(action)``, and every SIP
reports what ``body.sense()`` returns (:class:`Sensed`: the wheel odometry, wheel speeds, stall,
bumpers, battery, gripper, break beams and sonar ranges, in SI units). ``rsal rehearse`` passes
the body of a robot in a simulated world (:mod:`mrs_bridge.rehearse`).

Faults on demand: :attr:`silent` (answer nothing, read nothing), :meth:`inject_garbage` (random
bytes between packets), :attr:`corrupt` (the next n SIPs with a wrong checksum), :attr:`truncate`
(the next n SIPs cut short).
"""

from __future__ import annotations

import math
import os
import random
import select
import struct
import threading
import time
import tty
from dataclasses import dataclass, field
from typing import Protocol

# ---------------------------------------------------------------------------- tables (the manuals)
#: standard SIP, TYPE .. SONAR COUNT: (name, struct code), little-endian
SIP_HEAD = [
    ("TYPE", "B"),  # 0x32 stopped, 0x33 moving
    ("XPOS", "H"),  # 15-bit wrapping counter, DistConv mm
    ("YPOS", "H"),
    ("THPOS", "H"),  # 4096 per revolution, 12 bits
    ("L_VEL", "h"),  # VelConv mm/s
    ("R_VEL", "h"),
    ("BATTERY", "B"),  # 0.1 V
    ("STALL_AND_BUMPERS", "H"),  # bit 0 left stall, 1-7 rear bumpers, 8 right stall, 9-15 front
    ("CONTROL", "h"),  # heading servo set-point
    ("FLAGS", "H"),  # bit 0 motors enabled, bits 1-4 sonar arrays on
    ("COMPASS", "B"),  # 2-degree units
    ("SONAR_COUNT", "B"),  # n, then n x (NUMBER B, RANGE H)
]
SONAR_READING = "<BH"
#: after the sonar readings
SIP_TAIL = [
    ("TIMER", "H"),  # high byte: the gripper state byte (GRIP)
    ("ANALOG", "B"),  # 0..255 = 0..5 V
    ("DIGIN", "B"),  # gripper beams and contacts (DIGIN), user inputs
    ("DIGOUT", "B"),
    ("BATTERYX10", "H"),  # ARCOS: 0.1 V
    ("CHARGESTATE", "B"),  # ARCOS: 0 not charging, 1 bulk, 2 overcharge, 3 float
]
SIP_STOPPED, SIP_MOVING = 0x32, 0x33
#: the gripper state byte (TIMER high byte)
GRIP = {"open": 0x01, "closed": 0x02, "paddles_moving": 0x04, "up": 0x10, "down": 0x20, "lift_moving": 0x40}
#: DIGIN bits of the gripper; the contacts read 0 when touching
DIGIN = {"outer_beam": 0x04, "inner_beam": 0x08, "left_contact": 0x10, "right_contact": 0x20}
#: client command numbers and argument types
CMD = {"PULSE": 0, "OPEN": 1, "CLOSE": 2, "ENABLE": 4, "VEL": 11, "RVEL": 21, "SONAR": 28, "DIGOUT": 30, "GRIPPER": 33}
SYNC = (0, 1, 2)
ARG_POS, ARG_NEG = 0x3B, 0x1B
#: GRIPPER command arguments
GRIPPER_ARG = {1: "open", 2: "close", 3: "stop", 4: "up", 5: "down", 6: "lift_stop"}

DIST_CONV = {"P2DX": 0.840, "P3AT": 1.0}  # mm per count, the robots' parameter files
ANGLE_CONV = 2 * math.pi / 4096
DIFF_CONV = {"P2DX": 0.0056, "P3AT": 0.0034}


def frame(payload: bytes, *, bad_checksum: bool = False) -> bytes:
    """Header 0xFA 0xFB, count (payload + 2), payload, checksum: the 16-bit big-endian word sum,
    an odd last byte xor'd in, sent high byte first."""
    c = 0
    for i in range(0, len(payload) - 1, 2):
        c = (c + (payload[i] << 8 | payload[i + 1])) & 0xFFFF
    if len(payload) % 2:
        c ^= payload[-1]
    if bad_checksum:
        c ^= 0x5A5A
    return bytes([0xFA, 0xFB, len(payload) + 2]) + payload + bytes([c >> 8, c & 0xFF])


@dataclass
class SipState:
    """One standard SIP's fields in the robot's raw units."""

    xpos: int = 0
    ypos: int = 0
    thpos: int = 0
    l_vel: int = 0
    r_vel: int = 0
    battery: int = 0  # 0.1 V
    stall_left: bool = False
    stall_right: bool = False
    front_bumpers: int = 0  # bit i = segment i + 1
    rear_bumpers: int = 0
    control: int = 0
    flags: int = 0
    compass: int = 0
    sonars: list[tuple[int, int]] = field(default_factory=list)  # (number, range)
    tail: bool = True  # TIMER .. CHARGESTATE present
    timer_low: int = 0
    grip: int = 0  # the gripper state byte
    analog: int = 0
    digin: int = 0
    digout: int = 0
    battery_x10: int = 0
    charge_state: int = 0


def encode_sip(s: SipState) -> bytes:
    """The payload of a standard SIP (the tables above)."""
    stall_bumpers = (
        (1 if s.stall_left else 0) | (s.rear_bumpers & 0x7F) << 1 | (0x100 if s.stall_right else 0)
        | (s.front_bumpers & 0x7F) << 9
    )  # fmt: skip
    moving = SIP_MOVING if (s.l_vel or s.r_vel) else SIP_STOPPED
    head = [moving, s.xpos, s.ypos, s.thpos, s.l_vel, s.r_vel, s.battery, stall_bumpers, s.control, s.flags]
    head += [s.compass, len(s.sonars)]
    out = struct.pack("<" + "".join(c for _, c in SIP_HEAD), *head)
    out += b"".join(struct.pack(SONAR_READING, n, r) for n, r in s.sonars)
    if s.tail:
        tail = [s.timer_low | s.grip << 8, s.analog, s.digin, s.digout, s.battery_x10, s.charge_state]
        out += struct.pack("<" + "".join(c for _, c in SIP_TAIL), *tail)
    return out


@dataclass(frozen=True)
class Sensed:
    """What a robot's body reports to its microcontroller, in SI units."""

    odom: tuple[float, float, float]  # wheel odometry x, y (m), heading (rad) since power-on
    vel: tuple[float, float] = (0.0, 0.0)  # forward speed (m/s), turn rate (rad/s) of the wheels
    stall: tuple[bool, bool] = (False, False)  # left, right wheel
    front_bumpers: int = 0  # segments pressed, bit i = segment i + 1
    rear_bumpers: int = 0
    battery: float = 12.3  # V
    paddles: str = "open"  # "open" | "closed" | "opening" | "closing"
    lift: str = "down"  # "up" | "down" | "raising" | "lowering"
    inner_beam: bool = False  # broken
    outer_beam: bool = False
    contacts: tuple[bool, bool] = (False, False)  # left, right paddle touching
    sonars: tuple[float, ...] | None = None  # m per transducer; None: the emulator's fixed table


class Body(Protocol):
    """The robot's mechanics as the emulated microcontroller sees them (module docstring)."""

    def drive(self, v: float, w: float) -> None: ...

    def gripper(self, action: str) -> None: ...

    def sense(self) -> Sensed: ...


class PioneerEmulator:
    def __init__(
        self,
        subclass: str = "P2DX",
        name: str = "emu",
        sonars: int = 8,
        rate: float = 10.0,
        body: Body | None = None,
    ):
        self.subclass, self.name, self.n_sonars, self.period = subclass, name, sonars, 1.0 / rate
        self.body = body
        self._driven: tuple[float, float] | None = None  # what body.drive was last told
        self.subclass_announced = subclass  # what SYNC2 answers (a test may make it unknown)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        tty.setraw(self.master)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.lock = threading.Lock()
        # state
        self.synced = -1  # last sync step answered
        self.open = False
        self.motors = False
        self.sonar_on = False
        self.v = 0.0  # mm/s commanded
        self.w = 0.0  # deg/s commanded
        self.x = self.y = self.th = 0.0  # mm, mm, rad
        self.start_counts = (32700, 100, 0)  # counters start near the 15-bit wrap
        self.battery = 12.3  # V
        self.charge_state = 0
        self.sonar_table = [0.5 + 0.25 * i for i in range(sonars)]  # m
        self.front_bumpers = self.rear_bumpers = 0  # segments pressed, bit i = segment i + 1
        self.stall = (False, False)  # left, right wheel
        # the gripper: paddles "open"/"closed"/"opening"/"closing", lift "up"/"down"/"raising"/"lowering"
        self.paddles, self.lift = "open", "down"
        self.paddle_time, self.lift_time = 0.3, 0.3  # s per motion
        self._paddle_done = self._lift_done = 0.0  # when the current motion ends
        self.inner_beam = self.outer_beam = False
        self.contacts = (False, False)  # left, right paddle touching
        self.user_inputs = 0b1000_0001  # DIGIN bits not wired to the gripper (0, 1, 6, 7)
        self.digout = 0
        # faults
        self.silent = False
        self.corrupt = 0
        self.truncate = 0
        self._garbage = bytearray()
        # records
        self.received: list[tuple[int, int | None]] = []  # (command, int argument)
        self.sips_sent = 0
        self._last_cmd = time.monotonic()
        self._buf = bytearray()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pioneer-emulator", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ test controls
    def inject_garbage(self, data: bytes | None = None, n: int = 64) -> None:
        with self.lock:
            self._garbage += data if data is not None else bytes(random.Random(n).randrange(256) for _ in range(n))

    def commands(self, cmd: int) -> list[int | None]:
        with self.lock:
            return [a for c, a in self.received if c == cmd]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    # ------------------------------------------------------------------ the robot
    def _run(self) -> None:
        last = time.monotonic()
        next_sip = last
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.01)
            data = b""
            if r:
                try:
                    data = os.read(self.master, 4096)
                except (BlockingIOError, OSError):
                    data = b""
            now = time.monotonic()
            with self.lock:
                if not self.silent:
                    self._buf += data
                    for p in self._packets():
                        self._on_command(p, now)
                self._integrate(now - last, now)
                self._move_gripper(now)
                last = now
                out = bytearray()
                if self._garbage and not self.silent:
                    out += self._garbage
                    self._garbage.clear()
                if self.open and not self.silent and now >= next_sip:
                    next_sip = now + self.period
                    out += self._sip()
            if out:
                self._write(bytes(out))

    def _write(self, data: bytes) -> None:
        try:
            os.write(self.master, data)
        except (BlockingIOError, OSError):  # nobody reading: the pty buffer is full; drop like a line
            pass

    def _packets(self):
        b = self._buf
        while True:
            i = b.find(b"\xfa\xfb")
            if i < 0:
                del b[:-1]
                return
            del b[:i]
            if len(b) < 3 or len(b) < 3 + b[2]:
                return
            n = b[2]
            payload = bytes(b[3 : 1 + n])
            ok = frame(payload)[-2:] == bytes(b[1 + n : 3 + n])
            del b[: 3 + n]
            if ok:
                yield payload

    def _on_command(self, p: bytes, now: float) -> None:
        cmd = p[0]
        arg = None
        if len(p) >= 4 and p[1] in (ARG_POS, ARG_NEG):
            arg = p[2] | p[3] << 8
            if p[1] == ARG_NEG:
                arg = -arg
        if not self.open:  # the sync handshake; after SYNC2 a [1] is OPEN, not SYNC1
            if len(p) == 1 and cmd in (0, 1, 2) and not (cmd == 1 and self.synced == 2):
                if cmd == 0 or self.synced >= cmd - 1:
                    self.synced = cmd
                    extra = b""
                    if cmd == 2:
                        extra = self.name.encode() + b"\0Pioneer\0" + self.subclass_announced.encode() + b"\0"
                    self._write(frame(bytes([cmd]) + extra))
                return
            if cmd == 1 and self.synced == 2:  # OPEN
                self.open = True
                self.received.append((cmd, arg))
                self._last_cmd = now
            return
        self.received.append((cmd, arg))
        self._last_cmd = now
        if cmd == CMD["CLOSE"]:
            self.open = False
            self.synced = -1
            self.motors = False
            self.v = self.w = 0.0
        elif cmd == CMD["ENABLE"]:
            self.motors = arg == 1
            if not self.motors:
                self.v = self.w = 0.0
        elif cmd == CMD["VEL"]:
            self.v = float(arg or 0)
        elif cmd == CMD["RVEL"]:
            self.w = float(arg or 0)
        elif cmd == CMD["SONAR"]:
            self.sonar_on = arg == 1
        elif cmd == CMD["DIGOUT"] and arg is not None:
            mask, bits = arg >> 8, arg & 0xFF
            self.digout = (self.digout & ~mask) | (bits & mask)
        elif cmd == CMD["GRIPPER"]:
            what = GRIPPER_ARG.get(arg or 0, "")
            if self.body is not None and what:
                self.body.gripper(what)
            else:
                self._grip_command(what, now)

    def _grip_command(self, what: str, now: float) -> None:
        if what == "open" and self.paddles != "open":
            self.paddles, self._paddle_done = "opening", now + self.paddle_time
        elif what == "close" and self.paddles != "closed":
            self.paddles, self._paddle_done = "closing", now + self.paddle_time
        elif what == "up" and self.lift != "up":
            self.lift, self._lift_done = "raising", now + self.lift_time
        elif what == "down" and self.lift != "down":
            self.lift, self._lift_done = "lowering", now + self.lift_time

    def _move_gripper(self, now: float) -> None:
        if self.paddles in ("opening", "closing") and now >= self._paddle_done:
            self.paddles = "open" if self.paddles == "opening" else "closed"
        if self.lift in ("raising", "lowering") and now >= self._lift_done:
            self.lift = "up" if self.lift == "raising" else "down"

    def grip_byte(self) -> int:
        """The gripper state byte for the current paddles and lift (table GRIP)."""
        g = {
            "open": GRIP["open"],
            "closed": GRIP["closed"],
            "opening": GRIP["paddles_moving"] | GRIP["open"],
            "closing": GRIP["paddles_moving"] | GRIP["closed"],
        }[self.paddles]
        return (
            g
            | {
                "up": GRIP["up"],
                "down": GRIP["down"],
                "raising": GRIP["lift_moving"] | GRIP["up"],
                "lowering": GRIP["lift_moving"] | GRIP["down"],
            }[self.lift]
        )

    def digin_byte(self) -> int:
        """DIGIN: the user inputs and the gripper's beams (1 = broken) and contacts (0 = touching)."""
        d = self.user_inputs & ~sum(DIGIN.values())
        d |= DIGIN["inner_beam"] if self.inner_beam else 0
        d |= DIGIN["outer_beam"] if self.outer_beam else 0
        d |= 0 if self.contacts[0] else DIGIN["left_contact"]
        d |= 0 if self.contacts[1] else DIGIN["right_contact"]
        return d

    def _integrate(self, dt: float, now: float) -> None:
        if now - self._last_cmd > 2.0:  # watchdog: no command (not even PULSE) for 2 s
            self.v = self.w = 0.0
        if self.body is not None:  # the body moves; tell it only what changed
            on = self.open and self.motors
            want = (self.v / 1000.0, math.radians(self.w)) if on else (0.0, 0.0)
            if want != self._driven:
                self.body.drive(*want)
                self._driven = want
            return
        if not (self.open and self.motors):
            return
        self.th += math.radians(self.w) * dt
        self.x += self.v * math.cos(self.th) * dt
        self.y += self.v * math.sin(self.th) * dt

    def sensed(self) -> Sensed:
        """What the body reports: ``body.sense()``, or the emulator's own unicycle and settings."""
        if self.body is not None:
            return self.body.sense()
        on = self.motors
        return Sensed(
            odom=(self.x / 1000.0, self.y / 1000.0, self.th),
            vel=(self.v / 1000.0 if on else 0.0, math.radians(self.w) if on else 0.0),
            stall=self.stall,
            front_bumpers=self.front_bumpers,
            rear_bumpers=self.rear_bumpers,
            battery=self.battery,
            paddles=self.paddles,
            lift=self.lift,
            inner_beam=self.inner_beam,
            outer_beam=self.outer_beam,
            contacts=self.contacts,
            sonars=tuple(self.sonar_table),
        )

    def sip_state(self) -> SipState:
        """The robot's state as SIP fields (raw units)."""
        s = self.sensed()
        if self.body is not None:  # the gripper's state comes from the body
            self.paddles, self.lift = s.paddles, s.lift
            self.inner_beam, self.outer_beam, self.contacts = s.inner_beam, s.outer_beam, s.contacts
        dc = DIST_CONV[self.subclass]
        x0, y0, t0 = self.start_counts
        x, y, th = s.odom
        v = s.vel[0] * 1000.0  # mm/s
        half = s.vel[1] / DIFF_CONV[self.subclass]
        sonars = s.sonars if s.sonars is not None else self.sonar_table
        return SipState(
            xpos=(x0 + round(x * 1000.0 / dc)) & 0x7FFF,
            ypos=(y0 + round(y * 1000.0 / dc)) & 0x7FFF,
            thpos=(t0 + round(th / ANGLE_CONV)) & 0xFFF,
            l_vel=round(v - half),
            r_vel=round(v + half),
            battery=round(s.battery * 10),
            stall_left=s.stall[0],
            stall_right=s.stall[1],
            front_bumpers=s.front_bumpers,
            rear_bumpers=s.rear_bumpers,
            flags=(1 if self.motors else 0) | (0b10 if self.sonar_on else 0),
            sonars=[(i, round(r * 1000)) for i, r in enumerate(sonars)] if self.sonar_on else [],
            grip=self.grip_byte(),
            analog=128,
            digin=self.digin_byte(),
            digout=self.digout,
            battery_x10=round(s.battery * 10),
            charge_state=self.charge_state,
        )

    def _sip(self) -> bytes:
        body = encode_sip(self.sip_state())
        self.sips_sent += 1
        if self.truncate:
            self.truncate -= 1
            return frame(body)[: 3 + len(body) // 2]
        bad = self.corrupt > 0
        if bad:
            self.corrupt -= 1
        return frame(body, bad_checksum=bad)
