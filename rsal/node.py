"""DeviceNode: discovery of devices by key-expression templates (thesis 3.5, 3.6.2.3).

In Player a ``PlayerClient`` connected to one host:port and listed its devices; the thesis's
DeviceNode wrapped it and "recognised devices that malfunction". Here there is no server to
connect to: a DeviceNode declares a liveliness subscriber (with history, so devices already alive
are reported at once) on each template, keeps the set of alive device addresses, tells listeners
when devices join or leave, and marks the proxies of devices that left as lost.

Templates are key expressions (``rsal/r0/**``, ``rsal/*/ranger/*``) or Player-style patterns
(``r0:*:*``, ``*:laser:*``), see :func:`rsal.keys.template_to_keyexpr`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

import zenoh

from . import keys
from .keys import DeviceAddr

if TYPE_CHECKING:
    from .client import Fabric

__all__ = ["DeviceNode"]


class DeviceNode:
    def __init__(self, fabric: Fabric, templates: Iterable[str] = ("**",)):
        self.fabric = fabric
        self.templates = [keys.template_to_keyexpr(t) for t in templates]
        self._alive: set[DeviceAddr] = set()
        self._cond = threading.Condition()
        self._join: list[Callable[[DeviceAddr], None]] = []
        self._leave: list[Callable[[DeviceAddr], None]] = []
        self._subs = [
            fabric.session.liveliness().declare_subscriber(t, self._on_token, history=True) for t in self.templates
        ]

    def _on_token(self, sample) -> None:
        parsed = keys.parse_key(str(sample.key_expr))
        if parsed is None or parsed[1] != "":
            return
        addr = parsed[0]
        joined = sample.kind == zenoh.SampleKind.PUT
        with self._cond:
            if joined == (addr in self._alive):
                return
            (self._alive.add if joined else self._alive.discard)(addr)
            self._cond.notify_all()
        proxy = self.fabric._proxies.get(addr)
        if proxy is not None:
            proxy._set_alive(joined)
        for fn in self._join if joined else self._leave:
            self.fabric.dispatcher.submit(fn, addr)

    # ------------------------------------------------------------------ queries
    def devices(self) -> list[DeviceAddr]:
        """Alive devices, sorted."""
        with self._cond:
            return sorted(self._alive)

    def is_alive(self, addr: DeviceAddr | str) -> bool:
        a = keys.parse_device(addr) if isinstance(addr, str) else addr.without_key()
        with self._cond:
            return a in self._alive

    def matches(self, template: str) -> list[DeviceAddr]:
        """Alive devices matching a (partial) template, e.g. ``r0:*:*`` or ``*:laser:*``."""
        ke = zenoh.KeyExpr(keys.template_to_keyexpr(template))
        return [a for a in self.devices() if ke.intersects(zenoh.KeyExpr(keys.device_key(a)))]

    def search(
        self, node: str | None = None, interface: str | None = None, index: int | None = None
    ) -> list[DeviceAddr]:
        """Alive devices with the given node / interface / index (None = any)."""
        return [
            a
            for a in self.devices()
            if (node is None or a.node == node)
            and (interface is None or a.interface == interface)
            and (index is None or a.index == index)
        ]

    def nodes(self) -> list[str]:
        return sorted({a.node for a in self.devices()})

    def wait_for(self, template: str, count: int = 1, timeout: float = 10.0) -> list[DeviceAddr]:
        """Block until at least ``count`` alive devices match ``template``; TimeoutError otherwise."""
        deadline = time.monotonic() + timeout
        ke = zenoh.KeyExpr(keys.template_to_keyexpr(template))
        with self._cond:
            while True:
                found = sorted(a for a in self._alive if ke.intersects(zenoh.KeyExpr(keys.device_key(a))))
                if len(found) >= count:
                    return found
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(
                        f"only {len(found)} of {count} device(s) matching {template!r} appeared within {timeout:g} s;"
                        " is the device server running (rsal ls)?"
                    )
                self._cond.wait(left)

    def wait_gone(self, addr: DeviceAddr, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        with self._cond:
            while addr in self._alive:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"{addr} still alive after {timeout:g} s")
                self._cond.wait(left)

    def device(self, addr: DeviceAddr | str):
        """The proxy of a device (its lost flag follows this node's view of liveliness)."""
        p = self.fabric.device(addr)
        p._set_alive(self.is_alive(p.addr))
        return p

    # ------------------------------------------------------------------ listeners
    def on_join(self, fn: Callable[[DeviceAddr], None]) -> None:
        self._join.append(fn)

    def on_leave(self, fn: Callable[[DeviceAddr], None]) -> None:
        self._leave.append(fn)

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:
                pass
        self._subs.clear()
