"""The low-battery event of a ``power`` device, shared by the drivers that report a battery.

A :class:`LowBattery` latch turns a stream of charge readings into the interface's events
(:data:`rsal.interfaces.power.LOW_EVENT`, :data:`~rsal.interfaces.power.RECOVERED_EVENT`): "low"
once when the charge falls below ``threshold`` percent, "recovered" once when it is back above
``threshold + hysteresis`` (so a reading that wobbles around the threshold does not repeat the
event). Used by :mod:`mrs_bridge.drivers.sim` (the simulator's battery model) and
:mod:`mrs_bridge.drivers.p2os` (a Pioneer's SIP battery voltage); the threshold is both drivers'
``low_battery`` parameter.
"""

from __future__ import annotations

from rsal.interfaces.power import LOW_EVENT, RECOVERED_EVENT

__all__ = ["DEFAULT_LOW_BATTERY", "HYSTERESIS", "LowBattery"]

DEFAULT_LOW_BATTERY = 20.0
"""% of charge below which a battery is low unless the driver's ``low_battery`` says otherwise."""
HYSTERESIS = 5.0
"""% above the threshold a low battery must reach before it is reported recovered."""


class LowBattery:
    """Whether a battery is low, and the event to publish when that changes."""

    def __init__(self, threshold: float = DEFAULT_LOW_BATTERY, hysteresis: float = HYSTERESIS):
        self.threshold = float(threshold)
        self.hysteresis = float(hysteresis)
        self.low = False

    def changes(self, percent: float) -> bool:
        """Whether :meth:`update` with this reading would return an event (and flip the latch)."""
        if self.low:
            return percent >= min(100.0, self.threshold + self.hysteresis)
        return percent < self.threshold

    def update(self, t: float, percent: float, volts: float) -> dict | None:
        """Feed one reading; returns the event message to publish, or None."""
        if not self.low and percent < self.threshold:
            self.low = True
            return {"t": t, "event": LOW_EVENT, "percent": percent, "volts": volts, "threshold": self.threshold}
        if self.low and percent >= min(100.0, self.threshold + self.hysteresis):
            self.low = False
            return {"t": t, "event": RECOVERED_EVENT, "percent": percent, "volts": volts, "threshold": self.threshold}
        return None
