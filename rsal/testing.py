"""An in-memory fabric for unit tests: the network swapped for a fake, as httpx's ``MockTransport``.

- :class:`FakeSession` is enough of a ``zenoh.Session`` for the device server, the device
  proxies and ``DeviceNode``: ``put``/``delete``, publishers, subscribers, queryables and ``get``,
  liveliness tokens, liveliness subscribers (with ``history``) and liveliness ``get``, all on key
  expressions matched by Zenoh's own ``KeyExpr.intersects`` (``*`` and ``**``; it runs offline).
  Delivery is synchronous, on the caller's thread, in declaration order: a test sees the effect of
  a ``put`` when the call returns. It records the liveliness tokens declared (``tokens``) and the
  last payload put on each key (``last``). ``FakeSession(silent=True)`` delivers nothing at all
  (every declaration succeeds; no sample, token or reply ever arrives): a fabric where nobody
  answers, not even the session's own declarations.
- :class:`FakeServer` is what a driver sees of its device server (``send``, ``publish``,
  ``publish_event``, ``request``, the rate-limited ``_warn``, ``shared``), every call recorded.
- :class:`FakeFabric` stands in for :class:`rsal.client.Fabric` under client-side device proxies:
  proxies subscribe on its :class:`FakeSession`, :meth:`FakeFabric.push` publishes a data sample
  to them, commands and RPCs are recorded and ``describe`` is answered from a table.

Only tests import this module; it is shipped so that tests of every package (and users' own
drivers and agents) share one fake instead of each writing its own.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import zenoh

from . import keys, msgs
from .keys import DeviceAddr, parse_device
from .msgs import ErrorCode, RpcError, VelocityCmd

__all__ = [
    "FakeFabric",
    "FakeId",
    "FakeQuery",
    "FakeReply",
    "FakeSample",
    "FakeServer",
    "FakeSession",
    "InlineDispatcher",
]

_PUT, _DELETE = zenoh.SampleKind.PUT, zenoh.SampleKind.DELETE

FAKE_ZID = "fa4e"  # every FakeSession's Zenoh id: all its entities are one session


def _intersects(a: str, b: str) -> bool:
    return zenoh.KeyExpr(a).intersects(zenoh.KeyExpr(b))


class FakeSample(NamedTuple):
    """A sample as a handler sees it: ``key_expr``, ``payload`` (``to_bytes()``, ``len()``) and ``kind``."""

    key_expr: str
    payload: zenoh.ZBytes
    kind: Any = _PUT  # zenoh.SampleKind


class FakeId(NamedTuple):
    """A replier's id, as ``Reply.replier_id`` gives it: the session's ``zid``."""

    zid: str


class FakeReply(NamedTuple):
    """A reply to :meth:`FakeSession.get`: ``ok`` (a sample) or ``err`` (an object with ``payload``),
    and ``replier_id`` (the answering session's id)."""

    ok: FakeSample | None = None
    err: FakeSample | None = None
    replier_id: FakeId | None = None


class FakeQuery:
    """A query as a queryable's handler sees it; its replies go straight back to the caller."""

    def __init__(self, key: str, payload: bytes | None, replies: list[FakeReply], zid: str = FAKE_ZID) -> None:
        self.key_expr = key
        self._id = FakeId(zid)
        self.selector = key
        self.parameters = ""
        self.payload = None if payload is None else zenoh.ZBytes(payload)
        self._replies = replies
        self.dropped = False

    def reply(self, key, payload, **kw) -> None:
        self._replies.append(FakeReply(ok=FakeSample(str(key), zenoh.ZBytes(bytes(payload))), replier_id=self._id))

    def reply_err(self, payload, **kw) -> None:
        self._replies.append(
            FakeReply(err=FakeSample(self.key_expr, zenoh.ZBytes(bytes(payload))), replier_id=self._id)
        )

    def drop(self) -> None:
        self.dropped = True


class _Entity:
    """A declared subscriber, queryable, publisher or token: ``undeclare()`` removes it."""

    def __init__(self, table: list | None = None, key: str = "", handler: Callable | None = None, on_undeclare=None):
        self.table, self.key, self.handler, self._on_undeclare = table, key, handler, on_undeclare
        if table is not None:
            table.append(self)

    def undeclare(self) -> None:
        if self.table is not None and self in self.table:
            self.table.remove(self)
            if self._on_undeclare is not None:
                self._on_undeclare(self)


class _Publisher(_Entity):
    def __init__(self, session: FakeSession, key: str) -> None:
        super().__init__()
        self.session, self.key = session, key

    def put(self, payload, **kw) -> None:
        self.session.put(self.key, payload)

    def delete(self, **kw) -> None:
        self.session.delete(self.key)

    # The fake session keeps every put (``last``), so it always counts as a listener.
    matching_status = True

    def declare_matching_listener(self, handler) -> _Matcher:
        return _Matcher()


class _Matcher:
    """A publisher's matching listener in the fake session: never reports a change."""

    def undeclare(self) -> None:
        pass


def _callable(handler) -> tuple[Callable, Callable | None]:
    """A plain callable, or a ``zenoh.handlers.Callback`` (its callback and its drop)."""
    if isinstance(handler, zenoh.handlers.Callback):
        return handler.callback, handler.drop
    return handler, None


class _Liveliness:
    def __init__(self, session: FakeSession) -> None:
        self.s = session

    def declare_token(self, key) -> _Entity:
        key = str(key)
        self.s.tokens.append(key)
        gone = lambda t: self.s._deliver(self.s._live_subs, t.key, b"", _DELETE)  # noqa: E731
        tok = _Entity(self.s._tokens, key, on_undeclare=gone)
        self.s._deliver(self.s._live_subs, key, b"", _PUT)
        return tok

    def declare_subscriber(self, key, handler, *, history: bool = False, **kw) -> _Entity:
        fn, _ = _callable(handler)
        sub = _Entity(self.s._live_subs, str(key), fn)
        if history and not self.s.silent:
            for t in list(self.s._tokens):
                if _intersects(sub.key, t.key):
                    fn(FakeSample(t.key, zenoh.ZBytes(b""), _PUT))
        return sub

    def get(self, key, handler=None, **kw):
        """The tokens alive on ``key``, as replies (a list when no handler is given)."""
        alive = [t.key for t in self.s._tokens if _intersects(str(key), t.key)]
        replies = [FakeReply(ok=FakeSample(k, zenoh.ZBytes(b""))) for k in alive]
        return self.s._answer(replies, handler)


class _Info:
    def zid(self) -> str:
        return FAKE_ZID


class FakeSession:
    """An in-memory Zenoh session; see the module docstring."""

    def __init__(self, *, silent: bool = False) -> None:
        self.silent = silent
        self.tokens: list[str] = []  # every liveliness token ever declared, in order
        self.last: dict[str, bytes] = {}  # the last payload put on each key
        self.closed = False
        self._subs: list[_Entity] = []
        self._queryables: list[_Entity] = []
        self._tokens: list[_Entity] = []
        self._live_subs: list[_Entity] = []
        self._lock = threading.RLock()

    # ------------------------------------------------------------------ pub/sub
    def _deliver(self, table: list[_Entity], key: str, payload: bytes, kind) -> None:
        if self.silent:
            return
        with self._lock:
            targets = [e for e in table if _intersects(e.key, key)]
        for e in targets:
            e.handler(FakeSample(key, zenoh.ZBytes(payload), kind))

    def put(self, key, payload, **kw) -> None:
        key, payload = str(key), bytes(payload)
        self.last[key] = payload
        self._deliver(self._subs, key, payload, _PUT)

    def delete(self, key, **kw) -> None:
        self.last.pop(str(key), None)
        self._deliver(self._subs, str(key), b"", _DELETE)

    def declare_publisher(self, key, **kw) -> _Publisher:
        return _Publisher(self, str(key))

    def declare_subscriber(self, key, handler, **kw) -> _Entity:
        return _Entity(self._subs, str(key), _callable(handler)[0])

    # ------------------------------------------------------------------ queries
    def declare_queryable(self, key, handler, **kw) -> _Entity:
        return _Entity(self._queryables, str(key), _callable(handler)[0])

    def _answer(self, replies: list[FakeReply], handler):
        if self.silent:
            replies = []
        if handler is None:
            return replies
        fn, done = _callable(handler)
        for r in replies:
            fn(r)
        if done is not None:
            done()
        return None

    def get(self, selector, handler=None, *, payload=None, **kw):
        """Ask every matching queryable; replies are collected synchronously, then handed to
        ``handler`` (a callable or a ``zenoh.handlers.Callback``, whose drop ends the query), or
        returned as a list when no handler is given. No queryable: no reply (as a timeout)."""
        key = str(selector).split("?", 1)[0]
        replies: list[FakeReply] = []
        with self._lock:
            targets = [q for q in self._queryables if _intersects(q.key, key)]
        for q in targets:
            q.handler(FakeQuery(key, None if payload is None else bytes(payload), replies))
        return self._answer(replies, handler)

    def liveliness(self) -> _Liveliness:
        return _Liveliness(self)

    @property
    def info(self) -> _Info:
        return _Info()

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        self.closed = True

    def is_closed(self) -> bool:
        return self.closed

    def __enter__(self) -> FakeSession:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---------------------------------------------------------------------------- the driver's server
@dataclass
class FakeServer:
    """What a driver sees of its device server; everything it does is recorded (addresses as text).

    ``sent``: ``(addr, msg)`` commands to other devices; ``published``: ``(addr, msg)`` data;
    ``events``: event maps; ``requests``: ``(addr, op, args)`` RPCs (answer them by calling the
    driver's ``on_reply``); ``warnings``: the texts of rate-limited warnings.
    """

    sent: list[tuple[str, Any]] = field(default_factory=list)
    published: list[tuple[str, Any]] = field(default_factory=list)
    events: list[Any] = field(default_factory=list)
    requests: list[tuple[str, str, dict | None]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    shared: dict = field(default_factory=dict)
    unheard: set = field(default_factory=set)  # devices (as text) whose data nobody subscribes to

    def listened(self, addr) -> bool:
        return str(addr) not in self.unheard

    def listen_group(self, addrs):
        """As the server's: ``any`` is true while one of ``addrs`` is not in :attr:`unheard`."""
        server, names = self, [str(a) for a in addrs]

        class _Group:
            @property
            def any(self) -> bool:
                return any(n not in server.unheard for n in names)

        return _Group()

    def send(self, addr, msg) -> None:
        self.sent.append((str(addr), msg))

    def publish(self, addr, msg) -> None:
        self.published.append((str(addr), msg))

    def publish_each(self, addrs, msg) -> None:
        for addr in addrs:
            self.published.append((str(addr), msg))

    def publish_event(self, addr, msg) -> None:
        self.events.append(msg)

    def request(self, driver, addr, op, args, timeout) -> None:
        self.requests.append((str(addr), op, args))

    def _warn(self, key, text, level=None) -> None:  # the server's rate-limited log
        self.warnings.append(text)

    def requested(self) -> list[tuple[str, str]]:
        """``(addr, op)`` of every request, in order."""
        return [(a, op) for a, op, _ in self.requests]

    def data(self) -> list[Any]:
        """The published messages, without their addresses."""
        return [m for _, m in self.published]


# ---------------------------------------------------------------------------- the client's fabric
class InlineDispatcher:
    """Runs a listener at once, on the caller's thread (``Fabric`` queues it on its own thread)."""

    def submit(self, fn, *args) -> None:
        fn(*args)


class FakeFabric:
    """Client-side fabric for device proxies: see the module docstring."""

    def __init__(self, session: FakeSession | None = None) -> None:
        self.session = session or FakeSession()
        self.dispatcher = InlineDispatcher()
        self._proxies: dict = {}
        self.geometry: dict[DeviceAddr, dict] = {}
        self.sent: list[tuple[DeviceAddr, object]] = []
        self.rpcs: list[tuple[DeviceAddr, str, dict]] = []

    def callback(self, fn):  # as Fabric.callback without direct_callbacks
        return fn

    def device(self, cls, text: str, geometry: dict | None = None):
        """A proxy of class ``cls`` for ``text`` (``node:iface:idx``); ``geometry`` answers its describe."""
        a = parse_device(text)
        p = cls(self, a)
        self._proxies[a] = p
        if geometry is not None:
            self.geometry[a] = geometry
        return p

    def push(self, dev, msg) -> None:
        """A data sample of ``dev`` arriving from the network."""
        self.session.put(keys.data_key(dev.addr), msgs.encode(msg))

    def rpc(self, addr, op, args=None, *, timeout=5.0):
        self.rpcs.append((addr, op, dict(args or {})))
        if op == "describe":
            if addr not in self.geometry:
                raise RpcError(ErrorCode.TIMEOUT, "no reply", keys.rpc_key(addr, op))
            return msgs.Describe(addr.node, addr.interface, addr.index, "fake", 10.0, self.geometry[addr]).to_dict()
        return {"ok": True}

    def send(self, addr, msg) -> None:
        self.sent.append((addr, msg))

    def hold(self, addr, msg) -> None:  # as Fabric.hold: sent now (the re-sends are not modelled)
        self.sent.append((addr, msg))

    def release(self, addr) -> None:
        pass

    def _forget(self, addr) -> None:
        self._proxies.pop(addr, None)

    def velocities(self) -> list[tuple[float, float]]:
        return [(m.v, m.w) for a, m in self.sent if isinstance(m, VelocityCmd)]
