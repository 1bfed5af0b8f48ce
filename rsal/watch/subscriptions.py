"""The subscription side of ``rsal watch``: what it receives from the fabric, and how.

The view does not use the proxies of :mod:`rsal.client` / :mod:`rsal.node`, on purpose: a proxy
decodes every sample on Zenoh's thread and notifies listeners (right for an agent that reacts to
each message), while a view of a 100-robot fleet only needs the newest sample of each device once
per tick. So samples wait in Zenoh's own ring buffers (``RingChannel``: no Python runs per
sample on Zenoh's threads), and each tick drains them into a latest-wins dict (one payload per
key), decoding only what it draws. Liveliness tokens (devices and agents), device events and agent
service messages (``svc/**``) arrive the same way; rpc replies (``describe``, ``get_pose``, maps)
are queued for the logger thread. Everything here runs without blocking, on Zenoh's threads or
inside the tick; the logger (:class:`rsal.watch.app.Watcher`) owns the rest.
"""

from __future__ import annotations

import collections
import threading
import time

import zenoh

from .. import keys
from ..keys import DeviceAddr
from .state import Stats, WatchOptions

__all__ = ["Subscriptions"]


class Subscriptions:
    """Intake of the live view: ring-buffered subscriptions drained into latest-wins state."""

    def __init__(self, session: zenoh.Session, opts: WatchOptions):
        self.session = session
        self.opts = opts
        self.ke = keys.template_to_keyexpr(opts.template)
        self.stats = Stats()
        self._lock = threading.Lock()
        self._pending: dict[str, bytes] = {}
        self._text: collections.deque = collections.deque(maxlen=20000)  # (kind, key, payload)
        self._replies: collections.deque = collections.deque()  # (what, addr, reply or RpcError)
        self._tokens: collections.deque = collections.deque()  # (addr, joined)
        self._addr_cache: dict[str, tuple | None] = {}
        self._subs: list = []
        self._channels: list = []

    # ------------------------------------------------------------------ zenoh side (never blocks)
    def _on_data(self, sample) -> None:
        payload = sample.payload.to_bytes()
        with self._lock:
            self._pending[str(sample.key_expr)] = payload
            self.stats.n_in += 1

    def _on_text(self, sample) -> None:
        self._text.append(("svc", str(sample.key_expr), sample.payload.to_bytes()))
        with self._lock:
            self.stats.n_text += 1

    def _on_event(self, sample) -> None:
        self._text.append(("event", str(sample.key_expr), sample.payload.to_bytes()))
        with self._lock:
            self.stats.n_text += 1

    def _on_agent(self, sample) -> None:
        self._text.append(("agent", str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

    def _on_token(self, sample) -> None:
        parsed = keys.parse_key(str(sample.key_expr))
        if parsed is not None and parsed[1] == "":
            self._tokens.append((parsed[0], sample.kind == zenoh.SampleKind.PUT))

    def _rpc(self, what: str, addr: DeviceAddr, op: str, args: dict | None = None, timeout: float = 5.0) -> None:
        from ..client import query_rpc

        query_rpc(self.session, addr, op, args, timeout, lambda r: self._replies.append((what, addr, r)))

    def start(self) -> None:
        s = self.session
        base = self.ke
        ring = zenoh.handlers.RingChannel
        # Samples wait in Zenoh's own ring buffers (no Python runs on Zenoh's threads for them, so
        # the logger never waits for the GIL behind thousands of callbacks a second); each tick
        # drains them into the latest-wins dict. A ring that overflows drops its oldest samples.
        self._channels = [
            (s.declare_subscriber(f"{base}/data", ring(self.opts.ring)), self._on_data),
            (s.declare_subscriber(f"{base}/event", ring(1024)), self._on_event),
        ]
        self._subs = [s.liveliness().declare_subscriber(base, self._on_token, history=True)]
        if self.opts.services:
            self._channels.append((s.declare_subscriber("svc/**", ring(self.opts.ring)), self._on_text))
            self._subs.append(s.liveliness().declare_subscriber("agents/*", self._on_agent, history=True))
        self._subs.extend(sub for sub, _ in self._channels)

    def drain(self) -> None:
        """Move what the Zenoh ring buffers hold into the latest-wins dict and the text queue
        (at most one ring's worth each, so a flood cannot keep a tick from ending)."""
        n = 0
        for sub, take in self._channels:
            for _ in range(self.opts.ring):
                smp = sub.try_recv()
                if smp is None:
                    break
                take(smp)
                n += 1
        self.stats.drain_max = max(self.stats.drain_max, n)

    def close(self) -> None:
        self._channels = []
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        self._subs.clear()

    def wait_for_devices(self, timeout: float, stop: threading.Event | None = None) -> bool:
        """True once a device matching the template is alive (tokens arrive on a Zenoh thread);
        False after ``timeout`` seconds or when ``stop`` is set."""
        stop = stop or threading.Event()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not stop.is_set():
            if self._tokens:
                return True
            stop.wait(0.05)
        return bool(self._tokens) and not stop.is_set()

    def _parse(self, key: str) -> tuple | None:
        p = self._addr_cache.get(key, False)
        if p is False:
            p = keys.parse_key(key)
            self._addr_cache[key] = p
        return p
