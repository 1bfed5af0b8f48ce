"""The device server's devices on the fabric: declaration, readiness tokens and publishing.

Part of :mod:`mrs_bridge.server` (the key space of :mod:`rsal.keys`, docs/protocol.md). Each
provided device gets a ``data`` and an ``event`` publisher, a ``cmd`` subscriber and an ``rpc/*``
queryable when its driver is set up, and its liveliness token only when the driver has run its
first ``update()`` ("ready means ready", :meth:`_Devices._announce`); :meth:`_Devices.set_online`
withdraws and returns the tokens of hardware that stops answering. Outbound: ``publish`` (the
hot path), ``publish_event``, and ``send``/``request`` to other devices, local or remote.

The per-device callbacks (``cmd``, ``rpc``, matching) run on Zenoh's network threads
(:func:`_direct`), not on a Python thread each.

A device's ``data`` is published only while someone listens: each data publisher has a Zenoh
matching listener that keeps :attr:`_Device.listened` (a plain bool, read on the hot path) up to
date, ``publish`` drops a message nobody subscribes to before encoding it, and drivers ask
:meth:`_Devices.listened` before they build an expensive message (a simulator serving 1000 robots
to a host that reads them all through the ``crowd`` device builds no per-robot samples;
docs/benchmarks.md, "Crowd"). A subscriber declared later gets data from the first step after
its interest reaches the server (Zenoh's matching status); events and rpcs are unchanged. A
driver with many devices keeps a :class:`ListenGroup` (:meth:`_Devices.listen_group`): one flag,
kept by the same listeners, that tells whether any of them is listened to.

:class:`_Devices` is a mixin of :class:`~mrs_bridge.server.DeviceServer`: it uses the server's
``session``, ``slots``, ``devices``, ``inbox``, ``stats``, ``_pub_cache`` and ``_on_sample``/``_on_query``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zenoh

from rsal import keys
from rsal.client import query_rpc
from rsal.keys import DeviceAddr
from rsal.msgs import encode
from rsal.ownership import DeviceToken

from ..driver import Driver
from .intake import MAX_PAYLOAD

if TYPE_CHECKING:
    from .core import _Slot


#: Zenoh calls each matching listener on a thread of its own: the flags of a :class:`ListenGroup`
#: are recomputed under this lock, so two devices of one group changing at once leave it right.
_MATCH_LOCK = threading.Lock()


def _direct(fn):
    """``fn`` as a callback run on Zenoh's own network thread. zenoh-python otherwise starts a
    Python thread per callback: three per device (``cmd``, ``rpc``, matching), 12,000 threads for
    a simulator of 1000 robots, which then failed to start with "can't start new thread" on a
    machine whose other processes held threads too; and three per required device (``data``,
    ``event``, liveliness) of a driver -- 1,200 threads in a server of 50 robots' navigation
    stacks, each waking for its samples and queueing for the GIL before the scheduler. Every
    callback here only checks, stores and hands over (the inbox, a bool) and never blocks (a full
    inbox's busy reply does not wait)."""
    return zenoh.handlers.Callback(fn, indirect=False)


class ListenGroup:
    """Whether anyone listens to any of several devices' ``data`` (:attr:`any`, a plain bool kept
    by their matching listeners): a driver serving many devices reads one flag per step instead of
    asking device by device (a simulator's 1000 robots nobody reads are skipped whole)."""

    __slots__ = ("devices", "any")

    def __init__(self, devices: list[_Device]):
        self.devices = devices
        self.any = False

    def refresh(self) -> None:  # under _MATCH_LOCK
        self.any = any(d.listened for d in self.devices)


@dataclass
class _Device:
    addr: DeviceAddr
    slot: _Slot
    token: Any = None
    pub: Any = None
    event_pub: Any = None
    cmd_sub: Any = None
    rpc_q: Any = None
    cmd_kinds: tuple | None = None  # message classes its cmd decodes to (None: not looked up yet)
    matcher: Any = None  # the data publisher's matching listener
    listened: bool = True  # a subscriber matches ``data`` (kept by ``matcher``; True until it reports)
    groups: list[ListenGroup] = field(default_factory=list)  # the listen groups this device is in

    def _on_match(self, status) -> None:  # Zenoh's thread: attribute writes, no zenoh call
        with _MATCH_LOCK:
            self.listened = bool(status.matching)
            for g in self.groups:
                g.refresh()

    def undeclare(self) -> None:
        for name in ("matcher", "cmd_sub", "rpc_q", "pub", "event_pub", "token"):
            ent = getattr(self, name)
            if ent is not None:
                try:
                    ent.undeclare()
                except Exception:  # already closed with the session
                    pass
                setattr(self, name, None)


class _Devices:
    """Declares, announces and withdraws devices, and publishes for their drivers."""

    def set_online(self, driver: Driver, online: bool) -> None:
        """Withdraw (``online`` false) or re-declare the liveliness tokens of ``driver``'s devices,
        for hardware that stops answering and comes back (clients see the devices lost, then found).
        Publishers, commands and rpcs stay declared. Scheduler thread only."""
        driver.online = bool(online)
        slot = next((s for s in self.slots if s.driver is driver), None)
        if slot is not None and not slot.announced:
            return  # not ready yet: the tokens come with the first update (_announce)
        for a in driver.cfg.provides:
            dev = self.devices.get(a.without_key())
            if dev is None:
                continue
            if online and dev.token is None:
                dev.token = DeviceToken(self.session, keys.device_key(dev.addr))
            elif not online and dev.token is not None:
                try:
                    dev.token.undeclare()
                except Exception:  # already closed with the session
                    pass
                dev.token = None

    def _declare(self, slot: _Slot, addr: DeviceAddr) -> None:
        s = self.session
        dev = _Device(addr, slot)
        dev.pub = s.declare_publisher(keys.data_key(addr))
        # Data only while someone listens: the listener keeps a bool the hot path reads; the status
        # is read once after declaring it, so a subscriber that existed before is not missed.
        dev.matcher = dev.pub.declare_matching_listener(_direct(dev._on_match))
        st = dev.pub.matching_status  # a MatchingStatus (zenoh 1.10; its stub says bool)
        dev.listened = bool(getattr(st, "matching", st))
        # Reliable, but never blocking: the scheduler publishes, and a peer that reads slowly must
        # not hold it up (with BLOCK, a full link to one slow subscriber stalls the whole server).
        # An event to a congested peer is dropped for that peer only.
        dev.event_pub = s.declare_publisher(
            keys.event_key(addr),
            reliability=zenoh.Reliability.RELIABLE,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        dev.cmd_sub = s.declare_subscriber(
            keys.cmd_key(addr), _direct(lambda smp, a=addr: self._on_sample(("cmd", a), smp.payload, MAX_PAYLOAD))
        )
        dev.rpc_q = s.declare_queryable(
            f"{keys.PREFIX}/{addr.path}/rpc/*", _direct(lambda q, a=addr: self._on_query(a, q))
        )
        self.devices[addr] = dev
        self._pub_cache.clear()

    def _announce(self, slot: _Slot) -> None:
        """Declare the liveliness tokens of ``slot``'s devices: it is set up and has run once."""
        slot.announced = True
        if not slot.driver.online:  # hardware not answering yet: its tokens come with set_online(True)
            return
        for a in slot.driver.cfg.provides:
            dev = self.devices.get(a.without_key())
            if dev is not None and dev.token is None:
                dev.token = DeviceToken(self.session, keys.device_key(dev.addr))

    # ------------------------------------------------------------------ outbound
    def publish(self, addr: DeviceAddr, msg) -> None:
        # Drivers publish with the same address objects every time (their cfg.provides): look the
        # device's ``put`` up by identity first, which skips hashing and comparing the dataclass.
        # The cache holds the address object, so its id cannot be reused while the entry lives; it
        # is emptied whenever a device is declared or withdrawn (which undeclares its publisher).
        hit = self._pub_cache.get(id(addr))
        if hit is None or hit[0] is not addr:
            dev = self.devices.get(addr.without_key() if addr.key else addr)
            if dev is None or dev.pub is None:
                return
            hit = self._pub_cache[id(addr)] = (addr, dev.pub.put, dev)
        if not hit[2].listened:
            self.stats["unheard"] += 1
            return
        pack = getattr(msg, "to_msgpack", None)  # encode(), without a call on the hot path
        hit[1](pack() if pack is not None else encode(msg))
        self.stats["published"] += 1

    def listened(self, addr: DeviceAddr) -> bool:
        """Whether a subscriber matches the ``data`` of device ``addr`` now (a cached flag, no
        network query): a driver asks before it builds a message that costs something."""
        hit = self._pub_cache.get(id(addr))
        if hit is None or hit[0] is not addr:
            dev = self.devices.get(addr.without_key() if addr.key else addr)
            if dev is None or dev.pub is None:
                return False
            hit = self._pub_cache[id(addr)] = (addr, dev.pub.put, dev)
        return hit[2].listened

    def listen_group(self, addrs) -> ListenGroup:
        """A :class:`ListenGroup` over the declared devices of ``addrs``: its ``any`` is true while
        someone subscribes to the ``data`` of at least one of them. Scheduler thread."""
        devs = []
        for addr in addrs:
            dev = self.devices.get(addr.without_key() if addr.key else addr)
            if dev is not None and dev.pub is not None and all(dev is not d for d in devs):
                devs.append(dev)
        group = ListenGroup(devs)
        with _MATCH_LOCK:
            for dev in devs:
                dev.groups.append(group)
            group.refresh()
        return group

    def publish_each(self, addrs, msg) -> None:
        """Publish one message on several devices, encoded once: a sonar ring's scan on
        ``ranger:0`` and its alias ``sonar:0`` (the same bytes as :meth:`publish` on each)."""
        payload = None
        cache = self._pub_cache
        for addr in addrs:
            hit = cache.get(id(addr))
            if hit is None or hit[0] is not addr:
                dev = self.devices.get(addr.without_key() if addr.key else addr)
                if dev is None or dev.pub is None:
                    continue
                hit = cache[id(addr)] = (addr, dev.pub.put, dev)
            if not hit[2].listened:
                self.stats["unheard"] += 1
                continue
            if payload is None:
                pack = getattr(msg, "to_msgpack", None)
                payload = pack() if pack is not None else encode(msg)
            hit[1](payload)
            self.stats["published"] += 1

    def send(self, addr: DeviceAddr, msg) -> None:
        """Put a command on another device's ``cmd`` key (a required device, local or remote)."""
        self.session.put(keys.cmd_key(addr.without_key()), encode(msg))

    def request(self, slot_driver: Driver, addr: DeviceAddr, op: str, args: dict | None, timeout: float) -> None:
        """Query ``rpc/<op>`` of another device; the result reaches ``driver.on_reply(addr, op, result,
        error)`` on the scheduler thread (``error`` an :class:`RpcError`, ``result`` None then)."""
        slot = next((s for s in self.slots if s.driver is slot_driver), None)
        if slot is None:
            raise ValueError("request() from a driver this server does not host")
        query_rpc(
            self.session,
            addr.without_key(),
            op,
            args,
            timeout,
            lambda outcome: self.inbox.put(("reply", slot, addr, op, outcome)),
        )

    def publish_event(self, addr: DeviceAddr, msg) -> None:
        dev = self.devices.get(addr.without_key() if addr.key else addr)
        if dev is None or dev.event_pub is None:
            return
        dev.event_pub.put(encode(msg))
