"""Rangers: scanning lasers and sonar rings (Stage 4 ``ranger`` model; Player's ranger interface).

Every robot's rangers are flattened into one table of *fans* when models change
(:meth:`Rangers.rebuild`); each step the fans due are cast in one batched, compiled pass
(:func:`simulator.raycast.cast_fans`) across *all* robots, which also adds range noise
(deterministic per seed and step). A sensor with ``samples > 1`` (a laser, or part of one) gives
one reading per beam; a single-sample sensor (a sonar transducer) is cast as a fan of
:data:`SONAR_SUBRAYS` rays across its cone and reads their minimum (:func:`segment_min`).
Sensors of both shapes may share a ranger; its readings follow the order of its sensors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..raycast import cast_fans, segment_min
from ..spec import RangerSpec
from .base import ReadingSensor

__all__ = ["SONAR_SUBRAYS", "RangerReading", "Rangers"]

SONAR_SUBRAYS = 5  # rays spread across a sonar cone; the transducer reads their minimum


@dataclass(frozen=True)
class RangerReading:
    """One scan of a ranger: ``ranges[i]`` is the range of beam/transducer ``i`` in metres."""

    ranges: np.ndarray  # float32
    time: float  # sim time of the scan, s
    spec: RangerSpec


class Rangers(ReadingSensor):
    """Every ranger of every robot, cast together."""

    kind = "ranger"
    spec_field = "rangers"
    describe_key = "rangers"

    def __init__(self, world):
        super().__init__(world)
        self.fans: dict[str, np.ndarray] = {}
        self._slices: list[tuple[str, int, int, int, int]] = []
        self._scan_out = np.zeros(0, dtype=np.float32)
        self._reduce: tuple[np.ndarray, np.ndarray] | None = None  # (first ray, ray count) per reading

    @classmethod
    def player_devices(cls, spec) -> list[tuple[str, int]]:
        """``ranger:i`` per ranger, then Player's aliases: ``sonar:0`` (the first sonar ranger)
        and ``laser:0`` (the first laser)."""
        out = super().player_devices(spec)
        if any(r.kind == "sonar" for r in spec.rangers):
            out.append(("sonar", 0))
        if any(r.kind != "sonar" for r in spec.rangers):
            out.append(("laser", 0))
        return out

    def specs(self, name: str) -> list[RangerSpec]:
        return list(self.devices.get(name, []))

    def describe(self, name: str) -> list[tuple[str, str, int]]:
        return [(r.name, r.kind, len(r.sensors)) for r in self.devices.get(name, [])]

    def rebuild(self) -> None:
        """Flatten every robot's ranger sensors into fan tables (done when models change)."""
        rob, lx, ly, lth, dth, nr, rmin, rmax, noise, every, cone = ([] for _ in range(11))
        # robot, ranger index, its first fan, its first reading, its reading count
        slices: list[tuple[str, int, int, int, int]] = []
        reading = 0
        dt = self.world.spec.interval_sim
        for m in self.world.robots:
            for ri, rs in enumerate(self.devices.get(m.spec.name, [])):
                first_fan = len(rob)
                first_reading = reading
                k_every = max(1, int(round(rs.interval / dt)))
                px, py, pa = rs.pose
                cpa, spa = math.cos(pa), math.sin(pa)
                for s in rs.sensors:
                    sx, sy, sa = s.pose
                    # sensor pose in the robot frame = device mount ∘ sensor pose
                    x = px + cpa * sx - spa * sy
                    y = py + spa * sx + cpa * sy
                    a = pa + sa
                    if s.samples <= 1:
                        count = SONAR_SUBRAYS if s.fov > 0 else 1
                        step = s.fov / (count - 1) if count > 1 else 0.0
                        first = a - s.fov / 2 if count > 1 else a
                        reading += 1
                    else:
                        count = int(s.samples)
                        step = s.fov / (count - 1)
                        first = a - s.fov / 2
                        reading += count
                    rob.append(m.row)
                    lx.append(x)
                    ly.append(y)
                    lth.append(first)
                    dth.append(step)
                    nr.append(count)
                    rmin.append(s.range_min)
                    rmax.append(s.range_max)
                    noise.append(s.noise)
                    every.append(k_every)
                    cone.append(s.samples <= 1)
                slices.append((m.spec.name, ri, first_fan, first_reading, reading - first_reading))
        f = {
            "robot": np.asarray(rob, dtype=np.int64),
            "lx": np.asarray(lx, dtype=float),
            "ly": np.asarray(ly, dtype=float),
            "lth": np.asarray(lth, dtype=float),
            "dth": np.asarray(dth, dtype=float),
            "n": np.asarray(nr, dtype=np.int64),
            "rmin": np.asarray(rmin, dtype=float),
            "rmax": np.asarray(rmax, dtype=float),
            "noise": np.asarray(noise, dtype=float),
            "every": np.asarray(every, dtype=np.int64),
        }
        n = f["n"]
        f["uids"] = np.array([m.uid for m in self.world.robots], dtype=np.int64)
        # Readings from rays: a beam is one ray, a cone the minimum of its fan's rays.
        is_cone = np.asarray(cone, dtype=bool) & (n > 1)
        if is_cone.any():
            per_fan = np.where(is_cone, 1, n)  # readings per fan
            fan_of = np.repeat(np.arange(n.size), per_fan)
            ray0 = np.cumsum(n) - n
            local = np.arange(int(per_fan.sum())) - np.repeat(np.cumsum(per_fan) - per_fan, per_fan)
            counts = np.where(is_cone[fan_of], n[fan_of], 1)
            self._reduce = (ray0[fan_of] + local, counts)
        else:
            self._reduce = None  # every reading is one ray: readings are views of the scan
        self.fans = f
        self._slices = slices
        self._scan_out = np.zeros(int(n.sum()), dtype=np.float32)

    def update(self, dt: float) -> None:
        w = self.world
        f = self.fans
        if f["n"].size == 0:
            return
        due = ((w.steps - 1) % f["every"]) == 0  # every sensor scans on the first step
        if not due.any():
            return
        all_due = bool(due.all())
        idx = np.arange(due.size) if all_due else np.nonzero(due)[0]
        pose = w.poses[f["robot"][idx]]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        lx, ly = f["lx"][idx], f["ly"][idx]
        fans = {
            "x": pose[:, 0] + c * lx - s * ly,
            "y": pose[:, 1] + s * lx + c * ly,
            "th0": pose[:, 2] + f["lth"][idx],
            "dth": f["dth"][idx],
            "n": f["n"][idx],
            "rmax": f["rmax"][idx],
            "owner": f["uids"][f["robot"][idx]],
            "noise": f["noise"][idx],
            "rmin": f["rmin"][idx],
        }
        # Noise and clipping happen inside the compiled caster (deterministic per seed and step).
        ranges = cast_fans(w.grid, fans, w.circles(), seed=w.seed, step=w.steps, threads=w.spec.threads).astype(
            np.float32
        )
        if all_due:
            out = ranges
        else:
            out = self._scan_out.copy()  # readings of sensors not due keep their old arrays
            out[np.repeat(due, f["n"])] = ranges
        out.flags.writeable = False
        self._scan_out = out
        vals = out if self._reduce is None else segment_min(out, *self._reduce)
        vals.flags.writeable = False  # readings are views into this tick's array
        t = w.time
        readings = self.readings
        for name, ri, first_fan, r0, count in self._slices:
            if due[first_fan]:
                readings[name][ri] = RangerReading(vals[r0 : r0 + count], t, self.devices[name][ri])
