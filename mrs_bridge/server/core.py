"""The device server's core: its drivers' slots, their lifecycle and the one scheduler loop.

Part of :mod:`mrs_bridge.server` (Player's server role, thesis 2.2.1 and 3.5; the package docstring
states the guarantees). :class:`DeviceServer` creates the drivers of a configuration, waits for
their required devices (liveliness with history, up to ``require_timeout`` seconds), sets them up,
and runs one loop that empties the inbox (:mod:`.intake`, :mod:`.rpc`) and calls every driver's
``update()`` at its own rate. A driver that raises is isolated: it is shut down, its devices are
withdrawn (:mod:`.devices`) and the drivers that depend on it follow; the others run on.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

from rsal import keys
from rsal.cliutil import FirstFew
from rsal.errors import RsalError
from rsal.keys import DeviceAddr
from rsal.msgs import MessageError
from rsal.suggest import did_you_mean

from ..config import ConfigError, DriverConfig, ServerConfig
from ..driver import DRIVERS, Driver
from .devices import _Device, _Devices, _direct
from .intake import INBOX_MAX, MAX_INPUT, _Inbox, _Intake
from .rpc import _Rpc

__all__ = ["DeviceServer", "ServerError", "make_driver_config"]

log = logging.getLogger("mrs_bridge.server")  # the server logs under one name

PUT = zenoh.SampleKind.PUT
WARN_INTERVAL = 5.0  # s between repeated warnings about the same key
WARN_KEYS = 4096  # rate-limiter entries kept; older ones are forgotten beyond this


class ServerError(RsalError, RuntimeError):
    """The server cannot start or run (no working driver)."""


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


class DeviceServer(_Intake, _Rpc, _Devices):
    """Hosts the drivers of one :class:`~mrs_bridge.config.ServerConfig` on ``session``. Its parts
    are mixins over one state: :class:`.intake._Intake` (what arrives), :class:`.rpc._Rpc` (queries
    and replies) and :class:`.devices._Devices` (declaring, announcing, publishing)."""

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
        where = config.source or "server"
        self._providing = FirstFew(f"drivers up in {where}")  # a line each for a few, then debug
        self._waiting = FirstFew(f"drivers waiting for devices in {where}")
        self.stats = {
            "cmd": 0,
            "rpc": 0,
            "rejected": 0,
            "published": 0,
            "unheard": 0,
            "too_large": 0,
            "dropped": 0,
            "busy": 0,
            "superseded": 0,  # data samples replaced by a newer one while waiting (latest wins)
        }
        self._latest: dict = {}  # (id(slot), device) -> the newest waiting data payload (intake)
        self._latest_lock = threading.Lock()
        self._reported = (0, 0, 0)  # too_large, dropped, busy already warned about
        self._failed = 0  # drivers that failed (the loop checks whether any still works)
        self._pub_cache: dict[int, tuple[DeviceAddr, Any, Any]] = {}  # id(addr) -> (addr, publisher's put, device)
        self._slot_by_id: dict[int, _Slot] = {}  # id(driver) -> its slot (checked by identity on use)
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
                    _direct(lambda s, slot=slot, r=r, put=self.inbox.put: put(("live", slot, r, s.kind == PUT))),
                    history=True,
                )
                slot.subs.append(sub)
            missing = ", ".join(map(str, sorted(slot.missing)))
            self._waiting.log(log, logging.INFO, "%s: waiting for %s", slot.name, missing)

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
        # By identity in a dict: a simulator calls this for each of its robots' drivers every step,
        # and a scan of the slots made that quadratic in the robots (1000: 1 M comparisons a step).
        slot = self._slot_by_id.get(id(driver))
        if slot is None or slot.driver is not driver:
            slot = self._slot_of(driver)
            if slot is None:
                return None
            self._slot_by_id[id(driver)] = slot
        if slot.state != "running":
            return None
        return self._call(slot, fn, *args)

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
                        _direct(
                            lambda s, slot=slot, r=r, ch=channel: self._on_sample(
                                ("input", slot, r, ch), s.payload, MAX_INPUT
                            )
                        ),
                    )
                )
        slot.state = "running"
        self._call(slot, drv.setup)
        if slot.state != "running":
            return
        for a in drv.cfg.provides:
            self._declare(slot, a.without_key())
        # a line per driver for a few; a crowd's (a 1000-robot world: 1002 drivers) at debug level
        provided = ", ".join(str(a.without_key()) for a in drv.cfg.provides)
        self._providing.log(log, logging.INFO, "%s: providing %s", slot.name, provided)

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


def make_driver_config(name: str, provides: list[str], node: str, **params) -> DriverConfig:
    """A driver block built in code (``rsal sim`` builds its config this way)."""
    from rsal.keys import parse_device

    return DriverConfig(name, [parse_device(p, node) for p in provides], [], params, None, f"<{name} {node}>")
