"""Who owns a device: owner tokens, and choosing an rpc reply only from the device's owner.

A device server declares, next to a device's liveliness token ``rsal/<node>/<iface>/<idx>``, a
second token naming its own Zenoh session: ``rsal/<node>/<iface>/<idx>/@owner/<zid>``
(:class:`DeviceToken`; docs/protocol.md, "Owner tokens"). ``@owner`` is a verbatim chunk, so no
wildcard matches it: ``rsal/**`` subscribers and queries never see these tokens, only a look-up
that names ``@owner`` does.

A client asks an rpc of every queryable on the key (``QueryTarget.ALL``, no consolidation) and, at
the same time, looks up the device's owner tokens. Zenoh tells which session sent each reply
(``Reply.replier_id``). :func:`choose` then keeps only the owner's reply: a peer that answers on
another device's ``rpc`` key is ignored, counted in :data:`STATS` and logged once. This needs no
Zenoh admin-space query (those deadlock in zenoh 1.10 when the same session declares at the same
time; docs/security.md).

What it does not do: a peer may also declare an owner token for a device it does not serve. Then
two sessions claim the device; a reply from either is refused while both answer (a conflict is
never settled silently), and one line names both sessions. Only the secured profile's access
control, where a host may declare tokens only under its own nodes, stops a peer from claiming.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from .msgs import ErrorCode, RpcError

__all__ = ["OWNER", "STATS", "DeviceToken", "choose", "owner_key", "owners_query", "replier_zid", "session_zid"]

log = logging.getLogger(__name__)

OWNER = "@owner"

#: replies dropped because their session does not own the device (``foreign``), and rpcs refused
#: because more than one owner answered (``conflicts``); per process
STATS = {"foreign": 0, "conflicts": 0}

_logged: set[tuple[str, str]] = set()
_lock = threading.Lock()


def owner_key(device_key: str, zid: str) -> str:
    """The owner token of the device whose liveliness key is ``device_key``, declared by ``zid``."""
    return f"{device_key}/{OWNER}/{zid}"


def owners_query(device_key: str) -> str:
    """The key expression that finds every owner token of a device."""
    return f"{device_key}/{OWNER}/*"


def session_zid(session: Any) -> str | None:
    """The Zenoh id of ``session`` as text, or None if the session cannot tell."""
    try:
        return str(session.info.zid())
    except Exception:
        return None


def replier_zid(reply: Any) -> str | None:
    """The Zenoh id of the session that sent ``reply``, or None if the reply does not say."""
    rid = getattr(reply, "replier_id", None)
    if rid is None:
        return None
    return str(getattr(rid, "zid", rid))


class DeviceToken:
    """A device's liveliness token plus its owner token; ``undeclare()`` withdraws both."""

    def __init__(self, session: Any, device_key: str) -> None:
        live = session.liveliness()
        self._tokens = [live.declare_token(device_key)]
        zid = session_zid(session)
        if zid is not None:
            self._tokens.append(live.declare_token(owner_key(device_key, zid)))

    def undeclare(self) -> None:
        tokens, self._tokens = self._tokens, []
        for t in tokens:
            try:
                t.undeclare()
            except Exception:  # already closed with the session
                pass


def _once(key: str, who: str, text: str) -> None:
    with _lock:
        if (key, who) in _logged:
            return
        _logged.add((key, who))
    log.warning("%s", text)


def choose(key: str, device: str, replies: list[tuple[str | None, Any]], owners: set[str], timeout: float):
    """The reply to use out of ``replies`` (``(replier zid, parsed reply or RpcError)``), given the
    ``owners`` found for ``device``; an :class:`RpcError` if there is none to use.

    With owners known, replies of other sessions are dropped (counted, logged once per device and
    session). A device nobody claims (a server of another implementation) is answered by whoever
    replies, as long as that is one session. Replies of more than one session are a conflict."""
    # A reply without a replier is Zenoh's own (the query's timeout, a routing error): it speaks for
    # no session, and counts only when no session answered at all.
    local = [r for z, r in replies if z is None]
    replies = [(z, r) for z, r in replies if z is not None]
    if not replies and local:
        return local[0]
    if owners:
        mine = [(z, r) for z, r in replies if z in owners]
        for z, _ in replies:
            if z not in owners:
                with _lock:
                    STATS["foreign"] += 1
                _once(
                    key,
                    str(z),
                    f"ignored a reply on {key} from session {z}, which does not own {device} "
                    f"(owner: {', '.join(sorted(owners))}); on an untrusted network use the secured "
                    "profile (docs/security.md)",
                )
    else:
        mine = list(replies)
    sessions = {z for z, _ in mine}
    if len(sessions) > 1:
        with _lock:
            STATS["conflicts"] += 1
        names = ", ".join(sorted(str(z) for z in sessions))
        _once(
            key,
            "conflict:" + names,
            f"refused the replies on {key}: {len(sessions)} sessions answer for {device} ({names})",
        )
        return RpcError(
            ErrorCode.UNAVAILABLE,
            f"{len(sessions)} sessions answer for {device} ({names}); stop the one that should not, "
            "or use the secured profile (docs/security.md)",
            key,
        )
    if mine:
        return mine[0][1]
    if replies:
        return RpcError(ErrorCode.UNAVAILABLE, f"only sessions that do not own {device} answered", key)
    return RpcError(ErrorCode.TIMEOUT, f"no reply within {timeout:g} s (is {device} alive?)", key)
