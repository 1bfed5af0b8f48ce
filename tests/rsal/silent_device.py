"""A Zenoh peer that announces devices but never answers them: the "device announced but silent"
case of the error-handling tests.

``python tests/rsal/silent_device.py --listen tcp/127.0.0.1:PORT ADDR...`` declares the liveliness
token of each device address (``node:interface:index``) and a queryable on its ``rpc/**`` keys that
keeps every query unanswered, so a client's query ends in Zenoh's own timeout. It prints ``ready``
once everything is declared and runs until SIGTERM.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

import zenoh

from rsal.keys import device_key, parse_device
from rsal.transport import TransportArgs, make_config


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("addrs", nargs="+", metavar="ADDR")
    ap.add_argument("--listen", action="append", default=[])
    ap.add_argument("--connect", action="append", default=[])
    args = ap.parse_args()
    stop = threading.Event()
    for s in (signal.SIGTERM, signal.SIGINT):
        signal.signal(s, lambda *_: stop.set())
    held: list = []  # queries kept unanswered until the end
    with zenoh.open(make_config(TransportArgs(listen=args.listen, connect=args.connect))) as session:
        handles = []
        for text in args.addrs:
            a = parse_device(text)
            handles.append(session.declare_queryable(f"{device_key(a)}/rpc/**", held.append))
            handles.append(session.liveliness().declare_token(device_key(a)))
        print("ready", flush=True)
        stop.wait()
        held.clear()
    return 0


if __name__ == "__main__":
    sys.exit(main())
