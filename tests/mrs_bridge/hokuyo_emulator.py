"""An emulated Hokuyo laser (URG-04LX or UTM-30LX) speaking SCIP 2.0 on a pseudo-terminal.

The driver under test opens :attr:`HokuyoEmulator.path` (the pty's slave side) as its serial port;
the emulator answers on the master side from its own thread: ``SCIP2.0``, ``VV``, ``PP``, ``II``,
``BM``, ``QT``, ``RS``, ``GD`` and ``MD`` (scans at the model's rate), unknown commands with status
``0L``. The scene is a round room: every reading is ``room_mm`` except step ``amin + 10``, which
answers the error code 1 (no echo). Faults on demand: ``mode = "silent"`` (reads and never
answers), ``"garbage"`` (noise bytes between scans), ``"badsum"`` (every other scan with a wrong
check character). ``commands`` records every command line received.
"""

from __future__ import annotations

import os
import select
import threading
import time

import numpy as np

from mrs_bridge.drivers.hokuyo import MODELS, check_char, data_lines, encode_values


def _line(text: bytes) -> bytes:
    return text + bytes([check_char(text)]) + b"\n"


def _field(key: str, value: str) -> bytes:
    body = f"{key}:{value}".encode()
    return body + b";" + bytes([check_char(body)]) + b"\n"


class HokuyoEmulator:
    def __init__(self, model: str = "URG-04LX", room_mm: int = 2000):
        self.pp = MODELS[model]
        self.room_mm = room_mm
        self.master, self.slave = os.openpty()
        self.path = os.ttyname(self.slave)
        self.mode = "normal"
        self.laser_on = False
        self.md: tuple[bytes, int, int, int] | None = None  # echo, start, end, cluster
        self.commands: list[bytes] = []
        self.scans_sent = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="hokuyo-emulator", daemon=True)
        self._thread.start()

    # -- the scene
    def readings(self, start: int, end: int, cluster: int) -> np.ndarray:
        steps = np.arange(start, end + 1)
        mm = np.full(steps.size, self.room_mm, dtype=np.int64)
        mm[steps == self.pp.amin + 10] = 1  # an error code: no echo
        n = (end - start) // cluster + 1
        return mm[: n * cluster].reshape(n, cluster).min(axis=1) if cluster > 1 else mm

    # -- framing
    def _send(self, data: bytes) -> None:
        try:
            os.write(self.master, data)
        except OSError:
            pass

    def _answer(self, echo: bytes, status: bytes, body: bytes = b"") -> None:
        self._send(echo + b"\n" + _line(status) + body + b"\n")

    def _scan_body(self, start: int, end: int, cluster: int, *, bad: bool = False) -> bytes:
        ts = int(time.monotonic() * 1000) % (1 << 24)
        payload = encode_values(self.readings(start, end, cluster), 3)
        lines = data_lines(payload)
        if bad:
            last = lines[0]
            lines[0] = last[:-1] + bytes([0x30 + ((last[-1] - 0x30 + 1) & 0x3F)])
        return _line(encode_values([ts], 4)) + b"".join(ln + b"\n" for ln in lines)

    # -- commands
    def _handle(self, cmd: bytes) -> None:
        self.commands.append(cmd)
        pp = self.pp
        op = cmd[:2]
        if cmd == b"SCIP2.0":
            self._answer(cmd, b"00")
        elif op == b"VV":
            fields = [
                ("VEND", "Emulated Sensors"),
                ("PROD", pp.model),
                ("FIRM", "1.0.0"),
                ("PROT", "SCIP 2.0"),
                ("SERI", "EMU0001"),
            ]
            self._answer(cmd, b"00", b"".join(_field(k, v) for k, v in fields))
        elif op == b"PP":
            fields = [
                ("MODL", f"{pp.model}(Emulated)"),
                ("DMIN", str(pp.dmin)),
                ("DMAX", str(pp.dmax)),
                ("ARES", str(pp.ares)),
                ("AMIN", str(pp.amin)),
                ("AMAX", str(pp.amax)),
                ("AFRT", str(pp.afrt)),
                ("SCAN", str(pp.scan_rpm)),
            ]
            self._answer(cmd, b"00", b"".join(_field(k, v) for k, v in fields))
        elif op == b"II":
            self._answer(cmd, b"00", _field("LASR", "ON" if self.laser_on else "OFF"))
        elif op == b"BM":
            self._answer(cmd, b"02" if self.laser_on else b"00")
            self.laser_on = True
        elif op in (b"QT", b"RS"):
            self.laser_on = False
            self.md = None
            self._answer(cmd, b"00")
        elif op in (b"GD", b"MD") and len(cmd) >= 12 and cmd[2:12].isdigit():
            start, end, cluster = int(cmd[2:6]), int(cmd[6:10]), int(cmd[10:12]) or 1
            if not pp.amin <= start <= pp.amax:
                self._answer(cmd, b"01")
            elif not start <= end <= pp.amax:
                self._answer(cmd, b"04" if end < start else b"02")
            elif op == b"GD":
                if not self.laser_on:
                    self._answer(cmd, b"10")
                else:
                    self._answer(cmd, b"00", self._scan_body(start, end, cluster))
            else:
                self.laser_on = True
                self._answer(cmd, b"00")
                self.md = (cmd, start, end, cluster)
        else:
            self._answer(cmd, b"0L")

    def _run(self) -> None:
        buf = b""
        period = 60.0 / self.pp.scan_rpm
        next_scan = time.monotonic()
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.005)
            if r:
                try:
                    buf += os.read(self.master, 4096)
                except OSError:
                    buf = b""
                *lines, buf = buf.split(b"\n")
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
                next_scan = max(next_scan + period, now - period)
                echo, start, end, cluster = self.md
                bad = self.mode == "badsum" and self.scans_sent % 2 == 1
                if self.mode == "garbage":
                    self._send(bytes(np.random.default_rng(self.scans_sent).integers(0, 256, 40, dtype=np.uint8)))
                    self._send(b"\n\n")
                self._send(echo + b"\n" + _line(b"99") + self._scan_body(start, end, cluster, bad=bad) + b"\n")
                self.scans_sent += 1

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
