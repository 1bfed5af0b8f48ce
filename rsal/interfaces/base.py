"""The building blocks of an interface module: the :class:`Interface` record and the
:class:`Device` base proxy (thesis 3.6.2.3 "Device").

An interface module (``rsal/interfaces/<name>.py``) holds one Player interface: its wire messages
(``docs/protocol.md``), its typed geometry where it has one, its client proxy (a :class:`Device`
subclass) and an :class:`Interface` record naming all of them, which the registry in
:mod:`rsal.interfaces` collects. Everything that needs to know an interface -- the key space's
interface list, the ``device()`` factory, the device server's typed decoding of ``cmd`` and of
driver inputs, the live view -- reads that record.

A proxy subscribes to its device's ``data`` (and ``event``) key and keeps the latest decoded
message: agents read values without waiting, as the thesis's device threads did, but fed by push
instead of polling. Listeners (``add_listener``) are called on the fabric's dispatcher thread with
each new message. Commands are fire-and-forget puts; long operations (gripper open/close) return
``concurrent.futures.Future`` objects that resolve when the device reports the new state.
A proxy whose device's liveliness token goes away is marked lost (``alive`` false, ``on_lost``
listeners called); it recovers by itself when the device comes back.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from .. import keys, msgs
from ..keys import DeviceAddr
from ..msgs import MessageError, decode_map

if TYPE_CHECKING:
    from ..client import Fabric

__all__ = ["Interface", "Device", "decode_as"]

log = logging.getLogger(__name__)
_monotonic = time.monotonic


class Device:
    """Base proxy: latest data, listeners, liveness, rpc and cmd."""

    data_type: Any = None  # msgs class used to decode data (None: plain dict)

    def __init__(self, fabric: Fabric, addr: DeviceAddr):
        self.fabric = fabric
        self.addr = addr
        self.alive = True
        self.latest: Any = None
        self.received_at = 0.0  # time.monotonic() of the latest data
        self.count = 0
        self._listeners: list[Callable[[Any], None]] = []
        self._inline_listeners: list[Callable[[Any], None]] = []
        self._event_listeners: list[Callable[[dict], None]] = []
        self._lost_listeners: list[Callable[[Device], None]] = []
        self._cond = threading.Condition()
        self._waiting = 0  # threads in wait_for_data: only then does new data need a notify
        self._bad = 0
        # The data path runs once per sample: bind what it calls once, here.
        dt = self.data_type
        if type(self)._decode is not Device._decode:  # a subclass decodes the map its own way
            self._from_bytes = lambda data: self._decode(decode_map(data))
        else:
            self._from_bytes = dt.from_bytes if dt is not None else decode_map
        self._has_after_data = type(self)._after_data is not Device._after_data
        s = fabric.session
        self._sub = s.declare_subscriber(keys.data_key(addr), fabric.callback(self._on_data))
        self._esub = s.declare_subscriber(keys.event_key(addr), fabric.callback(self._on_event))
        self._describe: msgs.Describe | None = None

    # ------------------------------------------------------------------ identity
    @property
    def node(self) -> str:
        return self.addr.node

    @property
    def interface(self) -> str:
        return self.addr.interface

    @property
    def index(self) -> int:
        return self.addr.index

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.addr} {'alive' if self.alive else 'lost'}>"

    # ------------------------------------------------------------------ inbound (Zenoh threads)
    def _decode(self, m: dict) -> Any:
        return self.data_type.from_dict(m) if self.data_type is not None else m

    def _on_data(self, sample) -> None:
        try:
            msg = self._from_bytes(sample.payload.to_bytes())
        except MessageError as e:
            self._bad += 1
            if self._bad in (1, 10, 100) or self._bad % 1000 == 0:
                log.warning("%s: dropped malformed data (%d so far): %s", self.addr, self._bad, e)
            return
        # One Zenoh thread per subscription delivers in order, so these plain writes need no lock;
        # waiters count themselves in under the condition before they check, so none is missed.
        self.latest = msg
        self.received_at = _monotonic()
        self.count += 1
        if self._waiting:
            with self._cond:
                self._cond.notify_all()
        if self._has_after_data:
            self._after_data(msg)
        for fn in self._inline_listeners:
            try:
                fn(msg)
            except Exception:
                log.exception("%s: inline listener %r failed", self.addr, getattr(fn, "__qualname__", fn))
        if self._listeners:
            submit = self.fabric.dispatcher.submit
            for fn in self._listeners:
                submit(fn, msg)

    def _after_data(self, msg: Any) -> None:
        """Hook for subclasses (runs on a Zenoh thread: keep it short)."""

    def _on_event(self, sample) -> None:
        try:
            ev = msgs.decode_map(sample.payload.to_bytes())
        except MessageError:
            return
        self._handle_event(ev)
        for fn in self._event_listeners:
            self.fabric.dispatcher.submit(fn, ev)

    def _handle_event(self, ev: dict) -> None:
        pass

    def _set_alive(self, alive: bool) -> None:
        if alive == self.alive:
            return
        self.alive = alive
        if not alive:
            for fn in self._lost_listeners:
                self.fabric.dispatcher.submit(fn, self)

    # ------------------------------------------------------------------ public
    def add_listener(self, fn: Callable[[Any], None], *, inline: bool = False) -> None:
        """``fn(msg)`` for every new data message, in order, on the fabric's dispatcher thread.

        ``inline=True`` runs ``fn`` on the Zenoh thread that decoded the message instead: no thread
        hand-off (the fastest path, for high-rate streams), but ``fn`` must return quickly and must
        not block or call Zenoh (STYLE rule 2). An exception in it is logged and dropped.
        """
        (self._inline_listeners if inline else self._listeners).append(fn)

    def remove_listener(self, fn: Callable[[Any], None]) -> None:
        for lst in (self._listeners, self._inline_listeners):
            if fn in lst:
                lst.remove(fn)

    def add_event_listener(self, fn: Callable[[dict], None]) -> None:
        self._event_listeners.append(fn)

    def on_lost(self, fn: Callable[[Device], None]) -> None:
        """``fn(device)`` when the device's token disappears (needs a DeviceNode watching it)."""
        self._lost_listeners.append(fn)

    def wait_for_data(self, timeout: float = 5.0, *, newer_than: int | None = None) -> Any:
        """Block until a data message (newer than message number ``newer_than``) arrived."""
        deadline = time.monotonic() + timeout
        with self._cond:
            self._waiting += 1
            try:
                while self.latest is None or (newer_than is not None and self.count <= newer_than):
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise TimeoutError(f"{self.addr}: no data within {timeout:g} s; is the device alive (rsal ls)?")
                    self._cond.wait(left)
                return self.latest
            finally:
                self._waiting -= 1

    def age(self) -> float:
        """Seconds since the latest data (inf if none)."""
        return time.monotonic() - self.received_at if self.latest is not None else math.inf

    def rpc(self, op: str, timeout: float = 5.0, **args) -> dict:
        return self.fabric.rpc(self.addr, op, args, timeout=timeout)

    def rpc_async(self, op: str, timeout: float = 5.0, **args) -> Future:
        return self.fabric.rpc_async(self.addr, op, args, timeout=timeout)

    def describe(self, timeout: float = 5.0) -> msgs.Describe:
        if self._describe is None:
            self._describe = msgs.Describe.from_dict(self.rpc("describe", timeout=timeout))
        return self._describe

    def send(self, msg) -> None:
        self.fabric.send(self.addr, msg)

    def undeclare(self) -> None:
        """Stop receiving (the fabric does this for every proxy when it closes)."""
        for s in (self._sub, self._esub):
            try:
                s.undeclare()
            except Exception:
                pass
        self.fabric._forget(self.addr)


def _no_summary(msg: Any) -> str:
    return ""


@dataclass(frozen=True)
class Interface:
    """One Player interface as the platform knows it.

    ``data``: the message class of its ``data`` key (None: a plain map, decoded but not typed);
    ``cmds``: the message classes its ``cmd`` key accepts, tried in order (a map that fits none is
    rejected with the first one's error); ``event``: what its ``event`` key carries (text for the
    documentation; events travel as plain maps); ``proxy``: the client proxy class;
    ``geometry``: the typed form of its ``rpc/describe`` geometry, if it has one; ``summary``: one
    line of text for a data message (the live view's log and ``rsal ls``).
    """

    name: str
    proxy: type[Device] = Device
    data: type | None = None
    cmds: tuple[type, ...] = ()
    event: str = ""
    geometry: type | None = None
    summary: Callable[[Any], str] = _no_summary
    doc: str = ""

    def decode_data(self, payload: bytes | bytearray | memoryview | None) -> Any:
        """A ``data`` payload to its message (a plain map when the interface has no data type)."""
        return self.data.from_bytes(payload) if self.data is not None else decode_map(payload)

    def decode_cmd(self, m: dict, accepted: tuple[type, ...] | None = None) -> Any:
        """A ``cmd`` map to the first of ``accepted`` (default: this interface's ``cmds``) that it
        fits; the map itself when there is no command type to try."""
        return decode_as(self.cmds if accepted is None else accepted, m)


def decode_as(kinds: tuple[type, ...], m: dict) -> Any:
    """``m`` as the first of the message classes ``kinds`` it fits, tried in order. When it fits
    none, the error raised is that of the first class with a field the map has (``{"goal": [1, 2]}``
    is a bad GoalCmd, not a VelocityCmd without ``v``). ``m`` itself if ``kinds`` is empty."""
    if not kinds:
        return m
    if not isinstance(m, dict):  # already a message
        if isinstance(m, kinds):
            return m
        raise MessageError(f"a {type(m).__name__} is not one of {' | '.join(k.__name__ for k in kinds)}")
    errors: list[tuple[type, MessageError]] = []
    for cls in kinds:
        try:
            return cls.from_dict(m)
        except MessageError as e:
            errors.append((cls, e))
    for cls, e in errors:
        if isinstance(m, dict) and any(f.name in m for f in fields(cls)):
            raise e
    raise errors[0][1]
