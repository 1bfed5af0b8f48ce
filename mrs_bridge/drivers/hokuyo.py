"""``hokuyo`` driver: Hokuyo URG-04LX / UTM-30LX laser range finders over SCIP 2.0 (thesis A.2).

The thesis's robots carried Hokuyo lasers driven by Player's ``hokuyo_aist``. This driver speaks
the sensor's own serial protocol, SCIP 2.0 (Hokuyo's "URG Series Communication Protocol
Specification SCIP-Version 2.0"), on a serial or USB-CDC port through pyserial, and provides the
scans as ``ranger`` / ``laser`` devices with the sensor's real geometry.

SCIP 2.0 (commands, frames, check characters, the character coding) is the pure codec
:mod:`mrs_bridge.hw.scip` (its names are re-exported here); the port's thread is
:class:`mrs_bridge.hw.serial_link.SerialLink`. This module is the glue: the session on the link
(below) and the devices on the server.

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

import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from rsal.msgs import ErrorCode, RangerData, RpcError

from ..driver import Driver, register
from ..hw.scip import (
    MODELS,
    STATUS,
    Frame,
    ScipError,
    ScipParams,
    check_char,
    data_lines,
    decode_scan,
    decode_values,
    encode_values,
    params_from_pp,
    parse_fields,
    parse_frame,
    status_text,
)
from ..hw.serial_link import SerialLink
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


# ---------------------------------------------------------------------------- serial link
class _ScipSession:
    """The SCIP 2.0 conversation on a :class:`SerialLink` (runs on the link's thread): enter SCIP
    2.0, read ``VV`` and ``PP``, laser on, stream with ``MD``; posts ``("up", pp, vv, start, end)``,
    ``("scan", t, stamp, mm)`` and ``("warn", text)`` to the link's inbox."""

    def __init__(self, drv: HokuyoDriver):
        self.drv = drv
        self.link: SerialLink | None = None
        self.buf = bytearray()
        self.garbage = 0  # frames or lines that were not SCIP, or failed a check character
        self.scans = 0

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
            if not self.link.wait_until(deadline):
                raise TimeoutError(f"no answer within {timeout:g} s")
            chunk = self.link.read()
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
                self.link.post("warn", f"dropped a frame: {e}")

    def command(self, cmd: bytes, ok: tuple[bytes, ...] = (b"00",), timeout: float = 1.0) -> Frame:
        self.link.write(cmd + b"\n")
        deadline = time.monotonic() + timeout
        while True:
            fr = self._next(max(0.01, deadline - time.monotonic()))
            if fr.echo.startswith(cmd[:2]) and not (cmd[:2] == b"MD" and fr.status == b"99"):
                if fr.status not in ok:
                    what = status_text(cmd, fr.status)
                    raise ScipError(f"{cmd.decode()}: status {fr.status.decode()} ({what})")
                return fr
            # an answer to an earlier command, or a scan of an MD still running: skip it

    # -- protocol
    def __call__(self, link: SerialLink) -> str:
        self.link = link
        d = self.drv
        self.buf.clear()
        link.reset_input()
        link.write(b"QT\n")  # stop a scan left running by an earlier client
        try:
            self.command(b"SCIP2.0", ok=(b"00", b"0D", b"0E", b"0L"), timeout=d.timeout)
        except TimeoutError:
            raise TimeoutError(f"{d.port}: the sensor does not answer SCIP2.0") from None
        vv = parse_fields(self.command(b"VV", timeout=d.timeout))
        pp = params_from_pp(parse_fields(self.command(b"PP", timeout=d.timeout)), d.model)
        self.command(b"BM", ok=(b"00", b"02"), timeout=d.timeout)
        start, end = d.steps(pp)
        req = f"MD{start:04d}{end:04d}{d.cluster:02d}000".encode()
        self.command(req, timeout=d.timeout)
        link.up("up", pp, vv, start, end)
        while not link.stopping:
            try:
                fr = self._next(d.timeout)
            except TimeoutError:
                if link.stopping:
                    break
                raise TimeoutError(f"{d.port}: no scan for {d.timeout:g} s") from None
            if not fr.echo.startswith(b"MD"):
                continue
            if fr.status != b"99":
                raise ScipError(f"MD: status {fr.status.decode()} ({status_text(b'MD', fr.status)})")
            try:
                ts, mm = decode_scan(fr)
            except ScipError as e:
                self.garbage += 1
                link.post("warn", f"dropped a scan: {e}")
                continue
            self.scans += 1
            link.post("scan", time.time(), ts, mm)
        return "stopped"


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
        self.link: SerialLink | None = None
        self.scip = _ScipSession(self)
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
        self.link = SerialLink(
            self.port,
            self.baud,
            self.scip,
            name=f"hokuyo-{self.port}",
            reconnect=self.reconnect,
            max_backoff=10.0,
            read_timeout=0.05,
            write_timeout=1.0,
            close_with=b"QT\n",  # laser off
            inbox_size=64,
        )
        self.link.start()

    def update(self, now: float) -> None:
        link = self.link
        if link is None:
            return
        scan = None
        while link.inbox:
            ev = link.inbox.popleft()
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
            elif kind == "lost":
                if self.online:
                    self.log.warning("%s: laser lost (%s); devices withdrawn until it answers", self.port, ev[1])
                    self.set_online(False)
                elif time.monotonic() - self._last_warn > 5.0:
                    self._last_warn = time.monotonic()
                    self.log.warning("%s: %s; retrying (check the cable and the port)", self.port, ev[1])
            elif kind == "warn" and time.monotonic() - self._last_warn > 5.0:
                self._last_warn = time.monotonic()
                self.log.warning("%s: %s (%d so far)", self.port, ev[1], self.scip.garbage)
        if scan is None or self._geom is None:
            return
        _, t, _ts, mm = scan
        a0, da, n = self._geom
        if mm.size != n:
            self.scip.garbage += 1
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
            return {
                "online": self.online,
                "port": self.port,
                "model": self.params.model,
                "scans": self.scip.scans,
                "published": self.published,
                "dropped": self.scip.garbage,
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
            self.link.stop(timeout=2.0)
