"""What the agents of a neighbourhood swarm received, accounted in batches (sized for 1000 robots).

All-to-all, every agent of a host accounts every message (one Python call per receiver and
message). With neighbourhood-scoped broadcasts a message is owed only to the agents whose cells
hold its sender's cell, yet one host of 1000 robots still sees some 100 k (receiver, message) pairs
per second; a call per pair would fill the host's loop. Instead:

- :class:`NearLedger` (one per :class:`agents.hub.RobotHub`) appends each message once (sender,
  sequence number, position, latency) and, when the hub is about to change its agents' cells
  (:attr:`agents.hub.RobotHub.before_rewatch`, every report period), accounts the (receiver,
  message) pairs of all its agents at once (:meth:`NearLedger.flush`): the messages grouped by cell
  (one sort), each watched cell's receivers as agent indices, the pairs expanded receiver-major in
  numpy, kept as one hub-wide key array per flush, and the latencies counted in one
  (agents x bins) histogram for the hub (one ``bincount``). An agent gets its share -- its keys,
  its histogram row, its count -- only when it asks (:meth:`NearLedger.take`, when its
  ``swarm_stats`` are built), so a flush costs no Python call per agent;
- :class:`Received` keeps what one agent received as sorted integer keys (sender code, sequence
  number) and gives them as flat ranges per sender (:meth:`Received.ranges`: ``swarm_stats``'s
  ``ranges``, checked by :class:`.delivery.NeighbourhoodDelivery` against ground truth).

Sender ids are interned process-wide (:func:`code`), so keys of different hubs agree.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .metrics import LATENCY_EDGES, latency_bins, sequence

if TYPE_CHECKING:
    from agents.hub import RobotHub
    from agents.services import Message

__all__ = ["NearLedger", "Received", "Taken", "code", "latency_bins"]

_SEQ_BITS = 24
_SEQ_MASK = (1 << _SEQ_BITS) - 1
_NBINS = LATENCY_EDGES.size - 1
_codes: dict[str, int] = {}
_names: list[str] = []


def code(sender: str) -> int:
    """The process-wide code of a sender id (interned on first use)."""
    c = _codes.get(sender)
    if c is None:
        c = _codes[sender] = len(_names)
        _names.append(sender)
    return c


class Received:
    """The (sender, sequence number) pairs one agent received, as sorted unique int64 keys."""

    def __init__(self) -> None:
        self._keys = np.zeros(0, dtype=np.int64)
        self._new: list[np.ndarray] = []
        self._one: list[int] = []  # single messages (Received.add), merged with the batches
        self._delta: list[np.ndarray] = []  # what came since the last take_new (add's singles included)
        self._delta_one: list[int] = []

    def add(self, sender: str, seq: int) -> None:
        k = (code(sender) << _SEQ_BITS) | seq
        self._one.append(k)
        self._delta_one.append(k)

    def add_keys(self, keys: np.ndarray) -> None:
        self._new.append(keys)
        self._delta.append(keys)

    def take_new(self) -> dict[str, list[int]]:
        """What was added since the last call, as :meth:`ranges` gives it (the sum of these parts
        is :meth:`ranges`): a report of the new keys costs what they are, not the whole set."""
        if not self._delta and not self._delta_one:
            return {}
        k = np.unique(np.concatenate([*self._delta, np.asarray(self._delta_one, dtype=np.int64)]))
        self._delta, self._delta_one = [], []
        return _ranges(k)

    def keys(self) -> np.ndarray:
        if self._new or self._one:
            # merge the new keys into the sorted ones: the two sorted runs concatenated and sorted
            # with the stable sort (a merge of runs, near linear), repeats dropped -- the whole set
            # grows to tens of thousands per agent (1.05 -> 0.20 ms for 6,000 into 36,000)
            new = np.concatenate([*self._new, np.asarray(self._one, dtype=np.int64)])
            new.sort()
            self._new, self._one = [], []
            k = np.concatenate([self._keys, new])
            k.sort(kind="stable")
            keep = np.empty(len(k), dtype=bool)
            keep[:1] = True
            np.not_equal(k[1:], k[:-1], out=keep[1:])
            self._keys = k[keep]
        return self._keys

    def __len__(self) -> int:
        return len(self.keys())

    def senders(self) -> int:
        """How many senders it received from."""
        return len(np.unique(self.keys() >> _SEQ_BITS))

    def ranges(self) -> dict[str, list[int]]:
        """Sender id -> the sequence numbers received as flat ranges ``[first0, last0, ...]``."""
        return _ranges(self.keys())


def _ranges(k: np.ndarray) -> dict[str, list[int]]:
    """Sorted unique keys as sender id -> flat inclusive sequence ranges ``[first0, last0, ...]``."""
    if not len(k):
        return {}
    cut = np.nonzero(np.diff(k) != 1)[0]
    starts = k[np.r_[0, cut + 1]]
    ends = k[np.r_[cut, len(k) - 1]]
    flat = np.empty(2 * len(starts), dtype=np.int64)
    flat[0::2] = starts & _SEQ_MASK
    flat[1::2] = ends & _SEQ_MASK
    senders = starts >> _SEQ_BITS  # sorted: each sender's runs are adjacent
    b = np.r_[0, np.nonzero(np.diff(senders))[0] + 1, len(senders)]
    fl = flat.tolist()
    return {
        _names[c]: fl[2 * i : 2 * j]
        for c, i, j in zip(senders[b[:-1]].tolist(), b[:-1].tolist(), b[1:].tolist(), strict=True)
    }


@dataclass
class Taken:
    """What a hub accounted for one agent since it last asked (:meth:`NearLedger.take`)."""

    keys: list[np.ndarray]  # (sender code << 24 | sequence number) per message, in batches
    counts: np.ndarray  # its latency histogram's counts per bin of LATENCY_EDGES
    max_s: float
    sum_s: float
    n: int  # messages accounted (keys may repeat when its cells listed it twice)


class NearLedger:
    """One hub's log of neighbourhood broadcasts, accounted for all its agents at once
    (:meth:`flush`) and handed to each agent when it asks (:meth:`take`).

    Only agents that :meth:`join` are accounted. ``keep`` flushes' key batches stay in the hub
    (an agent that asks less often gets its older slices parked, so memory stays what the agents'
    own records would hold)."""

    def __init__(self, hub: RobotHub, keep: int = 16):
        self.hub = hub
        self.keep = keep
        self._key: list[int] = []
        self._x: list[float] = []
        self._y: list[float] = []
        self._lat: list[float] = []
        self.flushed_at = time.time()  # wall time up to which the agents' figures are complete
        self.messages = 0
        self.pairs = 0  # (receiver, message) pairs accounted
        # the joined agents: index <-> agent, each one's own sender code (its messages are not owed to it)
        self._index: dict[int, int] = {}
        self._agents: list[object | None] = []
        self._own = np.zeros(0, dtype=np.int64)
        # per agent: latency counts (agents x bins), max, sum, messages; the next batch it takes
        self._counts = np.zeros((0, _NBINS), dtype=np.int64)
        self._max = np.zeros(0)
        self._sum = np.zeros(0)
        self._n = np.zeros(0, dtype=np.int64)
        self._next = np.zeros(0, dtype=np.int64)
        # the key batches of the last flushes: (keys receiver-major, bounds per agent index)
        self._batches: list[tuple[np.ndarray, np.ndarray]] = []
        self._base = 0  # the number of the first batch in _batches
        self._parked: dict[int, list[np.ndarray]] = {}  # slices of dropped batches not yet taken

    # ------------------------------------------------------------------ agents
    def join(self, agent: object) -> None:
        """Account ``agent`` (an object with an ``id``) from the next flush on, when the hub lists
        it as a receiver of a cell (:meth:`agents.hub.RobotHub.agents_in`)."""
        if id(agent) in self._index:
            return
        i = self._index[id(agent)] = len(self._agents)
        self._agents.append(agent)
        if i >= len(self._own):
            grow = max(64, 2 * len(self._own))
            self._own = np.r_[self._own, np.full(grow, -1, dtype=np.int64)]
            self._counts = np.vstack([self._counts, np.zeros((grow, _NBINS), dtype=np.int64)])
            self._max = np.r_[self._max, np.zeros(grow)]
            self._sum = np.r_[self._sum, np.zeros(grow)]
            self._n = np.r_[self._n, np.zeros(grow, dtype=np.int64)]
            self._next = np.r_[self._next, np.zeros(grow, dtype=np.int64)]
        self._own[i] = code(agent.id)  # type: ignore[attr-defined]
        self._next[i] = self._base + len(self._batches)

    def leave(self, agent: object) -> None:
        """Stop accounting ``agent`` (what it has not taken is dropped)."""
        i = self._index.pop(id(agent), None)
        if i is not None:
            self._agents[i] = None
            self._parked.pop(i, None)
            self._counts[i] = 0
            self._max[i] = self._sum[i] = 0.0
            self._n[i] = 0

    def take(self, agent: object) -> Taken | None:
        """What the hub accounted for ``agent`` since it last asked (None if it has not joined)."""
        i = self._index.get(id(agent))
        if i is None:
            return None
        keys = self._parked.pop(i, [])
        end = self._base + len(self._batches)
        for b in range(max(int(self._next[i]) - self._base, 0), len(self._batches)):  # parked: older
            k, bounds = self._batches[b]
            if i + 1 < len(bounds) and bounds[i + 1] > bounds[i]:
                keys.append(k[bounds[i] : bounds[i + 1]])
        self._next[i] = end
        out = Taken(keys, self._counts[i].copy(), float(self._max[i]), float(self._sum[i]), int(self._n[i]))
        self._counts[i] = 0
        self._max[i] = self._sum[i] = 0.0
        self._n[i] = 0
        return out

    # ------------------------------------------------------------------ messages
    def on_message(self, hub: RobotHub, msg: Message, now: float) -> None:  # the host's loop, once per message
        seq = sequence(msg.conversation)
        if seq is None:
            return
        b = msg.body
        self._key.append((code(msg.sender) << _SEQ_BITS) | seq)
        self._x.append(b.x)
        self._y.append(b.y)
        self._lat.append(now - msg.time)
        self.messages += 1

    def flush(self) -> None:
        """Account the messages logged since the last flush for every joined agent whose cells (as
        they are now, before the hub changes them) hold the message's cell, except its own."""
        now = time.time()
        n = len(self._key)
        if not n:
            self.flushed_at = now
            return
        keys = np.asarray(self._key, dtype=np.int64)
        size = self.hub.cell_size
        cx = np.floor(np.asarray(self._x, dtype=float) / size).astype(np.int64)  # agents.cells.cell_of
        cy = np.floor(np.asarray(self._y, dtype=float) / size).astype(np.int64)
        lat = np.maximum(np.asarray(self._lat, dtype=float), 0.0)
        self._key, self._x, self._y, self._lat = [], [], [], []
        bins = latency_bins(lat)
        # the messages grouped by cell: order[start[j]:end[j]] are those of distinct cell j
        cc = (cx << 32) + (cy & 0xFFFFFFFF)
        order = np.argsort(cc, kind="stable")
        sc = cc[order]
        start = np.nonzero(np.r_[True, sc[1:] != sc[:-1]])[0]
        end = np.r_[start[1:], n]
        # (agent index, cell j) for every receiver the hub lists in each of these cells
        index = self._index
        pa: list[int] = []
        pc: list[int] = []
        first = order[start]
        for j, (ix, iy) in enumerate(zip(cx[first].tolist(), cy[first].tolist(), strict=True)):
            for a in self.hub.agents_in(f"c{ix}_{iy}"):
                i = index.get(id(a))
                if i is not None:
                    pa.append(i)
                    pc.append(j)
        self._batch(keys, bins, lat, order, start, end, np.asarray(pa, dtype=np.int64), np.asarray(pc, dtype=np.int64))
        self.flushed_at = now

    def _batch(
        self,
        keys: np.ndarray,
        bins: np.ndarray,
        lat: np.ndarray,
        order: np.ndarray,
        start: np.ndarray,
        end: np.ndarray,
        pa: np.ndarray,
        pc: np.ndarray,
    ) -> None:
        """Expand the (agent index ``pa``, cell ``pc``) pairs into (agent, message) pairs,
        receiver-major (``order[start[j]:end[j]]`` are cell j's messages), and count them."""
        na = len(self._agents)
        o = np.argsort(pa, kind="stable")
        pa, pc = pa[o], pc[o]
        length = end[pc] - start[pc]
        total = int(length.sum())
        offset = np.cumsum(length) - length
        msg = order[np.repeat(start[pc] - offset, length) + np.arange(total)]
        agent = np.repeat(pa, length)
        ok = (keys[msg] >> _SEQ_BITS) != self._own[agent]  # not its own messages
        msg, agent = msg[ok], agent[ok]
        self.pairs += len(msg)
        per = np.bincount(agent, minlength=na)
        bounds = np.r_[0, np.cumsum(per)]
        self._counts[:na] += np.bincount(agent * _NBINS + bins[msg], minlength=na * _NBINS).reshape(na, _NBINS)
        lm = lat[msg]
        self._sum[:na] += np.bincount(agent, weights=lm, minlength=na)
        self._n[:na] += per
        has = np.nonzero(per)[0]
        if len(has):
            self._max[has] = np.maximum(self._max[has], np.maximum.reduceat(lm, bounds[has]))
        self._batches.append((keys[msg], bounds))
        while len(self._batches) > self.keep:  # park the oldest batch's slices of the agents that did not ask
            k, b = self._batches.pop(0)
            waiting = np.nonzero(self._next[: len(b) - 1] <= self._base)[0]
            for i in waiting[b[waiting + 1] > b[waiting]].tolist():
                if self._agents[i] is not None:
                    self._parked.setdefault(i, []).append(k[b[i] : b[i + 1]])
            self._base += 1
