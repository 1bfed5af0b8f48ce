"""The client side of the fabric: one Zenoh session, device proxies and listener dispatch.

:class:`Fabric` is what agents and tools hold: it opens the session (loopback defaults from
:mod:`rsal.transport`), makes :mod:`device proxies <rsal.devices>` for addresses, runs RPCs as
futures, and runs every listener on one dispatcher thread, so Zenoh's own threads only decode
samples and queue work (STYLE rule 2: callbacks never block and never call Zenoh).

Bases stop when their velocity commands stop (``cmd_timeout``, 0.5 s by default, docs/protocol.md);
:meth:`Fabric.hold` re-sends a held velocity command every :data:`HOLD_REFRESH` seconds from one
thread per fabric, for callers that set a velocity once and expect it to hold. It stops with the
process, so a dead client's robot still stops.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import zenoh

from . import keys, ownership
from .clock import clock
from .keys import DeviceAddr
from .msgs import ErrorCode, RpcError, encode, parse_reply
from .transport import TransportArgs, open_session

__all__ = ["Fabric", "Dispatcher", "query_rpc", "HOLD_REFRESH"]

log = logging.getLogger(__name__)

HOLD_REFRESH = 0.2  # s: a held command is re-sent this often (5 Hz, well inside a base's 0.5 s cmd_timeout)


def query_rpc(
    session: zenoh.Session,
    addr: DeviceAddr,
    op: str,
    args: dict | None,
    timeout: float,
    done: Callable[[dict | RpcError], None],
) -> None:
    """Query ``rsal/<addr>/rpc/<op>`` without blocking; ``done`` gets the reply map or an
    :class:`RpcError` (the device's typed error, a transport error, or a timeout), exactly once, on
    a Zenoh thread. The one implementation behind :meth:`Fabric.rpc_async` and the device server's
    driver requests. Only the reply of the session that owns the device counts
    (:mod:`rsal.ownership`)."""
    key = keys.rpc_key(addr, op)
    replies: list = []  # (replier zid, reply map or RpcError)
    owners: set[str] = set()
    lock = threading.Lock()
    pending = [2]  # the query and the owner look-up

    def on_reply(reply) -> None:
        try:
            if reply.ok is not None:
                result = parse_reply(reply.ok.payload.to_bytes(), key=key)
            else:
                parse_reply(reply.err.payload.to_bytes(), is_error=True, key=key, timeout=timeout)  # raises
        except RpcError as e:
            result = e
        with lock:
            replies.append((ownership.replier_zid(reply), result))

    def on_owner(reply) -> None:
        if reply.ok is not None:
            with lock:
                owners.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])

    def finish() -> None:
        with lock:
            pending[0] -= 1
            if pending[0]:
                return
        done(ownership.choose(key, str(addr), replies, owners, timeout))

    # Every queryable on the key answers (a rogue one included) and the owner's reply is chosen:
    # with consolidation, Zenoh would keep one reply, which need not be the owner's.
    try:
        session.liveliness().get(
            ownership.owners_query(keys.device_key(addr)), zenoh.handlers.Callback(on_owner, finish), timeout=timeout
        )
    except Exception as e:
        done(RpcError(ErrorCode.UNAVAILABLE, f"cannot look the device's owner up: {e}", key))
        return
    try:
        session.get(
            key,
            zenoh.handlers.Callback(on_reply, finish),
            payload=encode(args or {}),
            timeout=timeout,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
        )
    except Exception as e:
        pending[0] = 99  # the look-up's end must not answer too
        done(RpcError(ErrorCode.UNAVAILABLE, f"cannot send the query: {e}", key))


class Dispatcher:
    """Runs callbacks in order on one daemon thread; a callback that raises is logged, not fatal."""

    def __init__(self, name: str = "rsal-dispatch"):
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._t = threading.Thread(target=self._run, name=name, daemon=True)
        self._closed = False
        self._t.start()

    def submit(self, fn: Callable, *args: Any) -> None:
        if not self._closed:
            self._q.put((fn, args))

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            fn, args = item
            try:
                fn(*args)
            except Exception:
                log.exception("listener %r failed", getattr(fn, "__qualname__", fn))

    def close(self, timeout: float = 5.0) -> None:
        if not self._closed:
            self._closed = True
            self._q.put(None)
            if threading.current_thread() is not self._t:
                self._t.join(timeout)


class Fabric:
    """A connection to the RSAL fabric. Use as a context manager or call :meth:`close`."""

    def __init__(self, session: zenoh.Session, *, own_session: bool = True, direct_callbacks: bool = False):
        """``direct_callbacks``: run the device proxies' subscription callbacks on Zenoh's network
        threads instead of a Python thread per subscription (Zenoh's default). For a process with
        many devices -- a swarm host with hundreds of robots -- that is hundreds fewer threads waking
        for the GIL: at 200 robots the host's control cycles overran 41 % of the time with a thread
        per subscription and 2.5 % without (docs/benchmarks.md). A single very high-rate stream is
        faster with its own thread (the network thread then only receives), hence the default."""
        self.session = session
        self._own = own_session
        self.direct_callbacks = direct_callbacks
        self.dispatcher = Dispatcher()
        self._proxies: dict[DeviceAddr, Any] = {}
        self._lock = threading.Lock()
        self._closed = False
        self._held: dict[DeviceAddr, list] = {}  # addr -> [encoded cmd, monotonic time last sent]
        self._hold_wake = threading.Event()
        self._hold_thread: threading.Thread | None = None

    @classmethod
    def connect(cls, args: TransportArgs | None = None) -> Fabric:
        return cls(open_session(args))

    def __enter__(self) -> Fabric:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        with self._lock:
            self._held.clear()
        self._hold_wake.set()
        for p in list(self._proxies.values()):
            p.undeclare()
        self._proxies.clear()
        self.dispatcher.close()
        if self._own:
            try:
                self.session.close()
            except Exception:
                pass

    def callback(self, fn: Callable[[Any], None]):
        """The handler to subscribe ``fn`` with: ``fn`` itself (Zenoh runs it on a thread of its
        own), or run directly on Zenoh's network thread with ``direct_callbacks``."""
        return zenoh.handlers.Callback(fn, indirect=False) if self.direct_callbacks else fn

    # ------------------------------------------------------------------ devices
    def device(self, addr: DeviceAddr | str, cls: type | None = None):
        """The proxy of a device (one per address per fabric); ``cls`` defaults by interface."""
        from .devices import proxy_class

        a = keys.parse_device(addr) if isinstance(addr, str) else addr.without_key()
        with self._lock:
            p = self._proxies.get(a)
            if p is None:
                p = (cls or proxy_class(a.interface))(self, a)
                self._proxies[a] = p
        return p

    def _forget(self, addr: DeviceAddr) -> None:
        with self._lock:
            self._proxies.pop(addr, None)

    def node(self, *templates: str):
        """A :class:`~rsal.node.DeviceNode` discovering devices that match the templates."""
        from .node import DeviceNode

        return DeviceNode(self, templates or ("**",))

    # ------------------------------------------------------------------ rpc and cmd
    def rpc_async(self, addr: DeviceAddr, op: str, args: dict | None = None, *, timeout: float = 5.0) -> Future:
        """Call ``rsal/<addr>/rpc/<op>``; the future resolves to the reply map or raises RpcError."""
        fut: Future = Future()

        def done(outcome) -> None:
            if fut.done():
                return
            if isinstance(outcome, RpcError):
                fut.set_exception(outcome)
            else:
                fut.set_result(outcome)

        query_rpc(self.session, addr, op, args, timeout, done)
        return fut

    def rpc(self, addr: DeviceAddr, op: str, args: dict | None = None, *, timeout: float = 5.0) -> dict:
        """Blocking :meth:`rpc_async` (do not call it from a Zenoh callback)."""
        return self.rpc_async(addr, op, args, timeout=timeout).result(timeout + 1.0)

    def send(self, addr: DeviceAddr, msg) -> None:
        """Fire-and-forget command to ``rsal/<addr>/cmd``."""
        self.session.put(keys.cmd_key(addr), encode(msg), congestion_control=zenoh.CongestionControl.DROP)

    def hold(self, addr: DeviceAddr, msg) -> None:
        """Send ``msg`` to ``addr``'s ``cmd`` now and re-send it every :data:`HOLD_REFRESH` s until
        the next :meth:`hold` or :meth:`release` of that device (or :meth:`close`)."""
        payload = encode(msg)
        self.session.put(keys.cmd_key(addr), payload, congestion_control=zenoh.CongestionControl.DROP)
        with self._lock:
            if self._closed:
                return
            self._held[addr] = [payload, clock().now()]
            if self._hold_thread is None:
                self._hold_thread = threading.Thread(target=self._refresh_held, name="rsal-hold", daemon=True)
                self._hold_thread.start()

    def release(self, addr: DeviceAddr) -> None:
        """Stop re-sending ``addr``'s held command (it then times out at the base unless refreshed)."""
        with self._lock:
            self._held.pop(addr, None)

    def _refresh_held(self) -> None:
        while not self._closed:
            clk = clock()  # HOLD_REFRESH counts seconds of the process's clock (simulated under use_sim_time)
            now = clk.now()
            with self._lock:
                due = [(a, h) for a, h in self._held.items() if now - h[1] >= HOLD_REFRESH - 0.01]
                for _, h in due:
                    h[1] = now
            for a, h in due:
                try:
                    self.session.put(keys.cmd_key(a), h[0], congestion_control=zenoh.CongestionControl.DROP)
                except Exception as e:  # the session closed under us
                    log.debug("held command to %s not re-sent: %s", a, e)
            self._hold_wake.wait(clk.wall(HOLD_REFRESH / 2))
