"""The lead-acid charge/voltage curve (rsal.interfaces.power) and the low-battery latch
(mrs_bridge.battery) that the sim and p2os drivers share."""

from __future__ import annotations

import numpy as np
import pytest

from mrs_bridge.battery import LowBattery
from rsal.interfaces.power import (
    LEAD_ACID_CURVE,
    LOW_EVENT,
    RECOVERED_EVENT,
    PowerData,
    lead_acid_fraction,
    lead_acid_volts,
)
from rsal.msgs import decode, encode


def test_the_curve_is_a_12v_lead_acid_pack_and_inverts():
    assert lead_acid_volts(0.0) == 10.5 and lead_acid_volts(1.0) == 13.0
    assert lead_acid_volts(0.5) == pytest.approx(12.2)
    v = np.array(LEAD_ACID_CURVE[1])
    assert np.all(np.diff(v) > 0)  # monotonic: every voltage names one charge
    for f in np.linspace(0, 1, 41):
        assert lead_acid_fraction(lead_acid_volts(f)) == pytest.approx(f, abs=1e-9)
    assert lead_acid_fraction(9.0) == 0.0 and lead_acid_fraction(14.2) == 1.0  # clipped, e.g. on a charger


def test_low_fires_once_below_the_threshold_and_recovers_above_the_hysteresis():
    lb = LowBattery(20.0, 5.0)
    seen = [lb.update(t, p, 12.0) for t, p in enumerate([30, 21, 19.9, 19, 21, 24.9, 19, 25, 26, 19])]
    kinds = [(i, e["event"]) for i, e in enumerate(seen) if e is not None]
    assert kinds == [(2, LOW_EVENT), (7, RECOVERED_EVENT), (9, LOW_EVENT)]
    assert seen[2] == {"t": 2, "event": "low", "percent": 19.9, "volts": 12.0, "threshold": 20.0}
    assert lb.low


def test_power_data_carries_the_low_flag_and_old_peers_decode_without_it():
    m = PowerData(1.0, 12.2, 50.0, True, True)
    assert decode(PowerData, encode(m)) == m and m.fraction == 0.5
    old = decode(PowerData, encode({"t": 0.0, "volts": 12.0, "percent": 40.0}))
    assert old.low is False and old.charging is False
