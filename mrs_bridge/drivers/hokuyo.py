"""``hokuyo`` driver: Hokuyo URG-04LX / UTM-30LX laser range finders over SCIP 2.0 (thesis A.2).

The thesis's robots carried Hokuyo lasers driven by Player's ``hokuyo_aist``. This driver speaks
the sensor's own serial protocol, SCIP 2.0 (Hokuyo's "URG Series Communication Protocol
Specification SCIP-Version 2.0"), on a serial or USB-CDC port through pyserial, and provides the
scans as ``ranger`` / ``laser`` devices with the sensor's real geometry.

SCIP 2.0 in brief, as implemented here:

- A command is one line ending in LF (``VV``, ``PP``, ``BM``, ``QT``, ``GD...``, ``MD...``,
  ``SCIP2.0``). The sensor answers with a block of lines ended by an empty line: the echo of the
  command, a status line of two characters plus a check character (``00P`` = ok; ``99b`` = a scan
  of a running ``MD``), then data lines, each with its own check character.
- The check character of a line is ``(sum of its bytes & 0x3F) + 0x30``. For ``key:value;`` lines
  of ``VV``/``PP`` it covers the bytes before the ``;`` (firmware that includes the ``;`` is
  accepted as well).
- ``GD``/``MD`` carry ``start`` and ``end`` steps (4 digits), the cluster count (2 digits, steps
  merged into one reading), ``MD`` also the scan interval (1 digit) and the number of scans (2
  digits, ``00`` for endless). Each scan is a time stamp (4 characters) and the ranges in mm, three
  characters per reading, every character ``c - 0x30`` holding 6 bits, most significant first; the
  data is cut into lines of 64 characters plus a check character.
- ``PP`` gives the geometry: ``DMIN``/``DMAX`` (mm), ``ARES`` (steps per revolution), ``AMIN``/
  ``AMAX`` (first/last measuring step), ``AFRT`` (the step straight ahead), ``SCAN`` (rpm). Step
  ``s`` points at ``(s - AFRT) * 2 pi / ARES`` rad.

The serial link lives on its own thread (the scheduler never waits for the sensor): it opens the
port, stops any running scan (``QT``), enters SCIP 2.0, reads ``VV`` and ``PP``, switches the laser
on (``BM``) and streams with ``MD``. Parsed scans go to the scheduler through a deque; ``update()``
publishes the newest one. The devices' tokens are declared only while the sensor answers: when no
scan arrives for ``timeout`` seconds, or the port fails, the tokens are withdrawn (clients see the
laser lost) and the link reconnects with a growing back-off; when the sensor answers again they
return. Lines that are not SCIP (noise, a half frame after a reconnect) and frames whose check
characters do not match are dropped, counted (``rpc/status``) and warned about at most every 5 s.
Readings below ``DMIN`` are the sensor's error codes (no echo, too near, ...): they are published
as ``range_max`` (no obstacle seen).

Parameters::

    [[driver]]
    name = "hokuyo"
    provides = ["r0:ranger:0", "r0:laser:0"]
    port = "/dev/ttyACM0"   # serial or USB-CDC device (required)
    baud = 115200           # bit/s (ignored by USB models)
    model = "URG-04LX"      # or "UTM-30LX": geometry until the sensor's PP answer replaces it
    pose = [0.13, 0, 0]     # x, y (m), yaw (degrees) on the robot
    cluster = 1             # steps merged per reading (1-99)
    min_angle = -120        # optional, degrees: measure only this part of the field of view
    max_angle = 120
    timeout = 1.0           # s without a scan before the laser counts as lost
    reconnect = 0.5         # s before the first reconnection attempt (doubles up to 10 s)
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from rsal.errors import RsalError
from rsal.msgs import ErrorCode, RangerData, RpcError

from ..driver import Driver, register
from ..params import param, parse_params

__all__ = [
    "MODELS",
    "ScipError",
    "ScipParams",
    "Frame",
    "HokuyoDriver",
    "check_char",
    "decode_values",
    "encode_values",
    "data_lines",
    "parse_frame",
    "parse_fields",
    "decode_scan",
    "STATUS",
]

log = logging.getLogger(__name__)

LINE = 64  # data characters per line before the check character


class ScipError(RsalError, ValueError):
    """A malformed SCIP 2.0 frame or an error status from the sensor."""


@dataclass(frozen=True)
class ScipParams:
    """The ``PP`` geometry of a sensor: ranges in mm, angles in steps."""

    model: str
    dmin: int
    dmax: int
    ares: int
    amin: int
    amax: int
    afrt: int
    scan_rpm: int

    def angle(self, step: float) -> float:
        return (step - self.afrt) * 2.0 * math.pi / self.ares

    def step(self, angle: float) -> int:
        return int(round(angle * self.ares / (2.0 * math.pi) + self.afrt))


#: the two sensors of the thesis (A.2), from their data sheets
MODELS: dict[str, ScipParams] = {
    "URG-04LX": ScipParams("URG-04LX", 20, 5600, 1024, 44, 725, 384, 600),
    "UTM-30LX": ScipParams("UTM-30LX", 23, 60000, 1440, 0, 1080, 540, 2400),
}

#: meanings of the status codes this driver may see (others are reported by number)
STATUS = {
    b"00": "ok",
    b"99": "scan data",
    b"01": "invalid start step",
    b"02": "invalid end step (or: the laser was already on)",
    b"03": "invalid cluster count",
    b"04": "end step before start step",
    b"0E": "already in SCIP 2.0 mode",
    b"0L": "unknown command",
    b"10": "the laser is off",
    b"50": "hardware error",
}


# ---------------------------------------------------------------------------- codec
def check_char(data: bytes) -> int:
    """The SCIP 2.0 check character of ``data``."""
    return (sum(data) & 0x3F) + 0x30


def encode_values(values, nchars: int) -> bytes:
    """Encode non-negative integers with ``nchars`` characters each (6 bits per character)."""
    v = np.asarray(values, dtype=np.int64).reshape(-1)
    if v.size and (v.min() < 0 or v.max() >= 1 << (6 * nchars)):
        raise ValueError(f"values must lie in [0, {1 << (6 * nchars)}) for {nchars} characters")
    shifts = 6 * np.arange(nchars - 1, -1, -1)
    chars = ((v[:, None] >> shifts) & 0x3F) + 0x30
    return chars.astype(np.uint8).tobytes()


def decode_values(data: bytes, nchars: int) -> np.ndarray:
    """Decode a run of ``nchars``-character values (int64); raises :class:`ScipError`."""
    if len(data) % nchars:
        raise ScipError(f"{len(data)} data characters are not a whole number of {nchars}-character values")
    a = np.frombuffer(data, dtype=np.uint8).astype(np.int64) - 0x30
    if a.size and (a.min() < 0 or a.max() > 0x3F):
        raise ScipError("data characters outside the SCIP range 0x30-0x6F")
    a = a.reshape(-1, nchars)
    shifts = 6 * np.arange(nchars - 1, -1, -1)
    return (a << shifts).sum(axis=1)


def data_lines(payload: bytes) -> list[bytes]:
    """Cut encoded data into SCIP lines of 64 characters, each followed by its check character."""
    return [payload[i : i + LINE] + bytes([check_char(payload[i : i + LINE])]) for i in range(0, len(payload), LINE)]


@dataclass(frozen=True)
class Frame:
    """One answer block: the echoed command, the two-character status and the data lines (check
    characters verified and removed)."""

    echo: bytes
    status: bytes
    lines: tuple[bytes, ...]


def parse_frame(raw: bytes) -> Frame:
    """Parse one block (the bytes before the terminating empty line); raises :class:`ScipError`."""
    lines = raw.replace(b"\r", b"").split(b"\n")
    if len(lines) < 2:
        raise ScipError(f"a frame needs an echo and a status line, got {raw[:40]!r}")
    echo, status = lines[0], lines[1]
    if not echo or not echo[:2].isalpha() or not echo.isascii():
        raise ScipError(f"not a SCIP echo line: {echo[:40]!r}")
    if len(status) == 3:
        if status[2] != check_char(status[:2]):
            raise ScipError(f"{echo[:2].decode()}: status line {status!r} fails its check character")
        status = status[:2]
    elif len(status) != 2:  # some commands (SCIP2.0 on old firmware) answer a bare status
        raise ScipError(f"{echo[:2].decode()}: malformed status line {status[:40]!r}")
    out = []
    for ln in lines[2:]:
        if not ln:
            continue
        body, ck = ln[:-1], ln[-1]
        if ck != check_char(body):
            semi = body.rfind(b";")  # key:value; lines: the sum stops before the ';'
            if not (semi == len(body) - 1 and ck == check_char(body[:semi])):
                raise ScipError(f"{echo[:2].decode()}: data line fails its check character")
        out.append(body)
    return Frame(echo, status, tuple(out))


def parse_fields(frame: Frame) -> dict[str, str]:
    """The ``key:value;`` lines of a ``VV``/``PP``/``II`` answer."""
    out = {}
    for ln in frame.lines:
        text = ln.decode("ascii", "replace").rstrip(";")
        k, sep, v = text.partition(":")
        if sep:
            out[k] = v
    return out


def decode_scan(frame: Frame) -> tuple[int, np.ndarray]:
    """The sensor time stamp (ms) and the ranges (mm, int64) of a ``GD``/``MD`` scan frame."""
    if not frame.lines:
        raise ScipError(f"{frame.echo[:2].decode()}: scan frame without a time stamp")
    stamp = frame.lines[0]
    if len(stamp) != 4:
        raise ScipError(f"{frame.echo[:2].decode()}: time stamp of {len(stamp)} characters, not 4")
    ts = int(decode_values(stamp, 4)[0])
    return ts, decode_values(b"".join(frame.lines[1:]), 3)


def params_from_pp(fields: dict[str, str], fallback: ScipParams) -> ScipParams:
    """:class:`ScipParams` from a ``PP`` answer (missing or unreadable keys keep ``fallback``'s)."""

    def num(key: str, default: int) -> int:
        v = fields.get(key, "")
        digits = v.split("(")[0].strip()
        try:
            return int(digits)
        except ValueError:
            return default

    model = fields.get("MODL", fallback.model).split("(")[0].strip() or fallback.model
    return ScipParams(
        model,
        num("DMIN", fallback.dmin),
        num("DMAX", fallback.dmax),
        num("ARES", fallback.ares),
        num("AMIN", fallback.amin),
        num("AMAX", fallback.amax),
        num("AFRT", fallback.afrt),
        num("SCAN", fallback.scan_rpm),
    )


# ---------------------------------------------------------------------------- serial link
class _Link(threading.Thread):
    """The sensor's serial link on its own thread; hands events to the driver through ``events``."""

    def __init__(self, drv: HokuyoDriver):
        super().__init__(name=f"hokuyo-{drv.port}", daemon=True)
        self.drv = drv
        self.events: collections.deque = collections.deque(maxlen=64)
        self.stop_flag = threading.Event()
        self.ser = None
        self.buf = bytearray()
        self.garbage = 0  # frames or lines that were not SCIP, or failed a check character
        self.scans = 0
        self.answered = False  # the current connection got as far as streaming

    # -- byte level
    def _read_frame(self, timeout: float) -> bytes:
        deadline = time.monotonic() + timeout
        while True:
            end = self.buf.find(b"\n\n")
            if end >= 0:
                raw = bytes(self.buf[:end])
                del self.buf[: end + 2]
                return raw
            if len(self.buf) > 1 << 16:  # never a frame: drop the noise
                self.garbage += 1
                self.buf.clear()
            if time.monotonic() >= deadline or self.stop_flag.is_set():
                raise TimeoutError(f"no answer within {timeout:g} s")
            chunk = self.ser.read(max(1, self.ser.in_waiting))
            if chunk:
                self.buf += chunk.replace(b"\r", b"")

    def _next(self, timeout: float) -> Frame:
        """The next well-formed frame; noise and failed checks are counted and skipped."""
        while True:
            raw = self._read_frame(timeout)
            if not raw:
                continue  # a stray empty line
            try:
                return parse_frame(raw)
            except ScipError as e:
                self.garbage += 1
                self.events.append(("warn", f"dropped a frame: {e}"))

    def command(self, cmd: bytes, ok: tuple[bytes, ...] = (b"00",), timeout: float = 1.0) -> Frame:
        self.ser.write(cmd + b"\n")
        deadline = time.monotonic() + timeout
        while True:
            fr = self._next(max(0.01, deadline - time.monotonic()))
            if fr.echo.startswith(cmd[:2]) and not (cmd[:2] == b"MD" and fr.status == b"99"):
                if fr.status not in ok:
                    what = STATUS.get(fr.status, "error")
                    raise ScipError(f"{cmd.decode()}: status {fr.status.decode()} ({what})")
                return fr
            # an answer to an earlier command, or a scan of an MD still running: skip it

    # -- protocol
    def _session(self) -> None:
        import serial

        d = self.drv
        self.ser = serial.Serial(d.port, d.baud, timeout=0.05, write_timeout=1.0)
        self.buf.clear()
        self.ser.reset_input_buffer()
        self.ser.write(b"QT\n")  # stop a scan left running by an earlier client
        try:
            self.command(b"SCIP2.0", ok=(b"00", b"0E", b"0L"), timeout=d.timeout)
        except TimeoutError:
            raise TimeoutError(f"{d.port}: the sensor does not answer SCIP2.0") from None
        vv = parse_fields(self.command(b"VV", timeout=d.timeout))
        pp = params_from_pp(parse_fields(self.command(b"PP", timeout=d.timeout)), d.model)
        self.command(b"BM", ok=(b"00", b"02"), timeout=d.timeout)
        start, end = d.steps(pp)
        req = f"MD{start:04d}{end:04d}{d.cluster:02d}000".encode()
        self.command(req, timeout=d.timeout)
        self.events.append(("up", pp, vv, start, end))
        self.answered = True
        while not self.stop_flag.is_set():
            try:
                fr = self._next(d.timeout)
            except TimeoutError:
                raise TimeoutError(f"{d.port}: no scan for {d.timeout:g} s") from None
            if not fr.echo.startswith(b"MD"):
                continue
            if fr.status != b"99":
                raise ScipError(f"MD: status {fr.status.decode()} ({STATUS.get(fr.status, 'error')})")
            try:
                ts, mm = decode_scan(fr)
            except ScipError as e:
                self.garbage += 1
                self.events.append(("warn", f"dropped a scan: {e}"))
                continue
            self.scans += 1
            self.events.append(("scan", time.time(), ts, mm))

    def run(self) -> None:
        import serial

        backoff = self.drv.reconnect
        while not self.stop_flag.is_set():
            self.answered = False
            try:
                self._session()
            except (OSError, serial.SerialException, ScipError, TimeoutError) as e:
                if not self.stop_flag.is_set():
                    self.events.append(("down", str(e)))
            finally:
                self._close()
            if self.answered:  # it worked until now: retry soon
                backoff = self.drv.reconnect
            if self.stop_flag.wait(backoff):
                break
            backoff = min(backoff * 2.0, 10.0)

    def _close(self) -> None:
        ser, self.ser = self.ser, None
        if ser is None:
            return
        try:
            ser.write(b"QT\n")  # laser off
            ser.flush()
        except Exception:
            pass
        try:
            ser.close()
        except Exception:
            pass

    def shutdown(self) -> None:
        self.stop_flag.set()
        self.join(2.0)


# ---------------------------------------------------------------------------- the driver
@dataclass(frozen=True)
class HokuyoParams:
    """The ``hokuyo`` driver's parameters (module docstring)."""

    port: str = param(missing='hokuyo needs port = "/dev/ttyACM0" (the sensor\'s serial device)')
    baud: int = param(115200, min=300, max=1_000_000)
    model: str = param("URG-04LX", choices=tuple(MODELS))
    pose: tuple[float, float, float] = param((0.0, 0.0, 0.0), expect="[x, y, yaw_degrees]")
    cluster: int = param(1, min=1, max=99)
    min_angle: float | None = param(None, min=-180.0, max=180.0, expect="an angle in [-180, 180] degrees")
    max_angle: float | None = param(None, min=-180.0, max=180.0, expect="an angle in [-180, 180] degrees")
    timeout: float = param(1.0, gt=0.0, expect="a positive number of seconds")
    reconnect: float = param(0.5, gt=0.0, expect="a positive number of seconds")

    def __post_init__(self) -> None:
        if self.min_angle is not None and self.max_angle is not None and self.min_angle >= self.max_angle:
            raise ValueError("min_angle must be smaller than max_angle")


@register("hokuyo", "hokuyo_aist", "urglaser")
class HokuyoDriver(Driver):
    interfaces = ("ranger", "laser")
    default_rate = 50.0  # polls the link's deque; scans come at the sensor's 10 or 40 Hz
    data_types = {"ranger": "RangerData", "laser": "RangerData"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        p = self.settings = parse_params(HokuyoParams, cfg)
        self.port, self.baud, self.cluster = p.port, p.baud, p.cluster
        self.model = MODELS[p.model]
        self.pose = [p.pose[0], p.pose[1], math.radians(p.pose[2])]
        self.min_angle = None if p.min_angle is None else math.radians(p.min_angle)
        self.max_angle = None if p.max_angle is None else math.radians(p.max_angle)
        self.timeout, self.reconnect = p.timeout, p.reconnect
        self.online = False  # tokens come when the sensor answers
        self.params = self.model
        self.info: dict[str, str] = {}
        self.last: RangerData | None = None
        self.published = 0
        self.link: _Link | None = None
        self._geom: tuple[float, float, int] | None = None  # angle_min, angle_step, count
        self._last_warn = 0.0

    def steps(self, pp: ScipParams) -> tuple[int, int]:
        """The first and last step to measure: the sensor's range, cut to min/max_angle."""
        start, end = pp.amin, pp.amax
        if self.min_angle is not None:
            start = max(start, pp.step(self.min_angle))
        if self.max_angle is not None:
            end = min(end, pp.step(self.max_angle))
        return start, max(start, end)

    # -- the driver contract
    def setup(self) -> None:
        self.link = _Link(self)
        self.link.start()

    def update(self, now: float) -> None:
        link = self.link
        if link is None:
            return
        scan = None
        while link.events:
            ev = link.events.popleft()
            kind = ev[0]
            if kind == "scan":
                scan = ev
            elif kind == "up":
                _, pp, vv, start, end = ev
                self.params, self.info = pp, vv
                n = (end - start) // self.cluster + 1
                step = 2.0 * math.pi / pp.ares
                # a cluster's reading belongs to the middle of its steps
                self._geom = (pp.angle(start + (self.cluster - 1) / 2.0), step * self.cluster, n)
                self.log.info(
                    "%s: %s (serial %s) answering, %d readings from %.1f to %.1f deg",
                    self.port,
                    pp.model,
                    vv.get("SERI", "?"),
                    n,
                    math.degrees(self._geom[0]),
                    math.degrees(self._geom[0] + (n - 1) * self._geom[1]),
                )
            elif kind == "down":
                if self.online:
                    self.log.warning("%s: laser lost (%s); devices withdrawn until it answers", self.port, ev[1])
                    self.set_online(False)
                elif time.monotonic() - self._last_warn > 5.0:
                    self._last_warn = time.monotonic()
                    self.log.warning("%s: %s; retrying (check the cable and the port)", self.port, ev[1])
            elif kind == "warn" and time.monotonic() - self._last_warn > 5.0:
                self._last_warn = time.monotonic()
                self.log.warning("%s: %s (%d so far)", self.port, ev[1], link.garbage)
        if scan is None or self._geom is None:
            return
        _, t, _ts, mm = scan
        a0, da, n = self._geom
        if mm.size != n:
            link.garbage += 1
            return
        pp = self.params
        rmax = pp.dmax / 1000.0
        ranges = np.where(mm < pp.dmin, pp.dmax, np.minimum(mm, pp.dmax)).astype(np.float32) / np.float32(1000.0)
        self.last = RangerData(t, ranges, a0, da, pp.dmin / 1000.0, rmax)
        if not self.online:
            self.log.info("%s: laser answering; devices declared", self.port)
            self.set_online(True)
        for a in self.cfg.provides:
            self.publish(a, self.last)
        self.published += 1

    def ops(self, addr) -> list[str]:
        return ["get", "status"]

    def on_rpc(self, addr, op, args) -> dict:
        if op == "get":
            if self.last is None:
                raise RpcError(ErrorCode.UNAVAILABLE, f"{self.port}: no scan yet (is the sensor connected?)")
            return self.last.to_dict()
        if op == "status":
            link = self.link
            return {
                "online": self.online,
                "port": self.port,
                "model": self.params.model,
                "scans": link.scans if link else 0,
                "published": self.published,
                "dropped": link.garbage if link else 0,
                "info": dict(self.info),
            }
        return super().on_rpc(addr, op, args)

    def geometry(self, addr) -> dict[str, Any]:
        pp = self.params
        if self._geom is not None:
            _, da, n = self._geom
        else:
            start, end = self.steps(pp)
            n = (end - start) // self.cluster + 1
            da = 2.0 * math.pi / pp.ares * self.cluster
        return {
            "kind": "laser",
            "pose": list(self.pose),
            "sensors": [
                {
                    "pose": [0.0, 0.0, 0.0],
                    "fov": da * (n - 1),
                    "samples": n,
                    "range_min": pp.dmin / 1000.0,
                    "range_max": pp.dmax / 1000.0,
                }
            ],
            "model": pp.model,
            "scan_hz": pp.scan_rpm / 60.0,
        }

    def shutdown(self) -> None:
        if self.link is not None:
            self.link.shutdown()
