"""What the Swarm scenario measures about its messages (thesis 4.2.3: "to stress the MAS layer").

Each broadcast's conversation id is ``p<sequence number>`` (:func:`sequence`), so a receiver counts
the gaps per sender (the delivery ratio); the receive wall time minus the message's ``time`` is its
latency, counted in the log-scale bins of :data:`LATENCY_EDGES` by a :class:`LatencyHistogram`
that merges across agents (the monitor merges every agent's) and travels as a dict on the
``swarm_stats`` service (:mod:`.messages`). The edges are round numbers, so a limit such as 50 ms is
checked exactly.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence

import numpy as np

__all__ = ["LATENCY_EDGES", "R10", "LatencyHistogram", "latency_bin", "latency_bins", "sequence"]

#: the R10 preferred numbers (ISO 3): ten steps per decade, each 25-28 % above the one before
R10 = (1.0, 1.25, 1.6, 2.0, 2.5, 3.15, 4.0, 5.0, 6.3, 8.0)
#: latency histogram bin edges in seconds: 10 µs .. 100 s on the R10 series, 10 bins per decade (bin
#: i is [e_i, e_i+1)). The edges are round numbers (1, 2, 5, 10, 20, 40, 50, 100 ms ...), so a limit
#: on one of them is decided exactly: every latency of the bins below the edge 50 ms is under 50 ms.
LATENCY_EDGES = np.array([float(f"{m}e{k}") for k in range(-5, 2) for m in R10] + [100.0])
_NBINS = LATENCY_EDGES.size - 1
_EDGES = LATENCY_EDGES.tolist()


def latency_bin(latency: float) -> int:
    """The bin of :data:`LATENCY_EDGES` that ``latency`` (seconds) falls in (clamped)."""
    i = bisect_right(_EDGES, latency) - 1
    return 0 if i < 0 else (i if i < _NBINS else _NBINS - 1)


def latency_bins(lat: np.ndarray) -> np.ndarray:
    """:func:`latency_bin` of each latency (seconds), vectorised."""
    i = np.searchsorted(LATENCY_EDGES, np.asarray(lat, dtype=float), side="right") - 1
    return np.clip(i, 0, _NBINS - 1)


def sequence(conversation: str) -> int | None:
    """The sequence number of a swarm broadcast's conversation id ``p<n>``, else None."""
    if len(conversation) > 1 and conversation[0] == "p" and conversation[1:].isdigit():
        return int(conversation[1:])
    return None


class LatencyHistogram:
    """Counts of latencies in the bins of :data:`LATENCY_EDGES`, mergeable across agents."""

    def __init__(self, counts: Sequence[int] | None = None, *, max_s: float = 0.0, sum_s: float = 0.0):
        self.counts = np.zeros(_NBINS, dtype=np.int64) if counts is None else np.asarray(counts, dtype=np.int64)
        if self.counts.shape != (_NBINS,):
            raise ValueError(f"a latency histogram has {_NBINS} bins, got {self.counts.shape}")
        self.max_s = float(max_s)
        self.sum_s = float(sum_s)
        self._pending = [0] * _NBINS  # counts not yet in ``counts`` (a list is faster to bump)
        self._npending = 0

    def add(self, latency: float) -> None:
        self.add_bin(latency_bin(latency), latency)

    def add_bin(self, i: int, latency: float) -> None:
        """Count a latency whose bin :func:`latency_bin` gave (shared by the agents of a host)."""
        self._pending[i] += 1
        self._npending += 1
        if latency > self.max_s:
            self.max_s = latency
        self.sum_s += latency

    def add_many(self, bins: np.ndarray, latencies: np.ndarray) -> None:
        """Count many latencies (seconds) whose bins are given (vectorised)."""
        if len(bins):
            self._flush()
            self.counts += np.bincount(bins, minlength=_NBINS)
            self.max_s = max(self.max_s, float(np.max(latencies)))
            self.sum_s += float(np.sum(latencies))

    def add_counts(self, counts: np.ndarray, max_s: float, sum_s: float) -> None:
        """Count a whole histogram's bins (counts per bin, their largest and summed latency: a
        row of :class:`.ledger.NearLedger`'s per-agent histograms)."""
        self._flush()
        self.counts += counts
        self.max_s = max(self.max_s, float(max_s))
        self.sum_s += float(sum_s)

    def _flush(self) -> None:
        if self._npending:
            self.counts += np.asarray(self._pending, dtype=np.int64)
            self._pending = [0] * _NBINS
            self._npending = 0

    def merge(self, other: LatencyHistogram) -> None:
        self._flush()
        other._flush()
        self.counts += other.counts
        self.max_s = max(self.max_s, other.max_s)
        self.sum_s += other.sum_s

    def subtract(self, earlier: LatencyHistogram) -> None:
        """Remove the counts of an earlier snapshot of the same agent's histogram (what came since;
        the largest latency stays the whole histogram's)."""
        self._flush()
        earlier._flush()
        self.counts = np.maximum(self.counts - earlier.counts, 0)
        self.sum_s = max(0.0, self.sum_s - earlier.sum_s)

    @property
    def n(self) -> int:
        self._flush()
        return int(self.counts.sum())

    def quantile(self, q: float) -> float:
        """The upper edge of the bin holding quantile ``q`` (seconds; an upper bound within 28 %), or
        the largest latency seen if that is lower."""
        n = self.n
        if n == 0:
            return math.nan
        self._flush()
        i = int(np.searchsorted(np.cumsum(self.counts), q * n, side="left"))
        return min(float(LATENCY_EDGES[min(i, _NBINS - 1) + 1]), self.max_s)

    def to_dict(self) -> dict:
        self._flush()
        nz = np.nonzero(self.counts)[0]
        return {"bins": nz.tolist(), "counts": self.counts[nz].tolist(), "max": self.max_s, "sum": self.sum_s}

    @classmethod
    def from_dict(cls, d: dict) -> LatencyHistogram:
        h = cls(max_s=float(d.get("max", 0.0)), sum_s=float(d.get("sum", 0.0)))
        bins, counts = d.get("bins", []), d.get("counts", [])
        if len(bins) != len(counts):
            raise ValueError("latency histogram: 'bins' and 'counts' differ in length")
        for i, c in zip(bins, counts, strict=True):
            if not (isinstance(i, int) and 0 <= i < _NBINS and isinstance(c, int) and c >= 0):
                raise ValueError(f"latency histogram: bad bin {i!r} or count {c!r}")
            h.counts[i] += c
        return h
