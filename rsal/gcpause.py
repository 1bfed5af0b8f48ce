"""Garbage-collector settings for the fabric's long-running processes, and a watch on its pauses.

CPython's cyclic collector stops the process (it holds the GIL) for as long as it traverses the
tracked objects of the generation it collects. An agent host of hundreds of agents keeps hundreds
of thousands of such objects alive from its start-up (agents, proxies, boards, subscriptions);
each full collection walks them all again, and a message that arrives meanwhile waits: pauses of
100-400 ms every few seconds in a 500-agent host, the p99 latency of a whole swarm
(docs/benchmarks.md). Two settings take the pauses away without giving up the collector:

- :func:`freeze_startup` (``gc.freeze``, Python 3.7+) moves every object alive after start-up to
  the permanent generation, which no later collection traverses;
- :func:`tune` raises the youngest generation's threshold, so that the per-message garbage (most
  of it freed by reference counting before any collection) is looked at less often.

:class:`GcWatch` measures the pauses (``gc.callbacks``) for progress lines.
"""

from __future__ import annotations

import gc
import time

__all__ = ["GEN0_THRESHOLD", "GcWatch", "freeze_startup", "tune"]

#: allocations between collections of the youngest generation (CPython's default: 700)
GEN0_THRESHOLD = 10_000


def tune(gen0: int = GEN0_THRESHOLD) -> None:
    """Collect the youngest generation every ``gen0`` net allocations (the older ones as before)."""
    _, g1, g2 = gc.get_threshold()
    gc.set_threshold(gen0, g1, g2)


def freeze_startup() -> int:
    """Collect once, then move every surviving object out of the collector's reach (they stay
    alive and are freed by reference counting as before); returns how many were frozen."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


class GcWatch:
    """The collector's pauses since the last :meth:`take`: their count, longest and total (s)."""

    def __init__(self) -> None:
        self._t0 = 0.0
        self.count = 0
        self.longest = 0.0
        self.total = 0.0
        gc.callbacks.append(self._on_gc)

    def _on_gc(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
            return
        d = time.perf_counter() - self._t0
        self.count += 1
        self.total += d
        if d > self.longest:
            self.longest = d

    def take(self) -> tuple[int, float, float]:
        """(pauses, longest s, total s) since the last call; starts a new period."""
        out = (self.count, self.longest, self.total)
        self.count, self.longest, self.total = 0, 0.0, 0.0
        return out

    def close(self) -> None:
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)
