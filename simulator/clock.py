"""The simulation clock: fixed steps, paced to real time with a speed-up factor or run flat out.

Stage advances its world by ``interval_sim`` per update and sleeps so that one update takes
``interval_real`` of wall time; here the ratio is a *speed-up* (1.0 = real time, 10.0 = ten
times faster, ``inf`` = as fast as possible). A paced run that falls behind does not try to catch
up by skipping sensor updates: it runs flat out until it is back on schedule and reports the
achieved real-time factor.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Pacer", "RunStats", "run"]


@dataclass
class RunStats:
    """What a run achieved."""

    steps: int
    sim_seconds: float
    wall_seconds: float

    @property
    def realtime_factor(self) -> float:
        return self.sim_seconds / self.wall_seconds if self.wall_seconds > 0 else math.inf


class Pacer:
    """Sleeps between steps so simulated time advances ``speedup`` times faster than wall time."""

    def __init__(self, interval_sim: float, speedup: float = 1.0):
        self.interval_sim = float(interval_sim)
        self.speedup = float(speedup) if speedup and speedup > 0 else math.inf
        self._t0 = time.perf_counter()
        self._n = 0

    def restart(self) -> None:
        self._t0 = time.perf_counter()
        self._n = 0

    def wait(self) -> None:
        """Call once per step, after the step."""
        self._n += 1
        if math.isinf(self.speedup):
            return
        due = self._t0 + self._n * self.interval_sim / self.speedup
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        elif delay < -1.0:
            # More than a second behind: re-anchor instead of bursting to catch up.
            self._t0 = time.perf_counter()
            self._n = 0


def run(
    world,
    duration: float,
    *,
    speedup: float = math.inf,
    on_step: Callable[[object], None] | None = None,
    progress: Callable[[RunStats], None] | None = None,
    progress_every: float = 1.0,
) -> RunStats:
    """Step ``world`` for ``duration`` simulated seconds. ``on_step(world)`` runs after every step
    (controllers); ``progress(stats)`` about every ``progress_every`` wall seconds."""
    steps = max(0, int(round(duration / world.spec.interval_sim)))
    pacer = Pacer(world.spec.interval_sim, speedup)
    t0 = time.perf_counter()
    last = t0
    sim0 = world.time
    for _ in range(steps):
        world.step()
        if on_step is not None:
            on_step(world)
        pacer.wait()
        if progress is not None:
            now = time.perf_counter()
            if now - last >= progress_every:
                last = now
                progress(RunStats(world.steps, world.time - sim0, now - t0))
    return RunStats(steps, world.time - sim0, time.perf_counter() - t0)
