"""Energy: the robots' batteries and the charging stations, as arrays with one row per robot.

The thesis proposes energy as the next step of its scenarios (4.2, 4.2.1, 5.4); Stage models it
with power packs (``joules``, ``watts``, ``give_watts``/``take_watts``), here it is a model per
robot that the world steps with everything else (:meth:`simulator.world.World.step`):

* **drain**: each step a robot's stored energy falls by ``per_metre`` joules for every metre its
  body moved (ground truth, not odometry), ``per_radian`` for every radian it turned, and
  ``watts`` times the step (electronics and sensors, also while idle). A teleport
  (:meth:`~simulator.world.World.set_pose`) costs nothing.
* **empty**: a robot whose battery is empty refuses to move: its command and velocity are held
  at zero before the drives act (it still charges, and moves again once it has energy).
* **chargers** (:class:`~simulator.spec.ChargerSpec`): a robot whose centre is within a
  charger's ``distance`` of its pose, and whose heading is within ``angle`` of the charger's yaw
  when the charger sets one, is docked and gains the charger's ``rate`` watts (the fastest
  charger it is docked at; capped by the battery's own ``max_charge``) up to its capacity.

* **record**: per robot, the lowest charge, the seconds spent empty and the joules gained while
  charging since the world was built -- judged on every step, for verdicts that must not miss a
  moment between samples (``batteries`` of the simulation interface).

Everything is a few numpy operations over all robots (and robots x chargers for docking): no
Python loop per robot in the step.

Pioneer defaults, from MobileRobots' Pioneer specifications: the DX bases (2DX, 3DX) carry up to
three hot-swappable 12 V sealed lead-acid batteries, 252 Wh with all three (907 kJ), and run 8 to
10 hours on them without accessories; the 3AT carries the same three batteries and runs 2 to 4
hours (skid steering). The same documents put the base's low-battery alarm at 11.5 V and its
shut-down at 11.0 V (:mod:`rsal.interfaces.power` reads such voltages as a charge). The split
into a constant draw and a cost of motion is ours, chosen so that the datasheet run time comes out at a typical duty:
:data:`PIONEER_DX` (20 W, 20 J/m, 4 J/rad) lasts 12.6 h idle and 8.4 h driving at 0.5 m/s;
:data:`PIONEER_AT` (30 W, 100 J/m, 40 J/rad) 8.4 h idle and 3.2 h at 0.5 m/s. Turning a
differential drive in place moves each wheel by half the track per radian, hence the smaller
per-radian cost; skid steering scrubs its wheels, hence the 3AT's larger one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .sensors.base import wrap
from .spec import BatterySpec, ChargerSpec

__all__ = ["Batteries", "BatteryState", "PIONEER_AT", "PIONEER_CAPACITY", "PIONEER_DX", "battery_problem"]

PIONEER_CAPACITY = 252.0 * 3600.0
"""J: three 12 V sealed lead-acid batteries, 252 Wh (the Pioneer specification's figure)."""
PIONEER_DX = BatterySpec(capacity=PIONEER_CAPACITY, per_metre=20.0, per_radian=4.0, watts=20.0)
"""Pioneer 2DX / 3DX: 8-10 h run time on three batteries (module docstring)."""
PIONEER_AT = BatterySpec(capacity=PIONEER_CAPACITY, per_metre=100.0, per_radian=40.0, watts=30.0)
"""Pioneer 3AT: 2-4 h run time on three batteries (module docstring)."""

_ARRAYS = {
    "capacity": 0, "energy": 0, "coef": 3, "max_charge": 0, "charging": 0, "has": 0,
    "lowest": 0, "flat": 0, "charged": 0,
}  # fmt: skip


@dataclass(frozen=True)
class BatteryState:
    """One robot's battery after the last step: ``energy`` and ``capacity`` in joules,
    ``fraction`` = energy / capacity, ``charging`` (docked at a charger and not full, or gaining),
    ``charger`` (the name of the charger it is docked at, or None), ``empty``; its record since the
    world was built: ``lowest`` fraction, ``flat`` seconds spent empty and ``charged`` joules
    gained while charging (the ground truth of an energy verdict, judged on every step). A robot
    without a battery model reads ``capacity`` 0, ``fraction`` 1 and never empties."""

    energy: float
    capacity: float
    fraction: float
    charging: bool
    charger: str | None
    empty: bool
    lowest: float = 1.0
    flat: float = 0.0
    charged: float = 0.0


def battery_problem(b: BatterySpec) -> str | None:
    """What is wrong with ``b`` (a negative rate, a charge outside [0, 1]...), or None."""
    if not b.capacity > 0:
        return f"battery capacity must be positive joules, not {b.capacity:g}"
    if not 0.0 <= b.charge <= 1.0:
        return f"battery charge must be a fraction between 0 and 1, not {b.charge:g}"
    for key in ("per_metre", "per_radian", "watts", "max_charge"):
        v = getattr(b, key)
        if not v >= 0:
            return f"battery {key} must be >= 0, not {v:g}"
    return None


class Batteries:
    """Every robot's battery by row (the rows of :class:`simulator.drive.Drives`) and the chargers.

    Arrays: ``capacity`` and ``energy`` (J), ``coef`` ``(J/m, J/rad, W)``, ``max_charge`` (W, inf
    when unlimited), ``charging`` (bool), ``has`` (bool: the robot has a battery model), the record
    ``lowest`` (fraction), ``flat`` (s empty) and ``charged`` (J gained while charging); ``dock``
    the index of the charger each robot is docked at (-1: none)."""

    def __init__(self, chargers: list[ChargerSpec]) -> None:
        for name, cols in _ARRAYS.items():
            dtype = bool if name in ("charging", "has") else float
            setattr(self, name, np.zeros((0, cols) if cols else 0, dtype=dtype))
        self.dock = np.zeros(0, dtype=np.int64)
        self.set_chargers(chargers)

    def set_chargers(self, chargers: list[ChargerSpec]) -> None:
        self.chargers = [replace(c) for c in chargers]
        c = self.chargers
        self._cpose = np.array([ch.pose for ch in c], dtype=float).reshape(-1, 3)
        self._crate = np.array([ch.rate for ch in c], dtype=float)
        self._cdist2 = np.array([ch.distance for ch in c], dtype=float) ** 2
        self._cangle = np.array([np.inf if ch.angle is None else ch.angle for ch in c], dtype=float)

    def add(self, spec: BatterySpec | None) -> None:
        b = spec if spec is not None else BatterySpec(charge=1.0)
        row = {
            "capacity": b.capacity,
            "energy": b.capacity * b.charge,
            "coef": (b.per_metre, b.per_radian, b.watts),
            "max_charge": b.max_charge if b.max_charge > 0 else np.inf,
            "charging": False,
            "has": spec is not None,
            "lowest": b.charge if spec is not None else 1.0,
            "flat": 0.0,
            "charged": 0.0,
        }
        for name, cols in _ARRAYS.items():
            arr = getattr(self, name)
            setattr(self, name, np.vstack([arr, row[name]]) if cols else np.append(arr, row[name]))
        self.dock = np.append(self.dock, -1)

    def remove(self, row: int) -> None:
        keep = np.ones(self.energy.shape[0], dtype=bool)
        keep[row] = False
        for name in (*_ARRAYS, "dock"):
            setattr(self, name, getattr(self, name)[keep])

    @property
    def empty(self) -> np.ndarray:
        """Robots (by row) whose battery is empty: they refuse to move."""
        return self.has & (self.energy <= 0.0)

    def step(self, prev: np.ndarray, pose: np.ndarray, dt: float) -> None:
        """Drain by the motion from ``prev`` to ``pose`` (true poses by row) over ``dt`` seconds,
        then charge the docked robots."""
        if not self.energy.size:
            return
        dist = np.hypot(pose[:, 0] - prev[:, 0], pose[:, 1] - prev[:, 1])
        turn = np.abs(wrap(pose[:, 2] - prev[:, 2]))
        used = self.coef[:, 0] * dist + self.coef[:, 1] * turn + self.coef[:, 2] * dt
        gain = np.zeros_like(used)
        self.dock[:] = -1
        if self._crate.size:
            dx = pose[:, 0, None] - self._cpose[None, :, 0]
            dy = pose[:, 1, None] - self._cpose[None, :, 1]
            r, c = np.nonzero(dx * dx + dy * dy <= self._cdist2[None, :])  # the few pairs in reach
            if r.size:
                facing = np.abs(wrap(pose[r, 2] - self._cpose[c, 2])) <= self._cangle[c]
                r, c = r[facing], c[facing]
                rate = self._crate[c]
                order = np.argsort(rate, kind="stable")  # the fastest charger wins: written last
                self.dock[r[order]] = c[order]
                docked = self.dock >= 0
                gain[docked] = np.minimum(self._crate[self.dock[docked]], self.max_charge[docked]) * dt
        before = self.energy
        self.energy = np.where(self.has, np.clip(before - used + gain, 0.0, self.capacity), self.capacity)
        self.charging = self.has & (self.dock >= 0) & (gain > used) & (self.energy < self.capacity)
        frac = np.divide(
            self.energy, self.capacity, out=np.ones_like(self.energy), where=self.has & (self.capacity > 0)
        )
        self.lowest = np.minimum(self.lowest, frac)
        self.flat = self.flat + np.where(self.empty, dt, 0.0)
        self.charged = self.charged + np.where(self.charging, self.energy - before, 0.0)

    def fraction(self, row: int) -> float:
        """:meth:`state`'s ``fraction`` alone (the sim driver reads it every step)."""
        cap = float(self.capacity[row])
        return float(self.energy[row]) / cap if self.has[row] and cap > 0 else 1.0

    def state(self, row: int) -> BatteryState:
        cap = float(self.capacity[row])
        e = float(self.energy[row])
        has = bool(self.has[row])
        d = int(self.dock[row])
        return BatteryState(
            energy=e if has else 0.0,
            capacity=cap if has else 0.0,
            fraction=e / cap if has and cap > 0 else 1.0,
            charging=bool(self.charging[row]),
            charger=self.chargers[d].name if d >= 0 else None,
            empty=bool(self.empty[row]),
            lowest=float(self.lowest[row]),
            flat=float(self.flat[row]),
            charged=float(self.charged[row]),
        )

    def set_fraction(self, row: int, fraction: float) -> None:
        """Set a robot's charge (tests, the simulation interface)."""
        self.energy[row] = float(np.clip(fraction, 0.0, 1.0)) * self.capacity[row]
        if self.has[row]:
            self.lowest[row] = min(self.lowest[row], float(np.clip(fraction, 0.0, 1.0)))
