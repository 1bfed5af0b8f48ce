"""Agent services: information channels on the key space ``svc/<service>/<sender_id>``.

Thesis 3.6.1 and figure 3.10: every service "represents a dedicated information channel", sends to
all subscribers, and "any subscriber can filter received messages". Here a service is a Zenoh key
space: an agent publishes on ``svc/<service>/<its id>`` and every subscriber of ``svc/<service>/*``
receives the message, filtered on the subscriber side. Every message carries ``sender``,
``conversation`` (an id that replies repeat) and ``time`` (seconds since the epoch) next to its
body, as one msgpack map whose schema is defined here and validated on decode (STYLE rule 4): a
malformed sample is dropped with a rate-limited warning and never reaches an agent.

Receivers check what they can (``docs/security.md``, "Open fabric"): a message whose envelope ``sender``
is not the sender chunk of its key (``svc/<service>/<sender>``) is a forgery on an open fabric -- an
agent publishes only under its own id -- so it is dropped, counted in :attr:`Services.forged` (and in
``dropped``) and reported by one rate-limited warning that names the key and the claimed sender.

Bundles (for crowds): a host that bundles a service's cell broadcasts (:attr:`Services.bundled`)
holds each of them for up to :attr:`Services.bundle_window` seconds and puts all it holds as one
sample on ``svc/<service>/@bundle/<zid>`` (its Zenoh session's id; :func:`encode_bundle`): columns
of cells, senders, conversations, times and bodies. ``@bundle`` is a verbatim chunk, so no ``*``
or ``**`` subscriber sees bundles; receivers that take them subscribe to :func:`bundle_key`
(:class:`BundleSubscription`; :class:`agents.cellsub.CellSubscription` with ``bundles``). A 1000-robot
swarm's hosts put ~2,000 broadcasts a second: each a Zenoh sample that every receiving session
routes (a route computed per sample, its cost growing with the declarations the session knows),
hands to a thread and decodes. Bundled, they are ~200 samples. What a bundle cannot carry is the
key's check of the sender: its entries name senders the key does not, so it is for open fabrics
(the secured profile's access rules allow no bundle key).

``hello`` is the discovery service: every running agent answers queries on ``svc/hello/<agent_id>``
with its id, class, robot and capabilities; :meth:`Services.who_is_there` collects the answers.

Zenoh delivers samples and queries on its own threads; the callbacks here only decode and hand the
result to the host's asyncio loop with ``loop.call_soon_threadsafe`` (STYLE rule 2).
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import threading
import time
import uuid
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import zenoh

from rsal.keys import SVC_PREFIX, check_name, is_name, service_key
from rsal.msgs import MessageError, decode_map, encode, get_bool, get_float, get_str

if TYPE_CHECKING:
    from .cellsub import CellSubscription
    from .runtime import AgentHost

__all__ = [
    "SVC_PREFIX",
    "HELLO",
    "Body",
    "SendPosition",
    "NewGoal",
    "Hello",
    "Outcome",
    "Message",
    "SCHEMAS",
    "Filter",
    "Subscription",
    "Services",
    "match",
    "service_key",
    "check_name",
    "decode_message",
    "encode_message",
    "SenderMismatch",
    "BUNDLE",
    "bundle_key",
    "encode_bundle",
    "decode_bundle",
    "BundleSubscription",
]

log = logging.getLogger(__name__)

HELLO = "hello"
_ENVELOPE = ("sender", "conversation", "time")
#: the verbatim key chunk of bundles: ``svc/<service>/@bundle/<zid>``
BUNDLE = "@bundle"
_BUNDLE_COLUMNS = ("cells", "senders", "conversations", "times", "bodies")


# ---------------------------------------------------------------------------- message bodies
class Body:
    """Base of service message bodies: a frozen dataclass with ``to_dict``/``from_dict``."""

    SERVICE: ClassVar[str] = ""

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class SendPosition(Body):
    """``send_position``: the pose of ``robot`` (x, y in m, yaw in rad) in ``frame`` (e.g. ``map``,
    ``odom``). The thesis's SendPositionService, which FollowAgent and MasterAgent subscribe to."""

    robot: str
    x: float
    y: float
    yaw: float
    frame: str = "map"

    SERVICE: ClassVar[str] = "send_position"

    @classmethod
    def from_dict(cls, m: dict) -> SendPosition:
        return cls(
            get_str(m, "robot"),
            get_float(m, "x"),
            get_float(m, "y"),
            get_float(m, "yaw"),
            get_str(m, "frame", "map"),
        )


@dataclass(frozen=True)
class NewGoal(Body):
    """``new_goal``: agent ``to`` should drive its robot to ``x``, ``y`` (m), ``yaw`` (rad) in the map
    frame. The thesis's NewGoalService (DispersionAgent to NavAgents)."""

    to: str
    x: float
    y: float
    yaw: float = 0.0

    SERVICE: ClassVar[str] = "new_goal"

    @classmethod
    def from_dict(cls, m: dict) -> NewGoal:
        return cls(get_str(m, "to"), get_float(m, "x"), get_float(m, "y"), get_float(m, "yaw", 0.0))


@dataclass(frozen=True)
class Hello(Body):
    """``hello``: who an agent is: its ``id``, agent ``cls`` (class name), the ``robot`` it controls
    (``""`` for none) and its ``capabilities`` (service names, skills)."""

    id: str
    cls: str
    robot: str = ""
    capabilities: tuple[str, ...] = ()

    SERVICE: ClassVar[str] = HELLO

    @classmethod
    def from_dict(cls, m: dict) -> Hello:
        caps = m.get("capabilities", [])
        if not isinstance(caps, list) or not all(isinstance(c, str) for c in caps):
            raise MessageError("field 'capabilities' must be a list of strings")
        return cls(get_str(m, "id"), get_str(m, "cls"), get_str(m, "robot", ""), tuple(caps))


@dataclass(frozen=True)
class Outcome(Body):
    """``outcome``: something a scenario counts happened — ``event`` (e.g. ``caught``, ``delivered``,
    ``arrived``, ``verdict``) about ``subject`` (the prey robot, the blob, the robot), with one
    human-readable line ``text``. ``ok`` false reports a failure; ``final`` true ends the scenario
    run with ``ok`` as its result (``rsal run`` listens on ``svc/outcome/*``). ``at`` (x, y in m,
    map frame; optional, omitted on the wire when absent) is the place the claim is about -- the
    goal an ``arrived`` reached, the target of an ``assigned`` -- so a judge can check it against
    ground truth (:mod:`agents.verdict`)."""

    event: str
    subject: str
    text: str
    ok: bool = True
    final: bool = False
    at: tuple[float, float] | None = None

    SERVICE: ClassVar[str] = "outcome"

    def to_dict(self) -> dict:
        d = super().to_dict()
        if self.at is None:
            del d["at"]
        return d

    @classmethod
    def from_dict(cls, m: dict) -> Outcome:
        at = m.get("at")
        if at is not None:
            ok = isinstance(at, (list, tuple)) and len(at) == 2
            if not ok or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in at):
                raise MessageError("field 'at' must be [x, y] (metres, map frame)")
            at = (float(at[0]), float(at[1]))
        return cls(
            get_str(m, "event"),
            get_str(m, "subject"),
            get_str(m, "text"),
            get_bool(m, "ok", True),
            get_bool(m, "final", False),
            at,
        )


SCHEMAS: dict[str, type] = {b.SERVICE: b for b in (SendPosition, NewGoal, Hello, Outcome)}


@dataclass(frozen=True)
class Message:
    """One service message: the envelope and its ``body`` (a :class:`Body` for a service in
    :data:`SCHEMAS`, else the remaining fields as a dict)."""

    service: str
    sender: str
    conversation: str
    time: float
    body: Any = field(default_factory=dict)


def encode_message(sender: str, body: Any, conversation: str, t: float) -> bytes:
    d = body.to_dict() if hasattr(body, "to_dict") else dict(body)
    clash = [k for k in _ENVELOPE if k in d]
    if clash:
        raise ValueError(f"message body must not use the envelope field(s) {', '.join(clash)}")
    return encode({"sender": sender, "conversation": conversation, "time": t, **d})


class SenderMismatch(MessageError):
    """The envelope's ``sender`` is not the key's sender chunk: a forged (or misrouted) message."""

    def __init__(self, claimed: str, key_sender: str):
        super().__init__(f"field 'sender' = {claimed!r} does not match the key's sender {key_sender!r}")
        self.claimed = claimed
        self.key_sender = key_sender


def decode_message(service: str, key_sender: str, data: bytes) -> Message:
    """Validate one sample of ``svc/<service>/<key_sender>``; raises :class:`MessageError`
    (:class:`SenderMismatch` when the envelope claims another sender than the key)."""
    m = decode_map(data)
    sender = get_str(m, "sender")
    if sender != key_sender:
        raise SenderMismatch(sender, key_sender)
    conversation = get_str(m, "conversation")
    t = get_float(m, "time", lo=0.0)
    rest = {k: v for k, v in m.items() if k not in _ENVELOPE}
    schema = SCHEMAS.get(service)
    body = schema.from_dict(rest) if schema is not None else rest
    return Message(service, sender, conversation, t, body)


# ---------------------------------------------------------------------------- bundles
def bundle_key(service: str, zid: str = "*") -> str:
    """``svc/<service>/@bundle/<zid>`` (``*``: every session's bundles)."""
    check_name("service", service)
    return f"{SVC_PREFIX}/{service}/{BUNDLE}/{zid if zid == '*' else check_name('session id', zid)}"


def encode_bundle(entries: list[tuple[str, str, str, float, Any]]) -> bytes:
    """One bundle of cell broadcasts, each ``(cell, sender, conversation, time, body)``: a msgpack
    map of five equally long columns (``cells``, ``senders``, ``conversations``, ``times``,
    ``bodies``; a body as its ``to_dict``)."""
    return encode(
        {
            "cells": [e[0] for e in entries],
            "senders": [e[1] for e in entries],
            "conversations": [e[2] for e in entries],
            "times": [e[3] for e in entries],
            "bodies": [b.to_dict() if hasattr(b, "to_dict") else dict(b) for b in (e[4] for e in entries)],
        }
    )


def decode_bundle(service: str, data: bytes) -> tuple[list[tuple[str, Message]], list[str]]:
    """The ``(cell, message)`` entries of one bundle of ``service``, and a reason for each entry
    that failed validation (that entry is left out); raises :class:`MessageError` when the bundle
    itself is malformed (nothing of it is used)."""
    m = decode_map(data)
    cols = []
    for name in _BUNDLE_COLUMNS:
        v = m.get(name)
        if type(v) is not list:
            raise MessageError(f"field {name!r} must be a list, not {type(v).__name__}")
        cols.append(v)
    n = len(cols[0])
    if any(len(c) != n for c in cols):
        raise MessageError("fields " + ", ".join(map(repr, _BUNDLE_COLUMNS)) + " must be lists of one length")
    schema = SCHEMAS.get(service)
    out: list[tuple[str, Message]] = []
    bad: list[str] = []
    for cell, sender, conv, t, body in zip(*cols, strict=True):
        try:
            if not is_name(cell):
                raise MessageError(f"cell {cell!r} is not a key chunk")
            if not is_name(sender):
                raise MessageError(f"sender {sender!r} is not an agent id")
            if type(conv) is not str:
                raise MessageError(f"conversation {conv!r} is not a string")
            if not (type(t) is float and t >= 0.0 and t - t == 0.0):
                raise MessageError(f"time {t!r} is not a finite float >= 0")
            if type(body) is not dict:
                raise MessageError(f"body of {sender} is not a map")
            out.append((cell, Message(service, sender, conv, t, schema.from_dict(body) if schema else body)))
        except MessageError as e:
            bad.append(str(e))
    return out, bad


# ---------------------------------------------------------------------------- filters
Filter = Callable[[Message], bool]
Callback = Callable[[Message], Awaitable[None] | None]


def match(**fields: Any) -> Filter:
    """A filter accepting messages whose envelope or body fields equal the given values, e.g.
    ``match(robot="r1")`` or ``match(to="nav1")``; a value may also be a set of accepted values."""

    def accept(msg: Message) -> bool:
        for k, want in fields.items():
            if k in _ENVELOPE:
                v = getattr(msg, k)
            elif isinstance(msg.body, dict):
                v = msg.body.get(k)
            else:
                v = getattr(msg.body, k, None)
            if not (v in want if isinstance(want, (set, frozenset)) else v == want):
                return False
        return True

    return accept


def _undeclare(entity: Any) -> None:
    try:
        entity.undeclare()
    except Exception:  # the session may already be closed
        pass


class _RateLimited:
    """Warn at most once per ``interval`` seconds per topic; counts what it held back."""

    def __init__(self, interval: float = 5.0):
        self.interval = interval
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def warn(self, topic: str, text: str) -> None:
        now = time.monotonic()
        if now - self._last.get(topic, -1e9) >= self.interval:
            held = self._held.pop(topic, 0)
            self._last[topic] = now
            log.warning("%s%s", text, f" ({held} similar message(s) suppressed)" if held else "")
        else:
            self._held[topic] = self._held.get(topic, 0) + 1


class Subscription:
    """A subscriber to one service; :meth:`close` undeclares it (the owning agent does on kill).
    ``keyexpr`` narrows or widens what it subscribes to (default ``svc/<service>/*``) and
    ``accept_key(key)``, if given, turns a sample away by its key on Zenoh's thread, before it is
    decoded (counted in :attr:`skipped`). With ``arrival``, ``callback(msg, t)`` also gets the wall
    time ``t`` the sample reached this subscriber (on Zenoh's thread: when the session received it,
    however long the host's loop then took to serve it). With ``on_thread`` the callback runs on
    Zenoh's thread itself, not the host's loop (it must be thread-safe and quick: e.g. append to a
    queue that the agent drains), which spares a busy receiver a loop wake-up per message. With
    ``remote_only`` it receives only other sessions' samples (``zenoh.Locality.REMOTE``)."""

    def __init__(
        self,
        services: Services,
        service: str,
        callback: Callback,
        flt: Filter | None,
        owner: str,
        keyexpr: str | None = None,
        accept_key: Callable[[str], bool] | None = None,
        *,
        arrival: bool = False,
        on_thread: bool = False,
        remote_only: bool = False,
    ):
        self.service = service
        self.owner = owner
        self._services = services
        self._callback = callback
        self._filter = flt
        self.received = 0  # messages passed to the callback
        self.skipped = 0  # samples ``accept_key`` turned away before decoding
        self._accept_key = accept_key
        self._arrival = arrival
        self._on_thread = on_thread
        self.keyexpr = keyexpr or service_key(service)
        # remote_only: this session's own puts are not routed to it at all (no callback to reject them)
        origin = zenoh.Locality.REMOTE if remote_only else zenoh.Locality.ANY
        self._sub = services.session.declare_subscriber(self.keyexpr, self._on_sample, allowed_origin=origin)
        self.closed = False

    def _on_sample(self, sample: zenoh.Sample) -> None:  # a Zenoh thread: decode, then hand over
        t = time.time() if self._arrival else None
        key = str(sample.key_expr)
        if self._accept_key is not None and not self._accept_key(key):
            self.skipped += 1
            return
        try:
            msg = decode_message(self.service, key.rsplit("/", 1)[-1], sample.payload.to_bytes())
        except MessageError as e:
            self._services.reject(key, e)
            return
        if self._on_thread:
            self._deliver(msg, t)
        else:
            self._services.call_soon(self._deliver, msg, t)

    def _deliver(self, msg: Message, t: float | None = None) -> None:  # the host's loop (or on_thread)
        if self.closed:
            return
        try:
            if self._filter is not None and not self._filter(msg):
                return
            self.received += 1
            out = self._callback(msg) if t is None else self._callback(msg, t)
            if inspect.isawaitable(out):
                if self._on_thread:  # no loop here to run it on
                    getattr(out, "close", lambda: None)()
                    raise TypeError("an on_thread callback must be a plain function, not a coroutine")
                self._services.host.spawn(out, f"{self.owner}: {self.service} callback")
        except Exception:
            log.exception("%s: callback for %s from %s failed", self.owner, self.service, msg.sender)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            _undeclare(self._sub)


class BundleSubscription:
    """A subscriber to the bundles of one service (``svc/<service>/@bundle/*``): ``callback(entries,
    t)`` gets each valid bundle's ``(cell, message)`` entries and the wall time ``t`` it arrived, on
    the host's loop or, with ``on_thread``, on Zenoh's thread (thread-safe and quick there). A
    malformed bundle, or entry, is dropped, counted in the host's ``dropped`` and warned about
    (rate-limited). ``remote_only``: other sessions' bundles only. :meth:`close` undeclares it."""

    def __init__(
        self,
        services: Services,
        service: str,
        callback: Callable[[list[tuple[str, Message]], float], None],
        owner: str,
        *,
        on_thread: bool = False,
        remote_only: bool = False,
    ):
        self.service, self.owner = service, owner
        self._services = services
        self._callback = callback
        self._on_thread = on_thread
        self.bundles = 0  # bundles received
        self.entries = 0  # their valid entries
        self.keyexpr = bundle_key(service)
        origin = zenoh.Locality.REMOTE if remote_only else zenoh.Locality.ANY
        self._sub = services.session.declare_subscriber(self.keyexpr, self._on_sample, allowed_origin=origin)
        self.closed = False

    def _on_sample(self, sample: zenoh.Sample) -> None:  # a Zenoh thread
        t = time.time()
        key = str(sample.key_expr)
        try:
            entries, bad = decode_bundle(self.service, sample.payload.to_bytes())
        except MessageError as e:
            self._services.reject(key, e)
            return
        for reason in bad:
            self._services.reject(key, MessageError(f"bundle entry dropped: {reason}"))
        self.bundles += 1
        self.entries += len(entries)
        if self._on_thread:
            self._deliver(entries, t)
        else:
            self._services.call_soon(self._deliver, entries, t)

    def _deliver(self, entries: list[tuple[str, Message]], t: float) -> None:
        if self.closed:
            return
        try:
            self._callback(entries, t)
        except Exception:
            log.exception("%s: bundle callback for %s failed", self.owner, self.service)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            _undeclare(self._sub)


class Services:
    """Publishing, subscribing and ``hello`` for the agents of one :class:`AgentHost`."""

    def __init__(self, host: AgentHost):
        self.host = host
        self.session: zenoh.Session = host.session
        self.dropped = 0  # samples that never reached an agent (malformed or forged)
        self.forged = 0  # of which: envelope sender != the key's sender chunk
        self._warn = _RateLimited()
        # cell broadcasts: one declared publisher per (service, sender), re-declared when the cell changes
        self._pubs: dict[tuple[str, str], tuple[str, zenoh.Publisher]] = {}
        self._pub_lock = threading.RLock()
        self.publishers_declared = 0  # publishers declared for cell broadcasts so far
        self.cache_publishers = True  # false: every cell broadcast a Session.put (for comparison)
        # cell subscriptions served in process (CellSubscription loopback): a broadcast of this host
        # reaches them as the Message it was, not through Zenoh's local routing, a thread and a decode
        self._loopback: dict[str, list[CellSubscription]] = {}
        self.local_senders: set[str] = set()  # senders whose cell broadcasts those subscriptions had so
        # bundles: the services whose cell broadcasts this host bundles, what it holds of each
        self.bundled: set[str] = set()
        self.bundle_window = 0.01  # seconds a bundled broadcast waits at most for others to join it
        self._held: dict[str, list[tuple[str, str, str, float, Any]]] = {}
        self._bundle_pubs: dict[str, zenoh.Publisher] = {}
        self._flush_due = False
        self._bundle_cond = threading.Condition()
        self._flusher: threading.Thread | None = None
        self._bundles_closed = False
        self.bundles_sent = 0  # bundles put so far
        self.bundled_messages = 0  # the broadcasts they carried
        # calls from Zenoh's threads for the loop, served in batches (call_soon)
        self._soon: list[tuple[Callable, tuple]] = []
        self._soon_lock = threading.Lock()
        self._soon_scheduled = False

    def warn(self, topic: str, text: str) -> None:
        self._warn.warn(topic, text)

    def reject(self, key: str, e: MessageError) -> None:
        """Count a sample on ``key`` that failed :func:`decode_message` and warn (rate-limited)."""
        self.dropped += 1
        if isinstance(e, SenderMismatch):
            self.forged += 1
            self.warn(
                f"forged:{key}",
                f"dropped a message on {key} that claims sender {e.claimed!r} (only {e.key_sender!r} "
                f"publishes there): a forgery or a misconfigured peer",
            )
        else:
            self.warn(f"bad:{key}", f"dropped a malformed message on {key}: {e}")

    def call_soon(self, fn: Callable, *args: Any) -> None:
        """Run ``fn(*args)`` on the host's loop (safe from any thread; ignored once the loop closed).

        Calls are queued in order and served in batches: only the first call of a batch wakes the
        loop (``call_soon_threadsafe`` writes to the loop's self-pipe), so a burst of samples from
        Zenoh's threads costs one wake-up, not one each."""
        with self._soon_lock:
            self._soon.append((fn, args))
            if self._soon_scheduled:
                return
            self._soon_scheduled = True
        try:
            self.host.loop.call_soon_threadsafe(self._run_soon)
        except RuntimeError:  # loop closed during shutdown
            with self._soon_lock:
                self._soon.clear()
                self._soon_scheduled = False

    def _run_soon(self) -> None:  # the host's loop
        with self._soon_lock:
            batch, self._soon = self._soon, []
            self._soon_scheduled = False  # calls queued from now on wake the loop again
        for fn, args in batch:
            try:
                fn(*args)
            except Exception:
                log.exception("%s: a call handed to the loop failed", fn)

    def publish(
        self, service: str, body: Any, *, sender: str, conversation: str | None = None, cell: str | None = None
    ) -> str:
        """Put ``body`` on ``svc/<service>/<sender>``, or with ``cell`` on
        ``svc/<service>/<cell>/<sender>`` (:mod:`agents.cells`); returns the conversation id used.

        A cell broadcast goes through a declared Zenoh publisher, one per (service, sender), kept
        while the sender stays in that cell and re-declared on the new key when it moves: a put on
        a declared publisher reuses its cached route (12 us against 45 us for ``Session.put`` with
        hundreds of cell subscribers in the session, docs/benchmarks.md). :meth:`release` undeclares
        them (the host does when the agent ends). Same keys and payloads on the wire."""
        check_name("service", service)
        check_name("agent id", sender)
        schema = SCHEMAS.get(service)
        if schema is not None and not isinstance(body, schema):
            raise TypeError(f"service {service!r} carries {schema.__name__}, not {type(body).__name__}")
        conv = conversation or uuid.uuid4().hex[:16]
        if cell is None:
            self.session.put(service_key(service, sender), encode_message(sender, body, conv, time.time()))
            return conv
        key = f"svc/{service}/{check_name('cell', cell)}/{sender}"
        t = time.time()
        local = self._loopback.get(service)
        if local:
            self.local_senders.add(sender)  # before the put: its Zenoh copy is turned away by key
        if service in self.bundled:
            self._hold(service, (cell, sender, conv, t, body))
        elif not self.cache_publishers:
            payload = encode_message(sender, body, conv, t)
            self.session.put(key, payload)
        else:
            payload = encode_message(sender, body, conv, t)
            with self._pub_lock:
                held = self._pubs.get((service, sender))
                if held is None or held[0] != key:
                    if held is not None:
                        _undeclare(held[1])  # the sender left that cell
                    held = self._pubs[(service, sender)] = (key, self.session.declare_publisher(key))
                    self.publishers_declared += 1
                held[1].put(payload)
        if local:
            msg = Message(service, sender, conv, t, body)
            for sub in tuple(local):
                if self._on_loop():
                    sub.local(msg, cell)
                else:
                    self.call_soon(sub.local, msg, cell)
        return conv

    def _hold(self, service: str, entry: tuple[str, str, str, float, Any]) -> None:
        """Keep a bundled broadcast for the next :meth:`flush_bundles`, which the host's bundling
        thread runs ``bundle_window`` s after the first one held (a thread, not the loop: a loop
        busy with a crowd's step would hold the bundle for as long)."""
        with self._bundle_cond:
            self._held.setdefault(service, []).append(entry)
            closed = self._bundles_closed
            if not self._flush_due and not closed:
                self._flush_due = True
                if self._flusher is None:
                    self._flusher = threading.Thread(target=self._bundling, name="bundles", daemon=True)
                    self._flusher.start()
                self._bundle_cond.notify()
        if closed:  # the host is ending: no thread waits any more
            self.flush_bundles()

    def _bundling(self) -> None:  # the bundling thread
        while True:
            with self._bundle_cond:
                while not self._flush_due and not self._bundles_closed:
                    self._bundle_cond.wait()
                if self._bundles_closed:
                    return
            time.sleep(self.bundle_window)
            self.flush_bundles()

    def flush_bundles(self) -> None:
        """Put what is held of every bundled service as one sample each (:func:`encode_bundle`)."""
        with self._bundle_cond:
            held, self._held = self._held, {}
            self._flush_due = False
        with self._pub_lock:
            for service, entries in held.items():
                if not entries:
                    continue
                pub = self._bundle_pubs.get(service)
                if pub is None:
                    zid = str(self.session.info.zid())
                    pub = self._bundle_pubs[service] = self.session.declare_publisher(bundle_key(service, zid))
                try:
                    pub.put(encode_bundle(entries))
                except Exception as e:  # a closing session: the broadcasts are lost, say so once
                    n = len(entries)
                    self.warn(f"bundle:{service}", f"could not put a bundle of {n} {service} broadcast(s): {e}")
                    continue
                self.bundles_sent += 1
                self.bundled_messages += len(entries)

    def bundle(self, service: str, window: float | None = None) -> None:
        """Bundle this host's cell broadcasts of ``service`` from now on (module docstring);
        ``window``: the most seconds one waits for others (default :attr:`bundle_window`)."""
        check_name("service", service)
        if window is not None:
            if isinstance(window, bool) or not isinstance(window, (int, float)) or not 0 <= window <= 1:
                raise ValueError(f"bundle window {window!r} must be a number of seconds from 0 to 1")
            self.bundle_window = float(window)
        self.bundled.add(service)

    def _on_loop(self) -> bool:
        try:
            return asyncio.get_running_loop() is self.host.loop
        except RuntimeError:
            return False

    def add_loopback(self, service: str, sub: CellSubscription) -> None:
        """Hand ``sub`` this host's own broadcasts of ``service`` in process (it turns their Zenoh
        copies away)."""
        self._loopback.setdefault(service, []).append(sub)

    def remove_loopback(self, service: str, sub: CellSubscription) -> None:
        subs = self._loopback.get(service, [])
        if sub in subs:
            subs.remove(sub)

    def publishers(self, sender: str | None = None) -> dict[tuple[str, str], str]:
        """The cell broadcasts' declared publishers: (service, sender) -> the key each puts on."""
        with self._pub_lock:
            return {k: key for k, (key, _p) in self._pubs.items() if sender is None or k[1] == sender}

    def release(self, sender: str | None = None) -> None:
        """Undeclare the cell broadcasts' publishers of ``sender`` (of every sender: None); the
        host does on an agent's end and on its own."""
        with self._pub_lock:
            gone = [k for k in self._pubs if sender is None or k[1] == sender]
            for k in gone:
                _undeclare(self._pubs.pop(k)[1])
        if sender is None:  # the host's end: what is held goes out first
            with self._bundle_cond:
                self._bundles_closed = True
                self._bundle_cond.notify()
            self.flush_bundles()
            with self._pub_lock:
                for pub in self._bundle_pubs.values():
                    _undeclare(pub)
                self._bundle_pubs.clear()

    def subscribe(
        self, service: str, callback: Callback, flt: Filter | None = None, *, owner: str = ""
    ) -> Subscription:
        """Receive every valid message on ``svc/<service>/*`` that ``flt`` accepts; ``callback`` (plain
        or ``async``) runs on the host's loop."""
        check_name("service", service)
        return Subscription(self, service, callback, flt, owner)

    def subscribe_cells(
        self,
        service: str,
        callback: Callback,
        flt: Filter | None = None,
        *,
        owner: str = "",
        wildcard_above: int | None = None,
        loopback: bool = False,
        bundles: bool = False,
    ) -> CellSubscription:
        """Receive the messages on ``svc/<service>/<cell>/*`` of the cells given to
        :meth:`agents.cellsub.CellSubscription.watch` (none at first): a subscriber per cell, or one
        on ``svc/<service>/*/*`` filtered by cell while more than ``wildcard_above`` cells are
        watched (default :data:`agents.cellsub.DEFAULT_WILDCARD_ABOVE`). ``loopback``: this host's own
        broadcasts reach it in process (:class:`agents.cellsub.CellSubscription`); ``bundles``: other
        hosts' bundles of the service too."""
        from .cellsub import DEFAULT_WILDCARD_ABOVE, CellSubscription

        check_name("service", service)
        above = DEFAULT_WILDCARD_ABOVE if wildcard_above is None else wildcard_above
        return CellSubscription(
            self, service, callback, flt, owner, wildcard_above=above, loopback=loopback, bundles=bundles
        )

    # ------------------------------------------------------------------ hello
    def declare_hello(self, hello: Hello) -> zenoh.Queryable:
        key = service_key(HELLO, hello.id)
        # run on Zenoh's own thread (it only queues the answer for the loop): zenoh-python would
        # otherwise start a Python thread for each queryable -- 500 idle threads in a swarm host
        handler = zenoh.handlers.Callback(lambda q: self.call_soon(self._answer_hello, q, key, hello), indirect=False)
        return self.session.declare_queryable(key, handler)

    def _answer_hello(self, query: zenoh.Query, key: str, hello: Hello) -> None:
        try:
            query.reply(key, encode_message(hello.id, hello, uuid.uuid4().hex[:16], time.time()))
        except Exception as e:  # a closed query or session must not stop the host
            self.warn(f"hello:{key}", f"could not answer hello on {key}: {type(e).__name__}: {e}")
        finally:
            try:
                query.drop()
            except Exception:
                pass

    async def who_is_there(self, timeout: float = 1.0) -> list[Hello]:
        """Query ``svc/hello/*`` and return every valid answer (sorted by id) within ``timeout`` s."""
        loop = self.host.loop
        answers: list[Hello] = []
        done: asyncio.Future = loop.create_future()

        def on_reply(reply: zenoh.Reply) -> None:  # a Zenoh thread
            if reply.ok is None:
                return
            key = str(reply.ok.key_expr)
            try:
                msg = decode_message(HELLO, key.rsplit("/", 1)[-1], reply.ok.payload.to_bytes())
            except MessageError as e:
                self.reject(key, e)
                return
            self.call_soon(answers.append, msg.body)

        def on_done() -> None:
            self.call_soon(lambda: done.done() or done.set_result(None))

        self.session.get(service_key(HELLO), zenoh.handlers.Callback(on_reply, on_done), timeout=timeout)
        await done
        return sorted(answers, key=lambda h: h.id)
