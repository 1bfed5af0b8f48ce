"""The local planners' parameter table: one :class:`Param` per Player option, and its check.

Each planner (:mod:`~mrs_bridge.nav.vfh`, :mod:`~mrs_bridge.nav.nd`, :mod:`~mrs_bridge.nav.snd`)
declares ``PARAMS: dict[str, Param]`` by Player's option names and in Player's configuration units
(the ``vfh``/``nd``/``snd`` drivers of the Player manual); :class:`~mrs_bridge.nav.local.LocalPlanner`
resolves a configuration against it once: an unknown name answered with "did you mean"
(:mod:`rsal.suggest`), a bad value with a ``ValueError`` naming the key and :meth:`Param.expected`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Real
from typing import Any

__all__ = ["Param", "check_param"]


@dataclass(frozen=True)
class Param:
    """One configuration parameter: its default, valid range and unit (Player's units)."""

    default: float | tuple[float, ...] | None  # None: see ``same_as``, or derived by the planner
    lo: float | tuple[float, ...]
    hi: float | tuple[float, ...]
    unit: str = ""
    doc: str = ""
    size: int = 1  # 1: a number; k > 1: a list of k numbers
    integer: bool = False
    same_as: str | None = None  # the default is this (earlier) parameter's value ...
    factor: float = 1.0  # ... times this

    def expected(self) -> str:
        kind = "an integer" if self.integer else "a number"
        if self.size == 1:
            return f"{kind} in [{_num(self.lo)}, {_num(self.hi)}]" + (f" {self.unit}" if self.unit else "")
        lo = self.lo if isinstance(self.lo, tuple) else (self.lo,) * self.size
        hi = self.hi if isinstance(self.hi, tuple) else (self.hi,) * self.size
        box = " x ".join(f"[{_num(a)}, {_num(b)}]" for a, b in zip(lo, hi, strict=True))
        return f"a list of {self.size} numbers in {box}" + (f" ({self.unit})" if self.unit else "")


def _num(x: float) -> str:
    return "inf" if x == math.inf else f"{x:g}"


def check_param(planner: str, key: str, value: Any, spec: Param) -> Any:
    def bad() -> ValueError:
        return ValueError(f"{planner}: parameter {key!r} = {value!r} is invalid; expected {spec.expected()}")

    if spec.size == 1:
        if isinstance(value, bool) or not isinstance(value, Real):
            raise bad()
        vals = (float(value),)
    else:
        if isinstance(value, str | bytes | Mapping) or not hasattr(value, "__len__"):
            raise bad()
        if len(value) != spec.size or any(isinstance(v, bool) or not isinstance(v, Real) for v in value):
            raise bad()
        vals = tuple(float(v) for v in value)
    los = spec.lo if isinstance(spec.lo, tuple) else (spec.lo,) * spec.size
    his = spec.hi if isinstance(spec.hi, tuple) else (spec.hi,) * spec.size
    for v, lo, hi in zip(vals, los, his, strict=True):
        if not (math.isfinite(v) and lo <= v <= hi):
            raise bad()
        if spec.integer and v != int(v):
            raise bad()
    if spec.size == 1:
        return int(vals[0]) if spec.integer else vals[0]
    return vals
