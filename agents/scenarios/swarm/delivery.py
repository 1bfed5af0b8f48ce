"""Delivery within a radius, judged on the simulation's ground truth (neighbourhood broadcasts).

With neighbourhood-scoped broadcasts (:mod:`agents.cells`) a receiver is owed only the broadcasts
of the senders near it, so the all-to-all measure (every sequence number of every sender) no longer
applies. :class:`NeighbourhoodDelivery` states what is owed from ground truth instead:

- **expected**: every (receiver, broadcast) pair whose robots' *true* distance at the broadcast's
  send time was at most ``radius`` -- the true poses come from the monitor's samples of the
  simulation (:meth:`truth`), linearly interpolated to the send time; the send time is when the
  broadcast reached the monitor's session (:meth:`sent`; it listens to every cell, and takes the
  time on Zenoh's thread, not when its busy loop served the message), not a time any peer claims.
  A pair counts only while the receiver was listening: from ``settle`` seconds after its reception
  began (``since``: its cells first watched) to ``settle`` seconds before its latest report (``t``);
- **received**: what each receiver reports compactly: per sender, the sequence numbers received as
  flat ranges ``[first0, last0, first1, last1, ...]`` (``ranges`` in ``swarm_stats``).

:meth:`result` is vectorised (numpy): the distances of every broadcast of one sample interval to
every robot in one expression, and the membership of the expected pairs in the received ranges by
one sorted search over integer keys. Broadcasts the monitor itself missed (gaps in a sender's
sequence numbers as the monitor saw them) are counted apart (:attr:`Delivery.monitor_missed`): the
judge cannot vouch for them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Delivery", "NeighbourhoodDelivery", "expand_ranges"]

_SEQ_BITS = 24  # sequence numbers below 2**24 (97 days at 2 Hz)


@dataclass
class Delivery:
    """What :meth:`NeighbourhoodDelivery.result` found."""

    expected: int = 0  # (receiver, broadcast) pairs within the radius at send time
    received: int = 0  # of which the receiver reported
    sends: int = 0  # broadcasts judged (within the ground truth's time span)
    monitor_missed: int = 0  # broadcasts the monitor never saw (gaps in its sequence numbers)
    missing: list[tuple[str, str, int, float]] = field(default_factory=list)  # a few (receiver, sender, seq, m)

    @property
    def pct(self) -> float:
        return 100.0 * self.received / self.expected if self.expected else 0.0


def expand_ranges(flat: Sequence[int]) -> np.ndarray:
    """The integers in flat inclusive ranges ``[a0, b0, a1, b1, ...]``, as one array."""
    r = np.asarray(flat, dtype=np.int64).reshape(-1, 2)
    if not len(r):
        return np.zeros(0, dtype=np.int64)
    lengths = np.maximum(r[:, 1] - r[:, 0] + 1, 0)
    total = int(lengths.sum())
    offsets = np.arange(total) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.repeat(r[:, 0], lengths) + offsets


class NeighbourhoodDelivery:
    """Ground-truth delivery of broadcasts to the receivers within ``radius`` m of their sender.

    ``robots`` are the robot names in the order of the monitor's ground-truth samples.
    """

    def __init__(self, robots: Sequence[str], radius: float, settle: float = 1.0):
        if not radius > 0:
            raise ValueError(f"neighbourhood radius {radius!r} must be a positive number of metres")
        self.robots = list(robots)
        self.index = {r: i for i, r in enumerate(self.robots)}
        self.radius = float(radius)
        self.settle = float(settle)
        self._truth_t: list[float] = []
        self._truth_xy: list[np.ndarray] = []
        self._rob: list[int] = []
        self._sid: list[int] = []
        self._seq: list[int] = []
        self._t: list[float] = []
        self._senders: dict[str, int] = {}  # sender agent id -> code

    def truth(self, t: float, xy: np.ndarray) -> None:
        """A ground-truth sample: the (n, 2) true positions of :attr:`robots` at wall time ``t``."""
        xy = np.asarray(xy, dtype=float)
        if xy.shape != (len(self.robots), 2):
            raise ValueError(f"a ground-truth sample has shape {(len(self.robots), 2)}, got {xy.shape}")
        if self._truth_t and t <= self._truth_t[-1]:
            return  # out of order: keep the times increasing
        self._truth_t.append(float(t))
        self._truth_xy.append(xy)

    def sent(self, sender: str, robot: str, seq: int, t: float) -> None:
        """Broadcast ``seq`` of agent ``sender`` (driving ``robot``) seen at wall time ``t``."""
        i = self.index.get(robot)
        if i is None:
            return
        self._rob.append(i)
        self._sid.append(self._senders.setdefault(sender, len(self._senders)))
        self._seq.append(int(seq))
        self._t.append(float(t))

    @property
    def nsent(self) -> int:
        return len(self._t)

    def broadcasts(self) -> list[tuple[str, str, int, float]]:
        """Every broadcast seen: (sender agent id, its robot, sequence number, wall time seen)."""
        names = {c: s for s, c in self._senders.items()}
        return [
            (names[c], self.robots[i], q, t)
            for c, i, q, t in zip(self._sid, self._rob, self._seq, self._t, strict=True)
        ]

    def positions_at(self, t: float) -> np.ndarray | None:
        """(n, 2) true positions at wall time ``t``, interpolated between samples; None outside them."""
        T = self._truth_t
        if len(T) < 2 or not T[0] <= t <= T[-1]:
            return None
        k = min(int(np.searchsorted(T, t, side="right")) - 1, len(T) - 2)
        w = (t - T[k]) / (T[k + 1] - T[k])
        return self._truth_xy[k] + w * (self._truth_xy[k + 1] - self._truth_xy[k])

    def result(self, reports: Mapping[str, Mapping], max_missing: int = 5) -> Delivery:
        """Judge the broadcasts seen so far against ``reports`` (agent id -> its latest
        ``swarm_stats``: ``robot``, ``since``, ``t``, ``ranges``)."""
        out = Delivery()
        n = len(self.robots)
        if len(self._truth_t) < 2 or not self._t:
            return out
        T = np.asarray(self._truth_t)
        X = np.stack(self._truth_xy)
        rob, sid = np.asarray(self._rob), np.asarray(self._sid)
        seq, t = np.asarray(self._seq, dtype=np.int64), np.asarray(self._t)
        out.monitor_missed = _gaps(sid, seq)
        # each robot's listening window and agent id, from its reports
        lo = np.full(n, np.inf)
        hi = np.full(n, -np.inf)
        agent_of: dict[int, str] = {}
        for aid, rep in reports.items():
            j = self.index.get(rep.get("robot", ""))
            since, until = rep.get("since"), rep.get("t")
            if j is None or not isinstance(since, (int, float)) or not isinstance(until, (int, float)):
                continue
            lo[j], hi[j] = since + self.settle, until - self.settle
            agent_of[j] = aid
        # the expected pairs: the broadcasts of each sample interval against every robot at once
        k_of = np.searchsorted(T, t, side="right") - 1
        k_of[t == T[-1]] = len(T) - 2
        judged = (k_of >= 0) & (k_of <= len(T) - 2)
        out.sends = int(judged.sum())
        r2 = self.radius * self.radius
        pair_send: list[np.ndarray] = []
        pair_recv: list[np.ndarray] = []
        for k in np.unique(k_of[judged]):
            s = np.nonzero(judged & (k_of == k))[0]
            w = (t[s] - T[k]) / (T[k + 1] - T[k])
            P = X[k][None] + w[:, None, None] * (X[k + 1] - X[k])[None]  # (m, n, 2)
            d = P - P[np.arange(len(s)), rob[s]][:, None, :]
            near = np.einsum("mnk,mnk->mn", d, d) <= r2
            near[np.arange(len(s)), rob[s]] = False
            near &= (t[s][:, None] >= lo[None]) & (t[s][:, None] <= hi[None])
            a, b = np.nonzero(near)
            pair_send.append(s[a])
            pair_recv.append(b)
        if not pair_send:
            return out
        ps, pr = np.concatenate(pair_send), np.concatenate(pair_recv)
        S = max(1, len(self._senders))
        want = ((pr.astype(np.int64) * S + sid[ps]) << _SEQ_BITS) + seq[ps]
        # the received keys, from each receiver's ranges (all expanded at once)
        base: list[int] = []
        lo_hi: list[int] = []
        for j, aid in agent_of.items():
            for sender, flat in reports[aid].get("ranges", {}).items():
                c = self._senders.get(sender)
                if c is None or len(flat) % 2:
                    continue
                base.extend([(j * S + c) << _SEQ_BITS] * (len(flat) // 2))
                lo_hi.extend(flat)
        r = np.asarray(lo_hi, dtype=np.int64).reshape(-1, 2)
        r += np.asarray(base, dtype=np.int64)[:, None]
        got = np.sort(expand_ranges(r.ravel()))
        order = np.argsort(want)
        pos = np.empty(len(want), dtype=np.int64)
        pos[order] = np.searchsorted(got, want[order])  # sorted needles: one pass
        ok = np.zeros(len(want), dtype=bool)
        inside = pos < len(got)
        ok[inside] = got[pos[inside]] == want[inside]
        out.expected, out.received = len(want), int(ok.sum())
        names = {c: s for s, c in self._senders.items()}
        for i in np.nonzero(~ok)[0][:max_missing]:
            snd, j = ps[i], pr[i]
            k = max(0, min(len(T) - 2, int(np.searchsorted(T, t[snd], side="right")) - 1))
            dist = float(np.hypot(*(X[k][j] - X[k][rob[snd]])))
            out.missing.append((agent_of[int(j)], names[int(sid[snd])], int(seq[snd]), round(dist, 2)))
        return out


def _gaps(sid: np.ndarray, seq: np.ndarray) -> int:
    """Sequence numbers missing between each sender's first and last one seen (vectorised)."""
    if not len(sid):
        return 0
    order = np.lexsort((seq, sid))
    sid, seq = sid[order], seq[order]
    keep = np.r_[True, (np.diff(sid) != 0) | (np.diff(seq) != 0)]  # distinct (sender, seq)
    sid, seq = sid[keep], seq[keep]
    starts = np.r_[0, np.nonzero(np.diff(sid))[0] + 1]
    ends = np.r_[starts[1:], len(sid)]
    span = seq[ends - 1] - seq[starts] + 1
    return int((span - (ends - starts)).sum())
