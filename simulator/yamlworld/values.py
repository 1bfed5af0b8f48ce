"""Typed values of a YAML world file, each refused with file:line and a fix.

The second stage of :mod:`simulator.yamlworld`: :class:`Values` reads numbers, integers, flags,
names, poses (x m, y m, yaw in degrees as in Stage files), sizes, colours and choices out of the
:class:`~simulator.yamlworld.reader.LineMap` mappings, warns about unknown keys (with a "did you
mean") and raises :class:`~simulator.errors.WorldFileError` naming the line of the offending key.
The device and model sections (:mod:`~simulator.yamlworld.devices`,
:mod:`~simulator.yamlworld.mapping`) build on it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from pathlib import Path

from ..errors import WorldFileError, did_you_mean
from ..spec import parse_color
from .reader import LineMap, LineSeq

__all__ = ["Pose", "Values", "is_num", "short"]

log = logging.getLogger(__name__)

Pose = tuple[float, float, float]


def is_num(v: object) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def short(v: object) -> str:
    """``repr(v)`` cut to 50 characters for a message."""
    r = repr(v)
    return r if len(r) <= 50 else r[:47] + "..."


class Values:
    """Typed values of one YAML world file: each reader names file:line and a fix when it refuses."""

    def __init__(self, display: str):
        self.file = display
        self.dir = Path(display).parent
        self.warnings: list[str] = []

    # ------------------------------------------------------------------ messages
    def error(self, line: int, message: str) -> WorldFileError:
        return WorldFileError(message, self.file, line)

    def warn(self, line: int, message: str) -> None:
        text = f"{self.file}:{line}: {message}"
        self.warnings.append(text)
        log.warning("%s", text)

    def check_keys(self, m: LineMap, known: Sequence[str], where: str) -> None:
        for key in m:
            if key in known:
                continue
            if not isinstance(key, str):
                raise self.error(m.line_of(key), f"{where}: key {key!r} must be a name such as '{known[0]}'")
            hint = did_you_mean(key, known)
            hint = f"{hint} " if hint else ""
            self.warn(m.line_of(key), f"unknown key '{key}' in {where} ignored; {hint}known: {', '.join(known)}")

    def mapping(self, v: object, line: int, where: str, example: str) -> LineMap:
        if not isinstance(v, LineMap):
            raise self.error(line, f"{where} must be a mapping, got {short(v)}; e.g. {example}")
        return v

    def sequence(self, m: LineMap, key: str, where: str, example: str) -> LineSeq:
        v = m.get(key)
        if v is None:
            return LineSeq()
        if not isinstance(v, LineSeq):
            raise self.error(m.line_of(key), f"{where}.{key} must be a list, got {short(v)}; e.g. {example}")
        return v

    # ------------------------------------------------------------------ scalars
    def num(
        self,
        m: LineMap,
        key: str,
        where: str,
        default: float,
        *,
        lo: float | None = None,
        positive: bool = False,
        unit: str = "",
    ) -> float:
        if key not in m:
            return default
        v = m[key]
        ok = is_num(v) and (lo is None or v >= lo) and (not positive or v > 0)
        if not ok:
            need = "a positive number" if positive else (f"a number >= {lo:g}" if lo is not None else "a number")
            ex = default if is_num(default) and default > 0 else 1.0
            raise self.error(m.line_of(key), f"{where}.{key} must be {need}{unit}, got {short(v)}; e.g. {key}: {ex:g}")
        return float(v)

    def integer(self, m: LineMap, key: str, where: str, default: int) -> int:
        if key not in m:
            return default
        v = m[key]
        if not isinstance(v, int) or isinstance(v, bool):
            raise self.error(m.line_of(key), f"{where}.{key} must be an integer, got {short(v)}; e.g. {key}: 1")
        return v

    def flag(self, m: LineMap, key: str, where: str, default: bool) -> bool:
        if key not in m:
            return default
        v = m[key]
        if isinstance(v, bool):
            return v
        if isinstance(v, int) and v in (0, 1):
            return bool(v)
        raise self.error(m.line_of(key), f"{where}.{key} must be true or false, got {short(v)}")

    def text(self, m: LineMap, key: str, where: str, default: str | None = None, *, required: bool = False) -> str:
        if key not in m:
            if required:
                raise self.error(m.line, f"{where} needs '{key}'; add e.g. {key}: {default or 'r0'}")
            return default or ""
        v = m[key]
        if not isinstance(v, str) or not v.strip():
            raise self.error(m.line_of(key), f"{where}.{key} must be a non-empty string, got {short(v)}")
        return v.strip()

    def numbers(self, m: LineMap, key: str, where: str, counts: tuple[int, ...], example: str) -> list[float]:
        v = m[key]
        if not isinstance(v, list) or len(v) not in counts or not all(is_num(x) for x in v):
            n = " or ".join(str(c) for c in counts)
            raise self.error(
                m.line_of(key),
                f"{where}.{key} must be a list of {n} numbers, got {short(v)}; e.g. {example}",
            )
        return [float(x) for x in v]

    def pose(self, m: LineMap, key: str, where: str, default: Pose = (0.0, 0.0, 0.0)) -> Pose:
        if key not in m:
            return default
        v = self.numbers(m, key, where, (2, 3), f"{key}: [1.0, 2.0, 90]   # x m, y m, yaw degrees")
        return (v[0], v[1], math.radians(v[2]) if len(v) == 3 else 0.0)

    def size(self, m: LineMap, key: str, where: str, default: Sequence[float]) -> tuple[float, float, float]:
        if key not in m:
            return (float(default[0]), float(default[1]), float(default[2]))
        example = f"{key}: [0.44, 0.38, 0.22]"
        v = self.numbers(m, key, where, (2, 3), example)
        if v[0] <= 0 or v[1] <= 0 or (len(v) == 3 and v[2] < 0):
            raise self.error(m.line_of(key), f"{where}.{key} must be positive sizes in metres; e.g. {example}")
        return (v[0], v[1], v[2] if len(v) == 3 else float(default[2]))

    def color(self, m: LineMap, key: str, where: str, default: tuple[int, int, int]) -> tuple[int, int, int]:
        if key not in m:
            return default
        v = m[key]
        try:
            if isinstance(v, str) or (isinstance(v, list) and all(is_num(x) for x in v)):
                return parse_color(v)
            raise ValueError(f"unknown colour {short(v)}")
        except ValueError as e:
            raise self.error(
                m.line_of(key), f"{where}.{key}: {e}; use a name such as 'green', '#00ff00' or [r, g, b]"
            ) from None

    def choice(self, m: LineMap, key: str, where: str, options: Sequence[str], default: str | None = None) -> str:
        if key not in m:
            if default is None:
                raise self.error(m.line, f"{where} needs '{key}': one of {', '.join(options)}")
            return default
        v = m[key]
        if isinstance(v, str) and v in options:
            return v
        hint = did_you_mean(v, options) if isinstance(v, str) else ""
        hint = f"{hint} " if hint else ""
        raise self.error(
            m.line_of(key), f"{where}.{key} {short(v)} is not known; {hint}use one of {', '.join(options)}"
        )

    def fov(self, m: LineMap, where: str, default_deg: float) -> float:
        v = self.num(m, "fov", where, default_deg, positive=True, unit=" (degrees)")
        if v > 360:
            raise self.error(m.line_of("fov"), f"{where}.fov must be at most 360 degrees; e.g. fov: 240")
        return v

    def range_(self, m: LineMap, where: str, default: tuple[float, float]) -> tuple[float, float]:
        if "range" not in m:
            return default
        v = m["range"]
        if is_num(v):
            lo, hi = default[0], float(v)
        else:
            lo, hi = self.numbers(m, "range", where, (2,), "range: [0.02, 5.6]   # min, max in m")
        if not (hi > 0 and 0 <= lo <= hi):
            raise self.error(m.line_of("range"), f"{where}.range must be [min, max] with 0 <= min <= max, max > 0")
        return (lo, hi)
