"""The ``power`` interface: a battery (Player's ``power``).

Message :class:`PowerData` (``data``), the low-battery event (``event``, :data:`LOW_EVENT`);
proxy :class:`Power`. Wire format: ``docs/protocol.md``. The same message comes from the
simulator's battery model (``mrs_bridge.drivers.sim``) and from a real Pioneer's SIP battery
voltage (``mrs_bridge.drivers.p2os``): both convert between charge and voltage with one curve,
:func:`lead_acid_volts` / :func:`lead_acid_fraction`, the state-of-charge table of a 12 V sealed
lead-acid pack at rest (about 12.7 V full, 12.2 V half, 11.6 V at 10 %, 10.5 V the cut-off
under load), its top raised to 13.0 V, what a freshly charged Pioneer pack reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..msgs import _Msg, get_bool, get_float
from .base import Device, Interface

__all__ = [
    "INTERFACE",
    "LEAD_ACID_CURVE",
    "LOW_EVENT",
    "RECOVERED_EVENT",
    "Power",
    "PowerData",
    "lead_acid_fraction",
    "lead_acid_volts",
]

LEAD_ACID_CURVE = (
    (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0),
    (10.5, 11.6, 11.75, 11.9, 12.05, 12.2, 12.32, 12.44, 12.55, 12.7, 13.0),
)
"""``(charge fractions, volts)`` of a 12 V lead-acid pack (module docstring); piecewise linear."""
_FRAC = np.array(LEAD_ACID_CURVE[0])
_VOLT = np.array(LEAD_ACID_CURVE[1])

LOW_EVENT = "low"
"""``event`` of the message a power device publishes once when its charge falls below its
low-battery threshold: ``{"t", "event": "low", "percent", "volts", "threshold"}``."""
RECOVERED_EVENT = "recovered"
"""``event`` published once when the charge is back above the threshold plus its hysteresis."""


def lead_acid_volts(fraction: float) -> float:
    """The voltage of a 12 V lead-acid pack at ``fraction`` (0..1, clipped) of its charge."""
    return float(np.interp(fraction, _FRAC, _VOLT))


def lead_acid_fraction(volts: float) -> float:
    """The charge fraction (0..1) of a 12 V lead-acid pack that reads ``volts`` (the inverse of
    :func:`lead_acid_volts`; below 10.5 V: 0, above 13 V: 1)."""
    return float(np.interp(volts, _VOLT, _FRAC))


@dataclass(frozen=True)
class PowerData(_Msg):
    t: float
    volts: float
    percent: float
    charging: bool = False
    low: bool = False

    @classmethod
    def from_dict(cls, m: dict) -> PowerData:
        return cls(
            get_float(m, "t"),
            get_float(m, "volts"),
            get_float(m, "percent", lo=0, hi=100),
            get_bool(m, "charging", False),
            get_bool(m, "low", False),
        )

    @property
    def fraction(self) -> float:
        """The charge as a fraction 0..1."""
        return self.percent / 100.0


class Power(Device):
    data_type = PowerData

    @property
    def percent(self) -> float | None:
        return self.latest.percent if self.latest else None

    @property
    def fraction(self) -> float | None:
        return self.latest.fraction if self.latest else None

    @property
    def charging(self) -> bool | None:
        return self.latest.charging if self.latest else None

    @property
    def low(self) -> bool | None:
        return self.latest.low if self.latest else None


INTERFACE = Interface(
    "power",
    proxy=Power,
    data=PowerData,
    summary=lambda m: f"{m.volts:.1f} V {m.percent:.0f} %{' charging' if m.charging else ''}{' LOW' if m.low else ''}",
    doc="battery voltage, charge, charging and low battery",
)
