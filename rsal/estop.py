"""The emergency stop of one robot or of the whole fabric, as one Zenoh query.

Every base (a ``position2d`` that moves a robot: ``sim``, ``p2os``, a local planner's output)
answers ``rpc/estop`` (latch) and ``rpc/release``. :func:`estop` sends one ``get`` on
``rsal/<node>/position2d/*/rpc/<op>`` -- ``<node>`` ``*`` for the whole fabric -- with
``QueryTarget.ALL`` and no consolidation, so every base answers separately and the caller sees
which ones confirmed. A ``position2d`` that is not a base (``amcl``'s map-frame pose) answers
``unknown_op`` and is left out. The protocol is in docs/protocol.md, "Emergency stop".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import zenoh

from . import keys
from .keys import DeviceAddr
from .msgs import ErrorCode, RpcError, encode, parse_reply

__all__ = ["EstopResult", "estop"]


@dataclass
class EstopResult:
    """Which bases confirmed (``confirmed``, by device) and which refused (``failed``: messages)."""

    op: str
    confirmed: list[DeviceAddr] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)

    @property
    def robots(self) -> list[str]:
        """The nodes (robots) with at least one base that confirmed, sorted."""
        return sorted({a.node for a in self.confirmed})

    def summary(self) -> str:
        """One line: ``latched: r0 (position2d:0, position2d:1), r1 (position2d:0)``."""
        verb = "latched" if self.op == "estop" else "released"
        parts = []
        for node in self.robots:
            mine = sorted((a for a in self.confirmed if a.node == node), key=lambda a: a.index)
            devs = ", ".join(f"position2d:{a.index}" for a in mine)
            parts.append(f"{node} ({devs})")
        return f"{verb}: {', '.join(parts) if parts else 'no robot'}"


def estop(
    session: zenoh.Session, node: str | None = None, *, release: bool = False, timeout: float = 2.0
) -> EstopResult:
    """Press (or ``release``) the emergency stop of every base of ``node``, or of every node if
    None; blocks until every base answered or ``timeout`` s passed."""
    op = "release" if release else "estop"
    result = EstopResult(op)
    replies = session.get(
        keys.bases_rpc_keyexpr(op, node),
        payload=encode({}),
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=timeout,
    )
    for reply in replies:
        try:
            if reply.ok is not None:
                key = str(reply.ok.key_expr)
                parse_reply(reply.ok.payload.to_bytes(), key=key)
                parsed = keys.parse_key(key)
                if parsed is not None and parsed[0] not in result.confirmed:
                    result.confirmed.append(parsed[0])
            else:
                parse_reply(reply.err.payload.to_bytes(), is_error=True)
        except RpcError as e:
            if e.code == ErrorCode.UNKNOWN_OP:  # a position2d that moves nothing (amcl's pose)
                continue
            result.failed.append(e.message)
    return result
