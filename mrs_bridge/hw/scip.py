"""Hokuyo SCIP 2.0 codec: commands, answer frames, check characters, the character coding (no I/O).

Spec: Hokuyo Automatic's "URG Series Communication Protocol Specification SCIP 2.0" (the protocol
of the URG-04LX and UTM-30LX of the thesis, A.2; Player's ``hokuyo_aist``). Section numbers below
are that document's chapters as this codec reads them: communication format, data encoding, and the
command reference.

**Framing** (communication format): the host sends one command line ending in LF (CR and CR LF are
accepted too). The sensor answers with a block ended by an empty line (two LFs)::

    echo of the command  LF
    status (2 characters)  check character  LF
    data line  check character  LF        (zero or more; 64 data characters at most per line)
    LF

The **check character** of a line is ``(sum of its bytes & 0x3F) + 0x30`` (:func:`check_char`): "00"
carries "P", "99" carries "b". For the ``key:value;`` lines of ``VV``/``PP``/``II`` the sum covers
the bytes before the ``;`` (firmware that includes the ``;`` is accepted as well).

**Data encoding**: a value is cut into 6-bit groups, most significant first, each sent as the
character ``group + 0x30`` (0x30..0x6F): 2 characters (12 bits; ``GS``/``MS``), 3 characters (18
bits; ``GD``/``MD`` ranges in mm), 4 characters (24 bits; the time stamp in ms).
(:func:`encode_values`, :func:`decode_values`). A scan's characters run on over lines of 64.

**Commands** used here (:data:`COMMANDS`):

=========== ===================================================================================
command     answer
=========== ===================================================================================
``SCIP2.0`` switch a SCIP 1.1 sensor to 2.0 (a sensor already in 2.0 may answer ``00`` or an
            "undefined command" status; the driver accepts both)
``VV``      version lines ``VEND``, ``PROD``, ``FIRM``, ``PROT``, ``SERI``
``PP``      geometry lines ``MODL``, ``DMIN``/``DMAX`` (mm), ``ARES`` (steps per revolution),
            ``AMIN``/``AMAX`` (first/last measuring step), ``AFRT`` (the step straight ahead),
            ``SCAN`` (rpm); step ``s`` points at ``(s - AFRT) * 2 pi / ARES`` rad
``II``      state lines (``MODL``, ``LASR`` on/off, ``SCSP``, ``MESM``, ``SBPS``, ``TIME``, ``STAT``)
``BM``      laser on; ``QT`` laser off (and stop ``MD``); ``RS`` reset to the power-on state
``GDssss``  one scan: start step, end step (4 digits each), cluster count (2 digits: steps
``eeeecc``  merged into one reading, their minimum); answer: time stamp line, then the ranges
``MDssss``  as ``GD`` plus the scan interval (1 digit, scans skipped) and the number of scans (2
``eeeeccin``  digits, ``00`` endless): first answered ``00`` with no data, then every scan with status
            ``99`` and the echo's last two digits counting the scans left
=========== ===================================================================================

**Status codes** (:data:`STATUS_COMMON`, :data:`STATUS_BY_COMMAND`, :func:`status_text`): ``00`` ok,
``99`` scan data follows; the common errors ``0A``..``0I`` (any command); per command as listed
(e.g. ``GD`` ``04`` end step out of range, ``05`` end step before the start step, ``10`` laser off;
``BM`` ``02`` already on); ``MD`` ``50``..``97`` hardware trouble.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rsal.errors import RsalError

__all__ = [
    "LINE",
    "MODELS",
    "COMMANDS",
    "STATUS",
    "STATUS_BY_COMMAND",
    "STATUS_COMMON",
    "Frame",
    "ScipError",
    "ScipParams",
    "check_char",
    "data_lines",
    "decode_scan",
    "decode_values",
    "encode_values",
    "params_from_pp",
    "parse_fields",
    "parse_frame",
    "status_text",
]

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

#: the commands this codec frames and what their answers carry (module docstring)
COMMANDS = ("SCIP2.0", "VV", "PP", "II", "BM", "QT", "RS", "GD", "GS", "MD", "MS")

#: status codes any command may answer (the specification's common error list)
STATUS_COMMON = {
    b"00": "ok",
    b"99": "scan data",
    b"0A": "unable to create transmission data or reply command internally",
    b"0B": "buffer shortage, or a command repeated that is already being processed",
    b"0C": "command with insufficient parameters (1)",
    b"0D": "undefined command (1)",
    b"0E": "undefined command (2)",
    b"0F": "command with insufficient parameters (2)",
    b"0G": "string in the command exceeds 16 characters",
    b"0H": "string has invalid characters",
    b"0I": "sensor in firmware update mode",
}

_SCAN_STATUS = {
    b"01": "start step not a number",
    b"02": "end step not a number",
    b"03": "cluster count not a number",
    b"04": "end step out of range",
    b"05": "end step before the start step",
}
#: per-command status codes
STATUS_BY_COMMAND = {
    b"BM": {b"01": "unable to control the laser (laser malfunction)", b"02": "the laser was already on"},
    b"GD": {**_SCAN_STATUS, b"10": "the laser is off"},
    b"GS": {**_SCAN_STATUS, b"10": "the laser is off"},
    b"MD": {
        **_SCAN_STATUS,
        b"06": "scan interval not a number",
        b"07": "number of scans not a number",
        b"98": "resumed after the laser was confirmed working again",
    },
    b"MS": {
        **_SCAN_STATUS,
        b"06": "scan interval not a number",
        b"07": "number of scans not a number",
        b"98": "resumed after the laser was confirmed working again",
    },
}

#: the common codes; kept for callers that look a status up without its command
STATUS = STATUS_COMMON


def status_text(cmd: bytes, status: bytes) -> str:
    """What ``status`` means in the answer to ``cmd`` (the specification's tables)."""
    op = cmd[:2]
    if status in STATUS_COMMON:
        return STATUS_COMMON[status]
    text = STATUS_BY_COMMAND.get(op, {}).get(status)
    if text:
        return text
    if op in (b"MD", b"MS") and status.isdigit() and 21 <= int(status) <= 49:
        return "processing stopped to verify an error"
    if status.isdigit() and 50 <= int(status) <= 97:
        return "hardware trouble (laser, motor ...)"
    return "error"


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
