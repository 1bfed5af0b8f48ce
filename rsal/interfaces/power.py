"""The ``power`` interface: a battery (Player's ``power``).

Message :class:`PowerData` (``data``); proxy :class:`Power`. Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..msgs import _Msg, get_bool, get_float
from .base import Device, Interface

__all__ = ["PowerData", "Power", "INTERFACE"]


@dataclass(frozen=True)
class PowerData(_Msg):
    t: float
    volts: float
    percent: float
    charging: bool = False

    @classmethod
    def from_dict(cls, m: dict) -> PowerData:
        return cls(
            get_float(m, "t"),
            get_float(m, "volts"),
            get_float(m, "percent", lo=0, hi=100),
            get_bool(m, "charging", False),
        )


class Power(Device):
    data_type = PowerData

    @property
    def percent(self) -> float | None:
        return self.latest.percent if self.latest else None


INTERFACE = Interface(
    "power",
    proxy=Power,
    data=PowerData,
    summary=lambda m: f"{m.volts:.1f} V {m.percent:.0f} %{' charging' if m.charging else ''}",
    doc="battery voltage and charge",
)
