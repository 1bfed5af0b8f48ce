"""Command intake of the device server: the bounded inbox, Zenoh's callbacks and typed decoding.

Part of :mod:`mrs_bridge.server` (Player's server role, thesis 2.2.1 and 3.5; the limits and
replies are those of docs/protocol.md, "Robustness"). Zenoh's callbacks (:meth:`_Intake._on_sample`,
:meth:`_Intake._on_query`) only check sizes, count and queue on the :class:`_Inbox`; the scheduler
thread then takes each item to :meth:`_Intake._handle`, which decodes it once, with its type where
the interface is known (:func:`rsal.interfaces.cmd_types`, :func:`rsal.interfaces.decode_data`),
and hands it to the driver. Bad input changes nothing and is warned about at a limited rate.

A required device's ``data`` is a state stream: latest wins (zenoh's ``RingChannel`` for sensor
streams). While a sample of one (driver, device) still waits in the inbox, a newer one replaces
its payload in place instead of queueing behind it, so a server that falls behind (100 navigation
stacks on one core) skips stale scans and poses instead of filling its inbox and dropping whatever
arrives next (commands, replies and events included). A server that keeps up sees every sample.
``event`` samples stay in order, every one delivered.

:class:`_Intake` is a mixin of :class:`~mrs_bridge.server.DeviceServer`: it uses the server's
``inbox``, ``devices``, ``stats``, ``_call``, ``_setup`` and ``_warn``.
"""

from __future__ import annotations

import collections
import logging
import queue
import threading

from rsal import interfaces, keys
from rsal.keys import DeviceAddr
from rsal.msgs import ErrorCode, MessageError, RpcError, decode_map, error_reply

__all__ = ["INBOX_MAX", "MAX_INPUT", "MAX_PAYLOAD"]

log = logging.getLogger("mrs_bridge.server")  # the server logs under one name

MAX_PAYLOAD = 64 * 1024  # bytes: larger cmd/rpc payloads are refused before decoding
MAX_INPUT = 4 * 1024 * 1024  # bytes: larger data/event samples from required devices are dropped
INBOX_MAX = 1024  # items waiting for the scheduler; beyond it cmds are dropped and rpcs answered busy


class _Inbox:
    """The scheduler's queue: bounded for input from the network (:meth:`offer` refuses when
    ``maxsize`` items wait), unbounded for the server's own items (``force``: replies to its own
    requests, liveliness changes, wake-ups), which are few by construction."""

    def __init__(self, maxsize: int):
        self.maxsize = maxsize
        self._q: collections.deque = collections.deque()
        self._cv = threading.Condition(threading.Lock())

    def offer(self, item, force: bool = False) -> bool:
        with self._cv:
            if not force and len(self._q) >= self.maxsize:
                return False
            self._q.append(item)
            self._cv.notify()
            return True

    def put(self, item) -> None:
        self.offer(item, force=True)

    def empty(self) -> bool:
        return not self._q

    def qsize(self) -> int:
        return len(self._q)

    def get_nowait(self):
        with self._cv:
            if not self._q:
                raise queue.Empty
            return self._q.popleft()

    def get(self, timeout: float):
        with self._cv:
            if not self._q and not self._cv.wait_for(lambda: self._q, timeout):
                raise queue.Empty
            return self._q.popleft()


class _Intake:
    """What reaches the scheduler from the network, and how it reaches the drivers."""

    # The three callbacks below run on Zenoh's threads: they only check sizes, count and queue.
    def _offer(self, item: tuple) -> bool:
        if self.inbox.offer(item):
            return True
        self.stats["dropped"] += 1
        return False

    def _on_sample(self, head: tuple, payload, limit: int) -> None:
        if len(payload) > limit:  # refused before it is copied or decoded
            self.stats["too_large"] += 1
            return
        if head[0] == "input" and head[3] == "data":  # latest wins while one waits
            key = (id(head[1]), head[2])
            data = payload.to_bytes()
            with self._latest_lock:
                waiting = key in self._latest
                self._latest[key] = data
            if waiting:
                self.stats["superseded"] += 1
                return
            if not self._offer(("latest", head[1], head[2], key)):
                with self._latest_lock:
                    self._latest.pop(key, None)
            return
        self._offer((*head, payload.to_bytes()))

    def _on_query(self, addr: DeviceAddr, query) -> None:
        if self._offer(("rpc", addr, query)):
            return
        # Full: the one Zenoh call made on a callback thread; an error reply does not wait.
        self.stats["busy"] += 1
        try:
            query.reply_err(error_reply(ErrorCode.BUSY, f"{addr}: the server is busy; try again later"))
        except Exception:
            pass
        finally:
            try:
                query.drop()
            except Exception:
                pass

    def _report_overload(self) -> None:
        now = (self.stats["too_large"], self.stats["dropped"], self.stats["busy"])
        if now != self._reported:
            d = [a - b for a, b in zip(now, self._reported, strict=True)]
            self._warn(
                "overload",
                f"refused {d[0]} sample(s) over the size limit, dropped {d[1]} item(s) and answered {d[2]} "
                f"rpc(s) busy because the inbox ({INBOX_MAX} items) was full",
            )
            if self._warned["overload"][1] == 0:  # logged now: count from here
                self._reported = now

    def _handle(self, item: tuple) -> None:
        kind = item[0]
        if kind == "cmd":
            self._on_cmd(item[1], item[2])
        elif kind == "rpc":
            self._on_rpc(item[1], item[2])
        elif kind in ("input", "latest"):
            if kind == "latest":
                _, slot, addr, key = item
                channel = "data"
                with self._latest_lock:
                    payload = self._latest.pop(key)
            else:
                _, slot, addr, channel, payload = item
            if slot.state != "running":
                return
            try:
                msg = interfaces.decode_data(addr.interface, payload) if channel == "data" else decode_map(payload)
            except MessageError as e:
                self._warn(f"input:{addr}", f"malformed {channel} from {addr}: {e}")
                return
            self._call(slot, slot.driver.on_input, addr, channel, msg)
        elif kind == "reply":
            _, slot, addr, op, res = item
            if slot.state != "running":
                return
            if isinstance(res, RpcError):
                self._call(slot, slot.driver.on_reply, addr, op, None, res)
            else:
                self._call(slot, slot.driver.on_reply, addr, op, res, None)
        elif kind == "live":
            _, slot, addr, alive = item
            if slot.state == "waiting":
                if alive:
                    slot.missing.discard(addr)
                else:  # seen, then lost before the others arrived: still missing
                    slot.missing.add(addr)
                if not slot.missing:
                    self._setup(slot)
            elif slot.state == "running" and not alive:
                self._warn(
                    f"lost:{slot.name}:{addr}",
                    f"{slot.name}: required device {addr} was lost; waiting for it to return",
                )

    def _on_cmd(self, addr: DeviceAddr, payload: bytes) -> None:
        self.stats["cmd"] += 1
        dev = self.devices.get(addr)
        if dev is None or dev.slot.state != "running":
            return
        try:
            kinds = dev.cmd_kinds
            if kinds is None:
                drv = dev.slot.driver
                kinds = dev.cmd_kinds = interfaces.cmd_types(addr.interface, drv.cmd_types.get(addr.interface, ""))
            m = decode_map(payload)
            msg = interfaces.decode_as(kinds, m)
            dev.slot.driver.on_cmd(addr, msg)
        except MessageError as e:
            self.stats["rejected"] += 1
            self._warn(f"cmd:{addr}", f"rejected cmd on {keys.cmd_key(addr)}: {e}")
        except Exception as e:
            self.stats["rejected"] += 1
            self._warn(f"cmd:{addr}", f"cmd on {keys.cmd_key(addr)} failed in the driver: {type(e).__name__}: {e}")
