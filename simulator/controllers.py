"""Built-in controllers: Stage's ``ctrl`` controllers, and demo controllers for headless runs.

Stage controllers (a position model's ``ctrl "NAME"`` in a world file) are looked up in
:data:`CONTROLLERS` and run by the world after every step (:class:`StageControllers`):

* ``wander``: Stage 4's example wander controller (``examples/ctrl/wander.cc``, read for its
  meaning): on every new scan of the robot's first ranger, cruise at 0.4 m/s; when a reading in
  the middle third of the scan is under 1.0 m (an obstruction) or any reading is under 0.3 m
  (stop), or while an avoidance is still running, drive at 0.05 m/s (0 when stopping) and turn at
  0.5 rad/s away from the side with the nearer minimum, keeping that turn for a random 10 to 19
  scans. Vectorised over all wandering robots whose scans have the same number of readings.

``wander`` (the function, ``python -m simulator --wander``, benchmarks): each robot drives
forward and, when its first laser (or, without a laser, its first ranger) sees something closer
than ``stop_dist`` in the front third of its field, slows down and turns towards the more open
side: Stage's wander in spirit, with other speeds, kept for the existing benchmarks.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CONTROLLERS", "StageControllers", "StageWander", "wander"]


def wander(world, *, speed: float = 0.5, turn: float = 0.8, stop_dist: float = 0.8) -> None:
    """Set every robot's velocity from the latest scan of its first laser (its first ranger if it
    has no laser; a robot without rangers just drives ahead)."""
    for name in world.robot_names:
        specs = world.rangers(name)
        r = None
        if specs:
            index = next((i for i, s in enumerate(specs) if s.kind == "laser"), 0)
            r = world.ranger(name, index)
        if r is None:
            world.set_velocity(name, speed, 0.0)
            continue
        z = r.ranges
        n = z.shape[0]
        if n >= 3:
            front = float(z[n // 3 : max(n // 3 + 1, 2 * n // 3)].min())
        else:
            front = float(z.min())
        if front < stop_dist:
            left = float(z[n // 2 :].mean())
            right = float(z[: n // 2].mean())
            world.set_velocity(name, 0.05, turn if left > right else -turn)
        else:
            world.set_velocity(name, speed, 0.0)


class StageWander:
    """Stage's wander controller for a set of robots (see the module docstring)."""

    CRUISE_SPEED = 0.4  # m/s
    AVOID_SPEED = 0.05  # m/s
    AVOID_TURN = 0.5  # rad/s
    MIN_FRONT_DISTANCE = 1.0  # m, an obstruction in the middle third of the scan
    STOP_DIST = 0.3  # m, any reading closer stops the robot
    AVOID_DURATION = 10  # scans; an avoidance lasts AVOID_DURATION + uniform[0, AVOID_DURATION) scans

    def __init__(self, names: list[str], seed: int = 0):
        self.names = list(names)
        n = len(self.names)
        self.avoid = np.zeros(n, dtype=np.int64)  # scans of avoidance left
        self.turn = np.zeros(n)  # rad/s held during an avoidance
        self.last = np.full(n, -1.0)  # time of the last scan acted on
        self.rng = np.random.default_rng(seed)

    def __call__(self, world) -> None:
        groups: dict[int, list[tuple[int, np.ndarray]]] = {}
        for i, name in enumerate(self.names):
            if name not in world.model_names:
                continue
            r = world.ranger(name, 0) if world.rangers(name) else None
            if r is None or r.time == self.last[i] or r.ranges.size == 0:
                continue
            self.last[i] = r.time
            groups.setdefault(r.ranges.size, []).append((i, r.ranges))
        for n, rows in groups.items():
            idx = np.array([i for i, _ in rows])
            z = np.stack([z for _, z in rows]).astype(float)
            lo, hi = n // 3 + 1, n - n // 3  # Stage: sample_count/3 < i < sample_count - sample_count/3
            obstruction = (z[:, lo:hi] < self.MIN_FRONT_DISTANCE).any(axis=1) if hi > lo else np.zeros(len(idx), bool)
            stop = (z < self.STOP_DIST).any(axis=1)
            left = z[:, n // 2 + 1 :].min(axis=1) if n // 2 + 1 < n else np.full(len(idx), 1e6)
            right = z[:, : n // 2 + 1].min(axis=1)
            avoiding = obstruction | stop | (self.avoid[idx] > 0)
            start = avoiding & (self.avoid[idx] < 1)
            k = idx[start]
            self.avoid[k] = self.rng.integers(0, self.AVOID_DURATION, k.size) + self.AVOID_DURATION
            self.turn[k] = np.where(left[start] < right[start], -self.AVOID_TURN, self.AVOID_TURN)
            self.avoid[idx[avoiding]] -= 1
            self.avoid[idx[~avoiding]] = 0
            v = np.where(avoiding, np.where(stop, 0.0, self.AVOID_SPEED), self.CRUISE_SPEED)
            w = np.where(avoiding, self.turn[idx], 0.0)
            for j, i in enumerate(idx):
                world.set_velocity(self.names[i], float(v[j]), float(w[j]))


CONTROLLERS = {"wander": StageWander}
"""Stage ``ctrl`` names the simulator runs, each a class built from the robots' names and a seed."""


class StageControllers:
    """The ``ctrl`` controllers of a world's robots, one instance per controller name; the
    world calls it after every step. Unknown names are reported by the world-file loader."""

    def __init__(self, specs, seed: int = 0):
        by_name: dict[str, list[str]] = {}
        for m in specs:
            if m.position and m.ctrl in CONTROLLERS:
                by_name.setdefault(m.ctrl, []).append(m.name)
        self.controllers = [CONTROLLERS[c](names, seed) for c, names in sorted(by_name.items())]

    def __bool__(self) -> bool:
        return bool(self.controllers)

    def __call__(self, world) -> None:
        for c in self.controllers:
            c(world)
