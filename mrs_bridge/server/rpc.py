"""Rpc dispatch of the device server: ``rpc/<op>`` queries, their typed replies and long operations.

Part of :mod:`mrs_bridge.server` (Player's request/reply, thesis 3.5; the reply schema and error
codes of docs/protocol.md). A query is checked (operation name, availability, size) before the
driver sees it; the driver's result becomes an ``ok`` reply and its exception a typed error
(``out_of_range``, ``bad_request``, the :class:`~rsal.msgs.RpcError`'s own code, else ``internal``),
so no request can stop the server. A :class:`~mrs_bridge.driver.Deferred` result keeps the query
open and is continued one slice per scheduler pass: a long operation never freezes the server.

:class:`_Rpc` is a mixin of :class:`~mrs_bridge.server.DeviceServer`: it uses the server's
``devices``, ``stats``, ``_pending``, ``_reported`` and ``_warn``.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from rsal import keys
from rsal.keys import DeviceAddr
from rsal.msgs import Describe, ErrorCode, MessageError, RpcError, decode_map, error_reply, ok_reply

from ..driver import Deferred, OutOfRange
from .intake import MAX_PAYLOAD

if TYPE_CHECKING:
    from .devices import _Device

log = logging.getLogger("mrs_bridge.server")  # the server logs under one name


class _Rpc:
    """Answers the ``rpc`` queries the scheduler takes off the inbox."""

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


def _continue(deferred: Deferred):
    """One slice of a long operation: its result map, or the :class:`Deferred` itself if not done."""
    result = deferred.step()
    return deferred if result is None else result
