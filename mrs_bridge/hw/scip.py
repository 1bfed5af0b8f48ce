"""Hokuyo SCIP 2.0 codec: commands, answer frames, check characters, the 6-bit character coding (no I/O).

Spec: Hokuyo's "URG Series Communication Protocol Specification SCIP-Version 2.0", the protocol of
the URG-04LX / UTM-30LX lasers of the thesis (A.2; Player's ``hokuyo_aist``). Moved here from the
``hokuyo`` driver unchanged.

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rsal.errors import RsalError

__all__ = [
    "LINE",
    "MODELS",
    "STATUS",
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
