"""A Pioneer robot on a pseudo-terminal, for testing the ``p2os`` driver without hardware.

:class:`PioneerEmulator` opens ``os.openpty()``; the driver opens the slave side by its path
(:attr:`PioneerEmulator.path`) like a serial port. A thread answers the P2OS sync handshake
(SYNC0/1/2 echoed, the SYNC2 echo carrying name, class and subclass), obeys OPEN, CLOSE, PULSE,
ENABLE, VEL, RVEL, SONAR, DIGOUT and GRIPPER, integrates a unicycle model of the commanded speeds
(stopping when no command arrived for 2 s, as the real watchdog does) and, once opened, sends
standard SIPs at 10 Hz in the layout documented in :mod:`mrs_bridge.drivers.p2os`, with sonar
ranges from a fixed table, a battery voltage and a gripper state.

Faults on demand: :attr:`silent` (answer nothing, read nothing), :meth:`inject_garbage` (random
bytes between packets), :attr:`corrupt` (the next n SIPs with a wrong checksum), :attr:`truncate`
(the next n SIPs cut short). Framing here is written independently of the driver's codec.
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

DIST_CONV = {"P2DX": 0.840, "P3AT": 1.0}  # mm per count, as the models the driver knows
ANGLE_CONV = 2 * math.pi / 4096
DIFF_CONV = {"P2DX": 0.0056, "P3AT": 0.0034}


def frame(payload: bytes, *, bad_checksum: bool = False) -> bytes:
    c = 0
    for i in range(0, len(payload) - 1, 2):
        c = (c + (payload[i] << 8 | payload[i + 1])) & 0xFFFF
    if len(payload) % 2:
        c ^= payload[-1]
    if bad_checksum:
        c ^= 0x5A5A
    return bytes([0xFA, 0xFB, len(payload) + 2]) + payload + bytes([c >> 8, c & 0xFF])


class PioneerEmulator:
    def __init__(self, subclass: str = "P2DX", name: str = "emu", sonars: int = 8, rate: float = 10.0):
        self.subclass, self.name, self.n_sonars, self.period = subclass, name, sonars, 1.0 / rate
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
        self.sonar_table = [0.5 + 0.25 * i for i in range(sonars)]  # m
        self.gripper = 0b1001  # paddles open, lift down
        self.digin = 0b1010_0101
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
        if len(p) >= 4 and p[1] in (0x3B, 0x1B):
            arg = p[2] | p[3] << 8
            if p[1] == 0x1B:
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
        if cmd == 2:  # CLOSE
            self.open = False
            self.synced = -1
            self.motors = False
            self.v = self.w = 0.0
        elif cmd == 4:
            self.motors = arg == 1
            if not self.motors:
                self.v = self.w = 0.0
        elif cmd == 11:
            self.v = float(arg or 0)
        elif cmd == 21:
            self.w = float(arg or 0)
        elif cmd == 28:
            self.sonar_on = arg == 1
        elif cmd == 30 and arg is not None:
            mask, bits = arg >> 8, arg & 0xFF
            self.digout = (self.digout & ~mask) | (bits & mask)
        elif cmd == 33:
            self.gripper = {
                1: (self.gripper & ~0b11) | 0b01,
                2: (self.gripper & ~0b11) | 0b10,
                4: (self.gripper & ~0b1100) | 0b0100,
                5: (self.gripper & ~0b1100) | 0b1000,
            }.get(arg, self.gripper)

    def _integrate(self, dt: float, now: float) -> None:
        if now - self._last_cmd > 2.0:  # watchdog: no command (not even PULSE) for 2 s
            self.v = self.w = 0.0
        if not (self.open and self.motors):
            return
        self.th += math.radians(self.w) * dt
        self.x += self.v * math.cos(self.th) * dt
        self.y += self.v * math.sin(self.th) * dt

    def _sip(self) -> bytes:
        dc = DIST_CONV[self.subclass]
        x0, y0, t0 = self.start_counts
        xpos = (x0 + round(self.x / dc)) & 0x7FFF
        ypos = (y0 + round(self.y / dc)) & 0x7FFF
        th = (t0 + round(self.th / ANGLE_CONV)) & 0xFFF
        wr = math.radians(self.w) if self.motors else 0.0
        v = self.v if self.motors else 0.0
        half = wr / DIFF_CONV[self.subclass]
        lv, rv = round(v - half), round(v + half)
        moving = 0x33 if (lv or rv) else 0x32
        flags = (1 if self.motors else 0) | (0b10 if self.sonar_on else 0)
        body = struct.pack("<BHHhhhBHhHB", moving, xpos, ypos, th, lv, rv, round(self.battery * 10), 0, 0, flags, 0)
        sonars = b""
        if self.sonar_on:
            sonars = b"".join(struct.pack("<BH", i, round(r * 1000)) for i, r in enumerate(self.sonar_table))
            body += bytes([len(self.sonar_table)]) + sonars
        else:
            body += b"\0"
        body += struct.pack("<BBBBBHB", self.gripper, 0, 128, self.digin, self.digout, round(self.battery * 10), 0)
        self.sips_sent += 1
        if self.truncate:
            self.truncate -= 1
            return frame(body)[: 3 + len(body) // 2]
        bad = self.corrupt > 0
        if bad:
            self.corrupt -= 1
        return frame(body, bad_checksum=bad)
