"""What the agents of a neighbourhood swarm received, accounted in batches (sized for 1000 robots).

All-to-all, every agent of a host accounts every message (one Python call per receiver and
message). With neighbourhood-scoped broadcasts a message is owed only to the agents whose cells
hold its sender's cell, yet one host of 1000 robots still sees some 100 k (receiver, message) pairs
per second; a call per pair would fill the host's loop. Instead:

- :class:`NearLedger` (one per :class:`agents.hub.RobotHub`) appends each message once (sender,
  sequence number, cell, latency) and, when the hub is about to change its agents' cells
  (:attr:`agents.hub.RobotHub.before_rewatch`, every report period), hands each agent the batch of
  messages in its cells at once, as numpy arrays (:meth:`NearLedger.flush`);
- :class:`Received` keeps what one agent received as sorted integer keys (sender code, sequence
  number) and gives them as flat ranges per sender (:meth:`Received.ranges`: ``swarm_stats``'s
  ``ranges``, checked by :class:`.delivery.NeighbourhoodDelivery` against ground truth).

Sender ids are interned process-wide (:func:`code`), so keys of different hubs agree.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from agents.cells import cell_of

from .metrics import LATENCY_EDGES, sequence

if TYPE_CHECKING:
    from agents.hub import RobotHub
    from agents.services import Message

__all__ = ["NearLedger", "Received", "code", "latency_bins"]

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


def latency_bins(lat: np.ndarray) -> np.ndarray:
    """:func:`.metrics.latency_bin` of each latency (seconds), vectorised."""
    lat = np.asarray(lat, dtype=float)
    i = np.floor((np.log10(np.maximum(lat, 1e-5)) + 5.0) * 10.0).astype(np.int64)
    i[lat <= 1e-5] = 0
    return np.clip(i, 0, _NBINS - 1)


class Received:
    """The (sender, sequence number) pairs one agent received, as sorted unique int64 keys."""

    def __init__(self) -> None:
        self._keys = np.zeros(0, dtype=np.int64)
        self._new: list[np.ndarray] = []
        self._one: list[int] = []  # single messages (Received.add), merged with the batches

    def add(self, sender: str, seq: int) -> None:
        self._one.append((code(sender) << _SEQ_BITS) | seq)

    def add_keys(self, keys: np.ndarray) -> None:
        self._new.append(keys)

    def keys(self) -> np.ndarray:
        if self._new or self._one:
            parts = [self._keys, *self._new, np.asarray(self._one, dtype=np.int64)]
            self._keys = np.unique(np.concatenate(parts))
            self._new, self._one = [], []
        return self._keys

    def __len__(self) -> int:
        return len(self.keys())

    def ranges(self) -> dict[str, list[int]]:
        """Sender id -> the sequence numbers received as flat ranges ``[first0, last0, ...]``."""
        k = self.keys()
        if not len(k):
            return {}
        cut = np.nonzero(np.diff(k) != 1)[0]
        starts = k[np.r_[0, cut + 1]]
        ends = k[np.r_[cut, len(k) - 1]]
        out: dict[str, list[int]] = {}
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
            out.setdefault(_names[s >> _SEQ_BITS], []).extend((s & _SEQ_MASK, e & _SEQ_MASK))
        return out


class NearLedger:
    """One hub's log of neighbourhood broadcasts, handed to its agents in batches (:meth:`flush`)."""

    def __init__(self, hub: RobotHub):
        self.hub = hub
        self._key: list[int] = []
        self._cell: list[str] = []
        self._lat: list[float] = []
        self.flushed_at = time.time()  # wall time up to which the agents' figures are complete
        self.messages = 0

    def on_message(self, hub: RobotHub, msg: Message, now: float) -> None:  # the host's loop, once per message
        seq = sequence(msg.conversation)
        if seq is None:
            return
        b = msg.body
        self._key.append((code(msg.sender) << _SEQ_BITS) | seq)
        self._cell.append(cell_of(b.x, b.y, hub.cell_size))
        self._lat.append(now - msg.time)
        self.messages += 1

    def flush(self) -> None:
        """Account the messages logged since the last flush for every agent whose cells (as they
        are now, before the hub changes them) hold the message's cell."""
        now = time.time()
        if not self._key:
            self.flushed_at = now
            return
        keys = np.asarray(self._key, dtype=np.int64)
        lat = np.maximum(np.asarray(self._lat), 0.0)
        cells = self._cell
        self._key, self._cell, self._lat = [], [], []
        bins = latency_bins(lat)
        by_cell: dict[str, list[int]] = {}
        for i, c in enumerate(cells):
            by_cell.setdefault(c, []).append(i)
        per_agent: dict[int, tuple[object, list[np.ndarray]]] = {}
        for c, idx in by_cell.items():
            agents = self.hub.agents_in(c)
            if not agents:
                continue
            arr = np.asarray(idx)
            for a in agents:
                e = per_agent.get(id(a))
                if e is None:
                    per_agent[id(a)] = (a, [arr])
                else:
                    e[1].append(arr)
        senders = keys >> _SEQ_BITS
        for a, parts in per_agent.values():
            take = getattr(a, "take", None)
            if take is None:
                continue
            idx = parts[0] if len(parts) == 1 else np.concatenate(parts)
            own = _codes.get(a.id)
            if own is not None:
                idx = idx[senders[idx] != own]
            if len(idx):
                take(keys[idx], bins[idx], lat[idx])
        self.flushed_at = now
