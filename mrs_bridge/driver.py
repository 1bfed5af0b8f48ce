"""The driver contract of the device server (Player's ``Driver`` class, thesis 2.2.1, 3.3.2).

A driver *provides* devices (addresses like ``r0:position2d:0``) and may *require* others, local
or on another server. The server owns all Zenoh entities; a driver only implements:

- ``setup()`` once its required devices are alive (inputs arrive through ``on_input``: a required
  device's ``data`` as its interface's message, ``Position2dData``, ``RangerData``, ...; events as maps);
  compiled kernels are prepared here (:mod:`mrs_bridge.kernels`), before anything is announced;
- ``ready()`` whether it can serve yet: its devices' tokens are declared after ``setup()``, the
  first ``update()`` and once ``ready()`` is true (a map still to arrive by rpc: not yet);
- ``update(now)`` at ``rate`` Hz on the server's single scheduler (publish with ``publish``; data
  nobody subscribes to is dropped, and ``listened(addr)`` tells before a costly message is built,
  ``listen_group(addrs).any`` for several devices at once);
- ``on_cmd(addr, msg)`` for a decoded ``cmd``: the message class the driver declares in
  ``cmd_types`` (``"GoalCmd | VelocityCmd"``), else the interface's (:mod:`rsal.interfaces`), else
  the plain map; raise :class:`~rsal.msgs.MessageError` (or :class:`OutOfRange`) to reject it: the
  server logs a rate-limited warning and nothing changes; ``X.from_dict(msg)`` returns an
  already-typed ``msg`` as is, so drivers written against maps keep working;
- ``on_rpc(addr, op, args)`` returning a result map; raise ``MessageError``/``OutOfRange``/
  :class:`~rsal.msgs.RpcError` for typed error replies, or return a :class:`Deferred` for a long
  operation that the server continues in slices and answers when done;
- ``geometry(addr)`` and ``ops(addr)`` for ``rpc/describe``; ``shutdown()`` to stop motors;
- ``set_online(flag)`` withdraws/re-declares the devices' tokens while hardware is silent;
- ``depends_on`` lists drivers of the same server this one needs (the ``sim`` drivers need the
  ``simulation`` driver's world): when one of them fails, this driver's devices are withdrawn too;
- ``send(addr, msg)`` commands a required device; ``request(addr, op, args)`` calls its rpc without
  blocking and the answer arrives in ``on_reply(addr, op, result, error)``.

Everything runs on the scheduler thread, so drivers need no locks.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

from rsal.keys import DeviceAddr
from rsal.msgs import ErrorCode, MessageError, RpcError

from .config import DriverConfig

if TYPE_CHECKING:
    from .server import DeviceServer

__all__ = ["Driver", "Deferred", "OutOfRange", "DRIVERS", "register"]

log = logging.getLogger(__name__)

DRIVERS: dict[str, type[Driver]] = {}


def register(*names: str):
    """Class decorator: make a driver available to configs under ``names``."""

    def deco(cls):
        for n in names:
            DRIVERS[n] = cls
        cls.driver_name = names[0]
        return cls

    return deco


class OutOfRange(MessageError):
    """A well-formed value outside what the device accepts."""


class Deferred:
    """What ``on_rpc`` returns for an operation too long for one go (e.g. ``step`` of 10,000
    simulation steps): the server calls ``step()`` once per scheduler pass, between the other
    requests and the drivers' updates, until it returns the result map; then it replies. ``step``
    may raise the usual typed errors. Keep each call short (milliseconds)."""

    def __init__(self, step):
        self.step = step


class Driver:
    driver_name: ClassVar[str] = "driver"
    default_rate: ClassVar[float] = 10.0
    #: interfaces this driver can provide ("*" any)
    interfaces: ClassVar[tuple[str, ...]] = ("*",)
    #: message type names for describe
    data_types: ClassVar[dict[str, str]] = {}
    cmd_types: ClassVar[dict[str, str]] = {}
    #: whether the devices' liveliness tokens are declared (hardware drivers start ``False`` and
    #: call :meth:`set_online` when the device answers)
    online: bool = True

    def __init__(self, cfg: DriverConfig, server: DeviceServer):
        self.cfg = cfg
        self.server = server
        self.rate = float(cfg.rate or self.default_rate)
        self.log = logging.getLogger(f"mrs_bridge.{self.driver_name}")
        #: drivers in this server this one cannot work without: when one fails, this one fails too
        #: (its devices are withdrawn)
        self.depends_on: list[Driver] = []
        for a in cfg.provides:
            if "*" not in self.interfaces and a.interface not in self.interfaces:
                raise MessageError(
                    f"{cfg.where}: driver {self.driver_name!r} cannot provide {a.interface!r} "
                    f"(it provides {', '.join(self.interfaces)})"
                )

    # ------------------------------------------------------------------ to override
    def setup(self) -> None:
        """Called once the required devices are alive."""

    def update(self, now: float) -> None:
        """Called at ``rate`` Hz (``rate`` 0: never; the driver publishes on its own events)."""

    def ready(self) -> bool:
        """Whether the devices can serve (e.g. a map that arrives by rpc is in): the server declares
        their tokens after ``setup()``, the first ``update()`` and once this is true."""
        return True

    def on_input(self, addr: DeviceAddr, channel: str, msg: Any) -> None:
        """Data (``channel == "data"``, the interface's message) or events (maps) from a required device."""

    def on_reply(self, addr: DeviceAddr, op: str, result: dict | None, error: RpcError | None) -> None:
        """The answer to :meth:`request` (``error`` set and ``result`` None if it failed)."""

    def on_cmd(self, addr: DeviceAddr, msg: Any) -> None:
        raise MessageError(f"{addr} takes no commands")

    def on_rpc(self, addr: DeviceAddr, op: str, args: dict) -> dict:
        raise RpcError(ErrorCode.UNKNOWN_OP, f"{addr} has no operation {op!r}; it has: {', '.join(self.all_ops(addr))}")

    def ops(self, addr: DeviceAddr) -> list[str]:
        """Operations besides ``describe``."""
        return []

    def geometry(self, addr: DeviceAddr) -> dict[str, Any]:
        return {}

    def shutdown(self) -> None:
        """Stop actuators; called on server stop and when the driver fails."""

    # ------------------------------------------------------------------ helpers
    def all_ops(self, addr: DeviceAddr) -> list[str]:
        return ["describe", *self.ops(addr)]

    def set_online(self, online: bool) -> None:
        """Hardware drivers: withdraw every provided device's token while the device does not
        answer (``False``) and declare them again when it does (``True``)."""
        self.server.set_online(self, online)

    def warn(self, key: str, text: str, level: int = logging.WARNING) -> None:
        """Log ``text`` rate-limited per ``key`` (at most once per 5 s, with a count of the others):
        use it for every message that input from the network can cause."""
        self.server._warn(f"{self.cfg.where}:{key}", text, level)

    def publish(self, addr: DeviceAddr, msg) -> None:
        self.server.publish(addr, msg)

    def listened(self, addr: DeviceAddr) -> bool:
        """Whether anyone subscribes to ``addr``'s ``data`` now (a cached flag): skip building a
        message nobody reads (``publish`` drops it anyway, but only after it was built)."""
        return self.server.listened(addr)

    def listen_group(self, addrs):
        """One flag for several of this driver's devices: the returned object's ``any`` is true
        while someone subscribes to the ``data`` of at least one of them (kept up to date by the
        server; read it once per update instead of :meth:`listened` per device). Call it once
        the devices are declared (from ``update``, not ``__init__``)."""
        return self.server.listen_group(addrs)

    def publish_each(self, addrs, msg) -> None:
        """Publish ``msg`` on each device of ``addrs``, encoded once (one scan on two devices)."""
        self.server.publish_each(addrs, msg)

    def send(self, addr: DeviceAddr, msg) -> None:
        """Command a (required) device: put ``msg`` on its ``cmd`` key."""
        self.server.send(addr, msg)

    def request(self, addr: DeviceAddr, op: str, args: dict | None = None, timeout: float = 5.0) -> None:
        """Call ``rpc/<op>`` of a (required) device without blocking; see :meth:`on_reply`."""
        self.server.request(self, addr, op, args, timeout)

    def required(self, interface: str, key: str | None = None) -> list[DeviceAddr]:
        """Required devices of ``interface`` (and Player role ``key``, e.g. "odometry", if given)."""
        return [r for r in self.cfg.requires if r.interface == interface and (key is None or r.key == key)]

    def event(self, addr: DeviceAddr, msg) -> None:
        self.server.publish_event(addr, msg)

    def provided(self, interface: str, index: int | None = None) -> list[DeviceAddr]:
        return [a for a in self.cfg.provides if a.interface == interface and (index is None or a.index == index)]
