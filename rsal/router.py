"""``rsal router``: a Zenoh router for fleets on several sites or behind access control.

On one machine or one LAN the fleet's processes are peers and need no router (see the README's
Zenoh profiles). Across sites, members run as clients (``--mode client --connect`` or a
``--config`` file) of a router per site, and routers connect to each other; with the secured
profile (``rsal secure``, docs/security.md) the router is where TLS ends, where every member
proves who it is (its own user/password) and where the generated access-control rules give each
identity only its own keys. This is Zenoh's own router (a session in ``router`` mode) with the
``rsal`` transport flags, progress lines and a clean stop on SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import sys

from .cliutil import stop_on_signals
from .transport import DEFAULT_ENDPOINT, TransportArgs, add_transport_args, open_session

__all__ = ["register", "run_router"]


def run_router(args: argparse.Namespace) -> int:
    targs = TransportArgs.from_namespace(args)
    if not targs.config:
        targs.mode = targs.mode or "router"
        if not targs.listen and not targs.connect:
            targs.listen = [DEFAULT_ENDPOINT]
    stop, got = stop_on_signals()
    try:
        session = open_session(targs)
    except ValueError as e:
        print(f"rsal router: {e}", file=sys.stderr, flush=True)
        return 1
    try:
        where = ", ".join(targs.listen) if targs.listen else (targs.config or "the configured endpoints")
        print(f"[router] {session.info.zid()} routing on {where}", flush=True)
        last = None
        while not stop.wait(args.report_every):
            now = (len(list(session.info.routers_zid())), len(list(session.info.peers_zid())))
            if now != last:
                print(f"[router] connected: {now[0]} router(s), {now[1]} peer(s)", flush=True)
                last = now
    finally:
        session.close()
    print(f"[router] stopped ({got[0] if got else 'done'})", flush=True)
    return 0


def register(sub) -> None:
    p = sub.add_parser("router", help="run a Zenoh router (several sites, or the secured profile)")
    p.add_argument(
        "--report-every", type=float, default=5.0, help="seconds between checks of the connections (default 5)"
    )
    add_transport_args(p)
    p.set_defaults(func=run_router)
