"""The device server: Player's server role on Zenoh (thesis 2.2.1, 3.5; DESIGN "Processes").

A :class:`DeviceServer` hosts the drivers of one configuration. For each provided device it
declares, per the key space of :mod:`rsal.keys`:

- a liveliness token ``rsal/<node>/<iface>/<idx>`` (present while the device works),
- a ``data`` publisher and an ``event`` publisher,
- a ``cmd`` subscriber and an ``rpc/*`` queryable (``rpc/describe`` on every device).

Ready means ready: a device's token is declared only once its driver is set up (compiled kernels
included, see :mod:`simulator.warmup`) and has run its first ``update()`` (drivers without a rate
publish on their own events: after the first scheduler pass), so a client that sees the token can
query, command and receive data at once, on the first run of a fresh checkout as on every other.

Concurrency: Zenoh callbacks only put raw items on one in-memory queue; a single scheduler loop
(:meth:`DeviceServer.run`) takes them off, decodes and validates them, hands them to drivers and
replies, and runs every driver's ``update()`` at its own rate. A driver that raises is logged, its
devices' tokens are withdrawn (clients see them as lost) and the other drivers keep running.
Bad input (not msgpack, wrong fields or types, NaN/inf, out of range, unknown op) gets an error
reply on ``rpc`` and a rate-limited warning on ``cmd``, and changes nothing.

Typed hand-over: where the interface is known (:mod:`rsal.interfaces`), a ``cmd`` reaches the
driver's ``on_cmd`` as its message (the types the driver declares in ``cmd_types``, else the
interface's: ``VelocityCmd``, ``GoalCmd``, ``GripperCmd``, ``DioCmd``) and a required device's
``data`` reaches ``on_input`` as the interface's data message (``Position2dData``,
``RangerData``, ...), decoded and validated once, here. Events and interfaces without a message
type arrive as plain maps.

Required devices may live on other servers: a driver with ``requires`` waits for their tokens
(liveliness subscriber with history) up to ``require_timeout`` seconds, then fails with a message
that names the missing devices.
"""

from __future__ import annotations

import collections
import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

from rsal import interfaces, keys
from rsal.client import query_rpc
from rsal.errors import RsalError
from rsal.keys import DeviceAddr
from rsal.msgs import (
    Describe,
    ErrorCode,
    MessageError,
    RpcError,
    decode_map,
    encode,
    error_reply,
    ok_reply,
)

from .config import ConfigError, DriverConfig, ServerConfig
from .driver import DRIVERS, Deferred, Driver, OutOfRange
from .params import did_you_mean

__all__ = ["DeviceServer", "ServerError"]

log = logging.getLogger(__name__)

WARN_INTERVAL = 5.0  # s between repeated warnings about the same key
WARN_KEYS = 4096  # rate-limiter entries kept; older ones are forgotten beyond this
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


class ServerError(RsalError, RuntimeError):
    """The server cannot start or run (no working driver)."""


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

    def undeclare(self) -> None:
        for name in ("cmd_sub", "rpc_q", "pub", "event_pub", "token"):
            ent = getattr(self, name)
            if ent is not None:
                try:
                    ent.undeclare()
                except Exception:  # already closed with the session
                    pass
                setattr(self, name, None)


@dataclass
class _Slot:
    driver: Driver
    state: str = "waiting"  # waiting | running | failed | stopped
    missing: set[DeviceAddr] = field(default_factory=set)
    deadline: float = math.inf
    next_due: float = 0.0
    subs: list[Any] = field(default_factory=list)  # liveliness and input subscribers
    announced: bool = False  # the devices' tokens are declared (first update done)
    reason: str = ""  # why the devices are not available (failed, withdrawn)

    @property
    def name(self) -> str:
        return self.driver.cfg.where


class DeviceServer:
    def __init__(
        self,
        config: ServerConfig,
        session: zenoh.Session,
        *,
        require_timeout: float = 30.0,
        drivers: dict[str, type[Driver]] | None = None,
        shared: dict[str, Any] | None = None,
    ):
        self.config = config
        self.session = session
        self.require_timeout = float(require_timeout)
        self.registry = drivers if drivers is not None else DRIVERS
        self.shared: dict[str, Any] = shared if shared is not None else {}
        self.inbox = _Inbox(INBOX_MAX)
        self.slots: list[_Slot] = []
        self.devices: dict[DeviceAddr, _Device] = {}
        self._stop = threading.Event()
        self._warned: dict[str, tuple[float, int]] = {}
        self.stats = {"cmd": 0, "rpc": 0, "rejected": 0, "published": 0, "too_large": 0, "dropped": 0, "busy": 0}
        self._reported = (0, 0, 0)  # too_large, dropped, busy already warned about
        self._failed = 0  # drivers that failed (the loop checks whether any still works)
        self._pub_cache: dict[int, tuple[DeviceAddr, Any]] = {}  # id(addr) -> (addr, publisher's put)
        self._pending: list[tuple] = []  # long rpcs in progress: (device, op, reply key, query, Deferred)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Create every driver (config errors raise :class:`ConfigError`) and declare the devices
        of those that need nothing; the others wait for their required devices."""
        for dc in self.config.drivers:
            cls = self.registry.get(dc.name)
            if cls is None:
                close = did_you_mean(dc.name, self.registry)
                hint = f"; did you mean {close!r}?" if close else f"; known: {', '.join(sorted(self.registry))}"
                raise ConfigError(f"{dc.where}: unknown driver {dc.name!r}{hint}")
            try:
                drv = cls(dc, self)
            except (MessageError, ConfigError, ValueError) as e:
                raise ConfigError(str(e) if str(e).startswith(dc.where) else f"{dc.where}: {e}") from None
            self.slots.append(_Slot(drv))
        for slot in self.slots:
            reqs = [r.without_key() for r in slot.driver.cfg.requires]
            if not reqs:
                self._setup(slot)
                continue
            slot.missing = set(reqs)
            slot.deadline = time.monotonic() + self.require_timeout
            for r in set(reqs):
                sub = self.session.liveliness().declare_subscriber(
                    keys.device_key(r),
                    lambda s, slot=slot, r=r: self.inbox.put(("live", slot, r, s.kind == zenoh.SampleKind.PUT)),
                    history=True,
                )
                slot.subs.append(sub)
            log.info("%s: waiting for %s", slot.name, ", ".join(map(str, sorted(slot.missing))))

    def stop(self) -> None:
        """Ask :meth:`run` to return (thread-safe, signal-safe)."""
        self._stop.set()
        self.inbox.put(("wake",))

    def close(self) -> None:
        """Stop actuators and withdraw every device (call after :meth:`run` returned)."""
        for slot in self.slots:
            if slot.state == "running":
                self._call(slot, slot.driver.shutdown, fail=False)
                slot.state = "stopped"
            for s in slot.subs:
                try:
                    s.undeclare()
                except Exception:
                    pass
            slot.subs.clear()
        for dev in list(self.devices.values()):
            dev.undeclare()
        self.devices.clear()
        self._pub_cache.clear()

    @property
    def running_drivers(self) -> list[Driver]:
        return [s.driver for s in self.slots if s.state == "running"]

    def drivers_of(self, cls: type) -> list[Driver]:
        return [s.driver for s in self.slots if s.state == "running" and isinstance(s.driver, cls)]

    # ------------------------------------------------------------------ the scheduler
    def run(self, *, until: float | None = None) -> None:
        """Serve until :meth:`stop` (or ``until`` monotonic time). One thread does everything."""
        now = time.monotonic()
        for slot in self.slots:
            slot.next_due = now
        while not self._stop.is_set():
            now = time.monotonic()
            if until is not None and now >= until:
                break
            item = None
            if not self.inbox.empty():
                item = self.inbox.get_nowait()
            else:
                timeout = 0.0 if self._pending else self._next_wakeup(now)
                if timeout > 0:
                    try:
                        item = self.inbox.get(timeout=timeout)
                    except queue.Empty:
                        pass
            handled = 0
            while item is not None:
                self._handle(item)
                handled += 1
                if handled >= 2000 or self._stop.is_set():
                    break
                try:
                    item = self.inbox.get_nowait()
                except queue.Empty:
                    item = None
            self._run_due(time.monotonic())
            if self._pending:
                self._run_pending()
            self._report_overload()
            if self._failed and not any(s.state in ("running", "waiting") for s in self.slots):
                raise ServerError("no driver is working any more; see the errors above")

    def _next_wakeup(self, now: float) -> float:
        t = now + 0.5
        for s in self.slots:
            if s.state == "running" and s.driver.rate > 0:
                t = min(t, s.next_due)
            elif s.state == "waiting":
                t = min(t, s.deadline)
        return max(0.0, t - now)

    def _run_due(self, now: float) -> None:
        for slot in self.slots:
            if slot.state == "waiting" and now >= slot.deadline:
                missing = ", ".join(map(str, sorted(slot.missing)))
                log.error(
                    "%s: required device(s) %s did not appear within %g s; start the server that "
                    "provides them, or check the 'requires' names",
                    slot.name,
                    missing,
                    self.require_timeout,
                )
                self._fail(slot, None)
                continue
            if slot.state != "running":
                continue
            if slot.driver.rate <= 0:  # publishes on its own events: ready after one scheduler pass
                if not slot.announced and self._call(slot, slot.driver.ready):
                    self._announce(slot)
                continue
            if now < slot.next_due:
                continue
            period = 1.0 / slot.driver.rate if math.isfinite(slot.driver.rate) else 0.0
            slot.next_due += period
            if slot.next_due < now - period:  # fell behind: do not burst
                slot.next_due = now + period
            self._call(slot, slot.driver.update, now)
            if not slot.announced and slot.state == "running" and self._call(slot, slot.driver.ready):
                self._announce(slot)

    def _call(self, slot: _Slot, fn, *args, fail: bool = True):
        try:
            return fn(*args)
        except Exception as e:
            if fail:
                log.error(
                    "%s: driver failed in %s: %s: %s; its devices are withdrawn",
                    slot.name,
                    getattr(fn, "__name__", "?"),
                    type(e).__name__,
                    e,
                )
                log.debug("driver failure", exc_info=True)
                self._fail(slot, e)
            else:
                log.warning("%s: %s: %s", slot.name, type(e).__name__, e)
            return None

    def call_driver(self, driver: Driver, fn, *args):
        """Run ``fn`` for ``driver`` (e.g. a simulation step callback) with failure isolation."""
        for slot in self.slots:
            if slot.driver is driver:
                if slot.state != "running":
                    return None
                return self._call(slot, fn, *args)
        return None

    def hosted(self, cls: type) -> list[Driver]:
        """Every driver of class ``cls`` this server hosts, whatever its state."""
        return [s.driver for s in self.slots if isinstance(s.driver, cls)]

    def _slot_of(self, driver: Driver) -> _Slot | None:
        return next((s for s in self.slots if s.driver is driver), None)

    def withdraw(self, driver: Driver, reason: str) -> None:
        """Take a running driver's devices off the fabric while the server runs on (e.g. a robot
        removed from the simulation): ``shutdown()``, tokens withdrawn, no more updates, and every
        rpc answered ``unavailable`` with ``reason``. Scheduler thread only."""
        slot = self._slot_of(driver)
        if slot is None or slot.state != "running":
            return
        self._call(slot, driver.shutdown, fail=False)
        slot.state = "stopped"
        slot.reason = reason
        self.set_online(driver, False)
        log.info("%s: devices withdrawn: %s", slot.name, reason)

    def reinstate(self, driver: Driver) -> None:
        """Undo :meth:`withdraw`: the devices serve and their tokens return. Scheduler thread only."""
        slot = self._slot_of(driver)
        if slot is None or slot.state != "stopped" or not slot.reason:
            return
        slot.state = "running"
        slot.reason = ""
        slot.next_due = time.monotonic()
        self.set_online(driver, True)
        log.info("%s: devices back", slot.name)

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
                dev.token = self.session.liveliness().declare_token(keys.device_key(dev.addr))
            elif not online and dev.token is not None:
                try:
                    dev.token.undeclare()
                except Exception:  # already closed with the session
                    pass
                dev.token = None

    def _fail(self, slot: _Slot, exc: Exception | None) -> None:
        if slot.state == "running":
            try:
                slot.driver.shutdown()
            except Exception as e:
                log.warning("%s: shutdown after failure: %s", slot.name, e)
        if slot.state == "failed":
            return
        slot.state = "failed"
        slot.reason = "its driver failed"
        self._failed += 1
        self._pub_cache.clear()
        for a in slot.driver.cfg.provides:
            dev = self.devices.pop(a.without_key(), None)
            if dev is not None:
                dev.undeclare()
        for s in slot.subs:
            try:
                s.undeclare()
            except Exception:
                pass
        slot.subs.clear()
        # Drivers that depend on this one in this process (e.g. the sim drivers on the simulation's
        # world) cannot work without it: they fail too, so no token outlives what it stands for.
        for other in self.slots:
            if other.state in ("running", "waiting", "stopped") and slot.driver in other.driver.depends_on:
                log.error("%s: withdrawn because %s failed", other.name, slot.name)
                self._fail(other, None)

    def _setup(self, slot: _Slot) -> None:
        drv = slot.driver
        # Inputs from required devices.
        for r in drv.cfg.requires:
            for channel, key in (("data", keys.data_key(r)), ("event", keys.event_key(r))):
                slot.subs.append(
                    self.session.declare_subscriber(
                        key,
                        lambda s, slot=slot, r=r, ch=channel: self._on_sample(
                            ("input", slot, r, ch), s.payload, MAX_INPUT
                        ),
                    )
                )
        slot.state = "running"
        self._call(slot, drv.setup)
        if slot.state != "running":
            return
        for a in drv.cfg.provides:
            self._declare(slot, a.without_key())
        log.info("%s: providing %s", slot.name, ", ".join(str(a.without_key()) for a in drv.cfg.provides))

    def _declare(self, slot: _Slot, addr: DeviceAddr) -> None:
        s = self.session
        dev = _Device(addr, slot)
        dev.pub = s.declare_publisher(keys.data_key(addr))
        # Reliable, but never blocking: the scheduler publishes, and a peer that reads slowly must
        # not hold it up (with BLOCK, a full link to one slow subscriber stalls the whole server).
        # An event to a congested peer is dropped for that peer only.
        dev.event_pub = s.declare_publisher(
            keys.event_key(addr),
            reliability=zenoh.Reliability.RELIABLE,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        dev.cmd_sub = s.declare_subscriber(
            keys.cmd_key(addr), lambda smp, a=addr: self._on_sample(("cmd", a), smp.payload, MAX_PAYLOAD)
        )
        dev.rpc_q = s.declare_queryable(f"{keys.PREFIX}/{addr.path}/rpc/*", lambda q, a=addr: self._on_query(a, q))
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
                dev.token = self.session.liveliness().declare_token(keys.device_key(dev.addr))

    # ------------------------------------------------------------------ inbound
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
        elif kind == "input":
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

    def _on_rpc(self, addr: DeviceAddr, query) -> None:
        self.stats["rpc"] += 1
        keep = False
        try:
            qkey = str(query.key_expr)
            op = qkey.rsplit("/", 1)[-1]
            dev = self.devices.get(addr)
            if op in ("*", "**"):
                op = "describe"  # a wildcard query (e.g. from `rsal ls`) gets the description
            elif not keys._NAME.match(op):
                self.stats["rejected"] += 1
                query.reply_err(
                    error_reply(
                        ErrorCode.BAD_REQUEST,
                        f"{addr}: {op[:40]!r} is not an operation name (letters, digits, '_', '-', '.')",
                    )
                )
                return
            reply_key = keys.rpc_key(addr, op)
            if dev is None or dev.slot.state != "running":
                why = f": {dev.slot.reason}" if dev is not None and dev.slot.reason else ""
                query.reply_err(error_reply(ErrorCode.UNAVAILABLE, f"{addr} is not available{why}"))
                return
            size = len(query.payload) if query.payload is not None else 0
            if size > MAX_PAYLOAD:
                self.stats["too_large"] += 1
                self._reported = (self._reported[0] + 1, *self._reported[1:])  # answered: no warning
                query.reply_err(
                    error_reply(
                        ErrorCode.TOO_LARGE, f"{addr}: request of {size} bytes is over the limit of {MAX_PAYLOAD}"
                    )
                )
                return
            keep = self._answer(dev, op, reply_key, query, lambda: self._rpc_result(dev, op, query))
        except Exception as e:  # never let a reply problem (e.g. a closed query) stop the server
            self._warn(f"rpc:{addr}", f"could not answer an rpc on {addr}: {type(e).__name__}: {e}")
        finally:
            if not keep:
                try:
                    query.drop()
                except Exception:
                    pass

    def _rpc_result(self, dev: _Device, op: str, query):
        addr, drv = dev.addr, dev.slot.driver
        args = decode_map(query.payload.to_bytes() if query.payload is not None else b"")
        if op == "describe":
            return self.describe(addr).to_dict()
        if op not in drv.ops(addr):
            raise RpcError(
                ErrorCode.UNKNOWN_OP, f"{addr} has no operation {op!r}; it has: {', '.join(drv.all_ops(addr))}"
            )
        return drv.on_rpc(addr, op, args) or {}

    def _answer(self, dev: _Device, op: str, reply_key: str, query, fn) -> bool:
        """Reply to ``query`` with ``fn()``'s result or its typed error. A :class:`Deferred` result
        is kept and continued on later scheduler passes: returns True then (the query stays open)."""
        try:
            result = fn()
            if isinstance(result, Deferred):
                self._pending.append((dev, op, reply_key, query, result))
                return True
            query.reply(reply_key, ok_reply(**result))
        except OutOfRange as e:
            self.stats["rejected"] += 1
            query.reply_err(error_reply(ErrorCode.OUT_OF_RANGE, str(e)))
        except MessageError as e:
            self.stats["rejected"] += 1
            query.reply_err(error_reply(ErrorCode.BAD_REQUEST, str(e)))
        except RpcError as e:
            self.stats["rejected"] += 1
            query.reply_err(error_reply(e.code, e.message))
        except Exception as e:
            self._warn(
                f"internal:{dev.addr}", f"{dev.slot.name}: rpc {op} failed: {type(e).__name__}: {e}", logging.ERROR
            )
            log.debug("rpc failure", exc_info=True)
            query.reply_err(error_reply(ErrorCode.INTERNAL, f"{type(e).__name__}: {e}"))
        return False

    def _run_pending(self) -> None:
        """One slice of every long operation in progress (see :class:`~mrs_bridge.driver.Deferred`)."""
        pending, self._pending = self._pending, []
        for dev, op, reply_key, query, deferred in pending:
            keep = False
            try:
                if dev.slot.state != "running":
                    query.reply_err(error_reply(ErrorCode.UNAVAILABLE, f"{dev.addr} is not available"))
                else:
                    keep = self._answer(dev, op, reply_key, query, lambda d=deferred: _continue(d))
            except Exception as e:
                self._warn(f"rpc:{dev.addr}", f"could not answer an rpc on {dev.addr}: {type(e).__name__}: {e}")
            if not keep:
                try:
                    query.drop()
                except Exception:
                    pass

    def describe(self, addr: DeviceAddr) -> Describe:
        dev = self.devices[addr]
        drv = dev.slot.driver
        return Describe(
            node=addr.node,
            interface=addr.interface,
            index=addr.index,
            driver=drv.driver_name,
            rate=float(getattr(drv, "publish_rate", lambda a: drv.rate)(addr)),
            geometry=drv.geometry(addr),
            ops=drv.all_ops(addr),
            cmd=drv.cmd_types.get(addr.interface, ""),
            data=drv.data_types.get(addr.interface, ""),
        )

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
            hit = self._pub_cache[id(addr)] = (addr, dev.pub.put)
        pack = getattr(msg, "to_msgpack", None)  # encode(), without a call on the hot path
        hit[1](pack() if pack is not None else encode(msg))
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

    def _warn(self, key: str, text: str, level: int = logging.WARNING) -> None:
        """Log ``text`` at most once per :data:`WARN_INTERVAL` per ``key``, with a count of the
        suppressed ones. Every log line that outside input can cause goes through here."""
        now = time.monotonic()
        last, suppressed = self._warned.get(key, (-math.inf, 0))
        if now - last >= WARN_INTERVAL:
            extra = f" ({suppressed} more like it suppressed)" if suppressed else ""
            log.log(level, "%s%s", text, extra)
            if len(self._warned) >= WARN_KEYS and key not in self._warned:
                self._warned = {k: v for k, v in self._warned.items() if now - v[0] < WARN_INTERVAL}
            self._warned[key] = (now, 0)
        else:
            self._warned[key] = (last, suppressed + 1)


def _continue(deferred: Deferred):
    """One slice of a long operation: its result map, or the :class:`Deferred` itself if not done."""
    result = deferred.step()
    return deferred if result is None else result


def make_driver_config(name: str, provides: list[str], node: str, **params) -> DriverConfig:
    """A driver block built in code (``rsal sim`` builds its config this way)."""
    from rsal.keys import parse_device

    return DriverConfig(name, [parse_device(p, node) for p in provides], [], params, None, f"<{name} {node}>")
