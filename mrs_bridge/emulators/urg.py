"""An emulated Hokuyo laser (URG-04LX or UTM-30LX) speaking SCIP 2.0 on a pseudo-terminal.

Written from Hokuyo's "URG Series Communication Protocol Specification SCIP 2.0", independently of
the driver: nothing here is imported from the project (not the driver, not its codec
:mod:`mrs_bridge.hw.scip`). This module's own tables and encoders:
the line framing and check character (:func:`check_char`, :func:`line`), the 2/3/4-character
coding (:func:`encode`), the sensors' ``PP`` values from their data sheets (:data:`SENSORS`), and
the status codes it answers (:data:`STATUS`). :func:`answer` frames one reply block, :func:`scan_block`
the body of a ``GD``/``MD`` scan.

The driver under test opens :attr:`HokuyoEmulator.path` (the pty's slave side) as its serial port;
the emulator answers on the master side from its own thread: ``SCIP2.0``, ``VV``, ``PP``, ``II``,
``BM``, ``QT``, ``RS``, ``GD`` and ``MD`` (scans at the model's rate), anything else with the
"undefined command" status ``0E``. ``MD`` honours its scan interval (scans skipped between two
sent) and its number of scans (the echo's last two digits count down the scans left; ``00``:
endless). The default scene is a round room: every reading is ``room_mm`` except
step ``amin + 10``, which answers the error code 1 (no echo). Given ``scene``, a callable taking
the requested step numbers (an int array) and returning one reading per step in mm (or an error
code below ``DMIN``), the ranges come from it instead: ``rsal rehearse`` ray-casts them in a
simulated world at the sensor's pose (:mod:`mrs_bridge.rehearse`); :meth:`Sensor.angle` gives a
step's direction. Faults on demand: ``mode =
"silent"`` (reads and never answers), ``"garbage"`` (noise bytes between scans), ``"badsum"`` (every
other scan with a wrong check character). ``commands`` records every command line received.
"""

from __future__ import annotations

import os
import select
import threading
import time
from dataclasses import dataclass

import numpy as np

LF = b"\n"
DATA_PER_LINE = 64  # data characters per line before its check character


@dataclass(frozen=True)
class Sensor:
    """A sensor's ``PP`` answer: ranges in mm, angles in steps, scan speed in rpm."""

    model: str
    dmin: int
    dmax: int
    ares: int
    amin: int
    amax: int
    afrt: int
    scan: int

    def angle(self, steps):
        """The direction of step(s) in radians, counter-clockwise from the front: step ``AFRT``
        looks ahead, one step is a ``1/ARES`` of a turn (SCIP 2.0, the ``PP`` parameters)."""
        return (np.asarray(steps, dtype=np.float64) - self.afrt) * (2.0 * np.pi / self.ares)


#: the sensors of the thesis (A.2), from their data sheets
SENSORS = {
    "URG-04LX": Sensor("URG-04LX", 20, 5600, 1024, 44, 725, 384, 600),
    "UTM-30LX": Sensor("UTM-30LX", 23, 60000, 1440, 0, 1080, 540, 2400),
}

#: the status codes this emulator answers
STATUS = {
    "ok": b"00",
    "scan": b"99",
    "start_not_number": b"01",
    "end_not_number": b"02",
    "cluster_not_number": b"03",
    "end_out_of_range": b"04",
    "end_before_start": b"05",
    "interval_not_number": b"06",
    "count_not_number": b"07",
    "laser_off": b"10",
    "laser_already_on": b"02",  # BM
    "undefined": b"0E",
}


def check_char(data: bytes) -> int:
    """The check character: the sum of the bytes, its low 6 bits, plus 0x30."""
    return (sum(data) & 0x3F) + 0x30


def line(data: bytes) -> bytes:
    """One answer line: data, its check character, LF."""
    return data + bytes([check_char(data)]) + LF


def field_line(key: str, value: str) -> bytes:
    """A ``key:value;`` line of VV/PP/II: the check character sums the bytes before the ';'."""
    body = f"{key}:{value}".encode("ascii")
    return body + b";" + bytes([check_char(body)]) + LF


def encode(values, chars: int) -> bytes:
    """Each value as ``chars`` characters of 6 bits, most significant first, plus 0x30."""
    v = np.asarray(values, dtype=np.int64).reshape(-1, 1)
    shifts = 6 * np.arange(chars - 1, -1, -1)
    return (((v >> shifts) & 0x3F) + 0x30).astype(np.uint8).tobytes()


def answer(echo: bytes, status: bytes, body: bytes = b"") -> bytes:
    """A reply block: the echo, the status line, the data lines, the empty line."""
    return echo + LF + line(status) + body + LF


def scan_block(stamp_ms: int, ranges_mm, chars: int = 3) -> bytes:
    """The data lines of a scan: the 4-character time stamp line, then the ranges cut into lines
    of 64 characters."""
    data = encode(ranges_mm, chars)
    lines = [data[i : i + DATA_PER_LINE] for i in range(0, len(data), DATA_PER_LINE)]
    return line(encode([stamp_ms % (1 << 24)], 4)) + b"".join(line(ln) for ln in lines)


class HokuyoEmulator:
    def __init__(self, model: str = "URG-04LX", room_mm: int = 2000, scene=None):
        self.pp = SENSORS[model]
        self.room_mm = room_mm
        self.scene = scene
        self.master, self.slave = os.openpty()
        self.path = os.ttyname(self.slave)
        self.mode = "normal"
        self.laser_on = False
        self.md: tuple[bytes, int, int, int] | None = None  # echo, start, end, cluster
        self.md_left = 0  # scans still to send (0: endless)
        self.md_skip = 0  # scans skipped between two sent (the interval digit)
        self.commands: list[bytes] = []
        self.scans_sent = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="hokuyo-emulator", daemon=True)
        self._thread.start()

    # -- the scene
    def readings(self, start: int, end: int, cluster: int) -> np.ndarray:
        steps = np.arange(start, end + 1)
        if self.scene is not None:
            mm = np.asarray(self.scene(steps), dtype=np.int64)
        else:
            mm = np.full(steps.size, self.room_mm, dtype=np.int64)
            mm[steps == self.pp.amin + 10] = 1  # an error code: no echo
        n = (end - start) // cluster + 1
        if cluster > 1:  # a cluster reports the minimum of its steps (the last may be short)
            mm = np.minimum.reduceat(mm, np.arange(0, steps.size, cluster))[:n]
        return mm

    # -- framing
    def _send(self, data: bytes) -> None:
        try:
            os.write(self.master, data)
        except OSError:
            pass

    def _scan_body(self, start: int, end: int, cluster: int, *, bad: bool = False) -> bytes:
        body = scan_block(int(time.monotonic() * 1000), self.readings(start, end, cluster))
        if bad:  # spoil the first range line's check character
            i = body.index(LF) + 1
            j = body.index(LF, i) - 1
            body = body[:j] + bytes([0x30 + ((body[j] - 0x30 + 1) & 0x3F)]) + body[j + 1 :]
        return body

    # -- commands
    def _scan_request(self, cmd: bytes, md: bool) -> tuple[bytes, tuple[int, int, int] | None]:
        """The status for a GD/MD request and its (start, end, cluster) when valid."""
        fields = [(cmd[2:6], "start_not_number"), (cmd[6:10], "end_not_number"), (cmd[10:12], "cluster_not_number")]
        if md:
            fields += [(cmd[12:13], "interval_not_number"), (cmd[13:15], "count_not_number")]
        for text, err in fields:
            if len(text) == 0 or not text.isdigit():
                return STATUS[err], None
        start, end, cluster = int(cmd[2:6]), int(cmd[6:10]), int(cmd[10:12]) or 1
        if end > self.pp.amax or start > self.pp.amax:
            return STATUS["end_out_of_range"], None
        if end < start:
            return STATUS["end_before_start"], None
        return STATUS["ok"], (start, end, cluster)

    def _handle(self, cmd: bytes) -> None:
        self.commands.append(cmd)
        pp = self.pp
        op = cmd[:2]
        if cmd == b"SCIP2.0":
            self._send(answer(cmd, STATUS["ok"]))
        elif op == b"VV":
            fields = [
                ("VEND", "Emulated Sensors"),
                ("PROD", pp.model),
                ("FIRM", "1.0.0"),
                ("PROT", "SCIP 2.0"),
                ("SERI", "EMU0001"),
            ]
            self._send(answer(cmd, STATUS["ok"], b"".join(field_line(k, v) for k, v in fields)))
        elif op == b"PP":
            fields = [
                ("MODL", f"{pp.model}(Emulated)"),
                ("DMIN", str(pp.dmin)),
                ("DMAX", str(pp.dmax)),
                ("ARES", str(pp.ares)),
                ("AMIN", str(pp.amin)),
                ("AMAX", str(pp.amax)),
                ("AFRT", str(pp.afrt)),
                ("SCAN", str(pp.scan)),
            ]
            self._send(answer(cmd, STATUS["ok"], b"".join(field_line(k, v) for k, v in fields)))
        elif op == b"II":
            self._send(answer(cmd, STATUS["ok"], field_line("LASR", "ON" if self.laser_on else "OFF")))
        elif op == b"BM":
            self._send(answer(cmd, STATUS["laser_already_on"] if self.laser_on else STATUS["ok"]))
            self.laser_on = True
        elif op in (b"QT", b"RS"):
            self.laser_on = False
            self.md = None
            self._send(answer(cmd, STATUS["ok"]))
        elif op in (b"GD", b"MD"):
            status, req = self._scan_request(cmd, md=op == b"MD")
            if req is None:
                self._send(answer(cmd, status))
            elif op == b"GD":
                if not self.laser_on:
                    self._send(answer(cmd, STATUS["laser_off"]))
                else:
                    self._send(answer(cmd, STATUS["ok"], self._scan_body(*req)))
            else:  # MD switches the laser on by itself
                self.laser_on = True
                self._send(answer(cmd, STATUS["ok"]))
                self.md = (cmd, *req)
                self.md_skip, self.md_left = int(cmd[12:13]), int(cmd[13:15])
        else:
            self._send(answer(cmd, STATUS["undefined"]))

    def _run(self) -> None:
        buf = b""
        rev = 60.0 / self.pp.scan  # s per revolution
        next_scan = time.monotonic()
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.005)
            if r:
                try:
                    buf += os.read(self.master, 4096)
                except OSError:
                    buf = b""
                *lines, buf = buf.split(LF)
                with self._lock:
                    for ln in lines:
                        ln = ln.strip(b"\r")
                        if ln and self.mode != "silent":
                            self._handle(ln)
                        elif ln:
                            self.commands.append(ln)
            now = time.monotonic()
            with self._lock:
                if self.md is None or self.mode == "silent" or now < next_scan:
                    continue
                period = rev * (1 + self.md_skip)
                next_scan = max(next_scan + period, now - period)
                echo, start, end, cluster = self.md
                if self.md_left:  # a counted MD: the echo's last two digits count the scans left
                    self.md_left -= 1
                    echo = echo[:13] + b"%02d" % self.md_left
                bad = self.mode == "badsum" and self.scans_sent % 2 == 1
                if self.mode == "garbage":
                    self._send(bytes(np.random.default_rng(self.scans_sent).integers(0, 256, 40, dtype=np.uint8)))
                    self._send(LF + LF)
                # an endless MD (scan count 00) echoes its command unchanged with every scan
                self._send(answer(echo, STATUS["scan"], self._scan_body(start, end, cluster, bad=bad)))
                self.scans_sent += 1
                if echo[13:15] == b"00" and self.md[0][13:15] != b"00":  # the last counted scan sent
                    self.md = None

    def set_mode(self, mode: str) -> None:
        with self._lock:
            self.mode = mode

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
