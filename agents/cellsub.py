"""A subscription to one service in a changing set of spatial cells (:mod:`agents.cells`).

Neighbourhood-scoped broadcasts (the thesis's "information-hiding", 5.3) are put on
``svc/<service>/<cell>/<sender>``. A receiver that watches a few cells holds one Zenoh subscriber
per cell (``svc/<service>/<cell>/*``), so the fabric routes it only its cells' messages. A host
that watches many -- a swarm host with 500 robots watches several hundred cells -- pays for each:
Zenoh matches every put of the session and every received sample against every subscriber
(``Session.put`` took 26 us CPU with 20 cell subscribers and 45-113 us with 400), and each runs
its Python callback on a thread of its own. Above :attr:`CellSubscription.wildcard_above` cells
(:data:`DEFAULT_WILDCARD_ABOVE`) a :class:`CellSubscription` therefore holds one subscriber on
``svc/<service>/*/*`` instead and turns away, by the key's cell chunk and before decoding, every
sample of a cell it does not watch; it returns to a subscriber per cell when the watched cells
fall to three quarters of the threshold (hysteresis, so a host near the threshold does not switch
at every re-watch).

No sample is missed in a switch: the new subscriber(s) are declared first and the old ones are
undeclared only :attr:`CellSubscription.grace` seconds later (undeclared at once, a few samples
that had reached only the old subscriber were lost: 3 of 400 in the switch test), every subscriber
turning away the cells no longer watched meanwhile. A message received through both in that
overlap is delivered once: for :attr:`CellSubscription.overlap` seconds after a switch, messages
are told apart by their envelope (sender, conversation, time) and a repeat is dropped (counted in
:attr:`CellSubscription.duplicates`).

With ``loopback`` the broadcasts of the host's own agents (``Services.publish`` in the same
process) reach the subscription in process, as the :class:`~agents.services.Message` they were,
on the host's loop when they are published, and its subscribers take only other sessions' samples
(``allowed_origin=REMOTE``): Zenoh does not route the host's own puts to them at all (the key's
sender chunk still turns away a local sender's copy, should one come). A swarm host of 500 robots
hears its own agents in about half of what it receives: each was a trip through Zenoh's local
routing, a callback thread and a decode (later a callback that only rejected it).

With ``bundles`` it also holds one subscriber on the service's bundles (``svc/<service>/@bundle/*``,
:mod:`agents.services`), whatever its form, and delivers the entries of its watched cells: one
sample, one thread hand-over and one loop call per bundle instead of per broadcast.
"""

from __future__ import annotations

import inspect
import logging
import time
from typing import TYPE_CHECKING

from rsal.keys import check_name

from .services import BundleSubscription, Callback, Filter, Message, Subscription

if TYPE_CHECKING:
    from .services import Services

__all__ = ["DEFAULT_WILDCARD_ABOVE", "CellSubscription"]

log = logging.getLogger(__name__)

#: above this many watched cells, one wildcard subscriber filtered by cell replaces a subscriber per cell
DEFAULT_WILDCARD_ABOVE = 64


class CellSubscription:
    """Subscribers to one service in a changing set of cells: :meth:`watch` declares what the new
    cells need before it undeclares what the old ones no longer need, so a receiver that moves
    misses nothing in between. Host loop only; :meth:`close` undeclares all.

    ``wildcard_above``: watching more cells than this, one subscriber on ``svc/<service>/*/*``
    filtered by cell (0 or less: never)."""

    def __init__(
        self,
        services: Services,
        service: str,
        callback: Callback,
        flt: Filter | None,
        owner: str,
        *,
        wildcard_above: int = DEFAULT_WILDCARD_ABOVE,
        overlap: float = 2.0,
        loopback: bool = False,
        bundles: bool = False,
    ):
        self.service, self.owner = service, owner
        self.wildcard_above = int(wildcard_above)
        self.overlap = float(overlap)  # seconds after a switch during which repeats are dropped
        self.grace = min(0.5, self.overlap / 2)  # seconds the old form's subscribers outlive a switch
        self._retiring: list[Subscription] = []
        self._services = services
        self._callback = callback
        self._filter = flt
        self._subs: dict[str, Subscription] = {}  # per-cell form: cell -> its subscriber
        self._wild: Subscription | None = None  # wildcard form
        self._watched: frozenset[str] = frozenset()  # read by the wildcard's key filter on Zenoh's thread
        self._dedupe_until = 0.0
        self._seen: set[tuple[str, str, float]] = set()
        self.received = 0  # messages passed to the callback
        self.loopback = bool(loopback)
        self.local_received = 0  # of which: the host's own broadcasts, handed over in process
        self.duplicates = 0  # messages received twice across a switch, dropped
        self.switches = 0
        self.closed = False
        if self.loopback:
            services.add_loopback(service, self)
        self.bundle_entries = 0  # bundle entries of watched cells, delivered
        self._bundles = (
            BundleSubscription(services, service, self._on_bundle, owner, on_thread=True, remote_only=self.loopback)
            if bundles
            else None
        )

    @property
    def cells(self) -> set[str]:
        """The cells watched."""
        return set(self._watched)

    @property
    def wildcard(self) -> bool:
        """True while one wildcard subscriber stands for the cells."""
        return self._wild is not None

    @property
    def subscribers(self) -> int:
        """The Zenoh subscribers held now."""
        return len(self._subs) + (self._wild is not None)

    @property
    def retiring(self) -> int:
        """The old form's subscribers still declared after a switch (for :attr:`grace` seconds)."""
        return len(self._retiring)

    @property
    def skipped(self) -> int:
        """Samples the wildcard subscriber turned away (cells not watched) since it was declared."""
        return self._wild.skipped if self._wild is not None else 0

    def watch(self, cells: set[str] | frozenset[str]) -> None:
        """Receive the messages of exactly ``cells`` from now on."""
        if self.closed:
            return
        service = self.service
        new = frozenset(check_name("cell", c) for c in cells)
        above = self.wildcard_above
        if self._wild is None:
            go_wild = 0 < above < len(new)
        else:
            go_wild = not (above <= 0 or len(new) <= above * 3 // 4)
        self._watched = new  # the subscribers' key filter reads it: set before any is declared
        if go_wild:
            if self._wild is None:
                self._wild = self._subscribe(f"svc/{service}/*/*")
                self._switched(list(self._subs.values()))
                self._subs.clear()
            return
        for c in sorted(new - self._subs.keys()):
            self._subs[c] = self._subscribe(f"svc/{service}/{c}/*")
        if self._wild is not None:
            self._switched([self._wild])
            self._wild = None
        for c in sorted(self._subs.keys() - new):
            self._subs.pop(c).close()

    def _subscribe(self, keyexpr: str) -> Subscription:
        s = self._services
        return Subscription(
            s, self.service, self._on_message, None, self.owner, keyexpr, self._accept, remote_only=self.loopback
        )

    def _switched(self, old: list[Subscription]) -> None:
        """The new form's subscribers are declared: keep the old ones for :attr:`grace` seconds
        (what reached them before the new ones were known is still delivered), then undeclare
        them; repeats are dropped for :attr:`overlap` seconds."""
        self.switches += 1
        self._dedupe_until = time.monotonic() + self.overlap
        self._retiring.extend(old)
        self._services.host.loop.call_later(self.grace, self._retire, old)

    def _retire(self, old: list[Subscription]) -> None:
        for sub in old:
            sub.close()
            if sub in self._retiring:
                self._retiring.remove(sub)

    def _accept(self, key: str) -> bool:  # Zenoh's thread: is the key's cell chunk watched?
        parts = key.split("/", 3)
        if len(parts) != 4 or parts[2] not in self._watched:
            return False
        return not (self.loopback and parts[3] in self._services.local_senders)  # had in process

    def _on_bundle(self, entries: list[tuple[str, Message]], _t: float) -> None:  # Zenoh's thread
        watched = self._watched
        local = self._services.local_senders if self.loopback else ()
        mine = [m for c, m in entries if c in watched and m.sender not in local]
        if mine:
            self._services.call_soon(self._deliver_many, mine)

    def _deliver_many(self, msgs: list[Message]) -> None:  # the host's loop
        if self.closed:
            return
        self.bundle_entries += len(msgs)
        for msg in msgs:
            try:
                out = self._on_message(msg)
                if out is not None:
                    self._services.host.spawn(out, f"{self.owner}: {self.service} callback")
            except Exception:
                log.exception("%s: callback for %s from %s failed", self.owner, self.service, msg.sender)

    def local(self, msg: Message, cell: str) -> None:  # the host's loop, from Services.publish
        """A broadcast of this host's own, from ``cell``: delivered when the cell is watched."""
        if self.closed or cell not in self._watched:
            return
        self.local_received += 1
        out = self._on_message(msg)
        if out is not None:
            self._services.host.spawn(out, f"{self.owner}: {self.service} callback")

    def _on_message(self, msg: Message):  # the host's loop, through Subscription._deliver
        if self._dedupe_until:
            if time.monotonic() <= self._dedupe_until:
                mid = (msg.sender, msg.conversation, msg.time)
                if mid in self._seen:
                    self.duplicates += 1
                    return None
                self._seen.add(mid)
            else:
                self._dedupe_until = 0.0
                self._seen.clear()
        if self._filter is not None and not self._filter(msg):
            return None
        self.received += 1
        out = self._callback(msg)
        return out if inspect.isawaitable(out) else None

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            if self.loopback:
                self._services.remove_loopback(self.service, self)
            for sub in self._subs.values():
                sub.close()
            self._subs.clear()
            if self._wild is not None:
                self._wild.close()
                self._wild = None
            for sub in self._retiring:
                sub.close()
            self._retiring.clear()
            if self._bundles is not None:
                self._bundles.close()
            self._watched = frozenset()
