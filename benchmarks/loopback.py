"""Loopback helpers the benchmarks share: a free TCP port and a plain zenoh-python peer session
(loopback endpoints, multicast scouting off), as a stock client opens it."""

from __future__ import annotations

import json
import socket


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def session(listen: str | None = None, connect: str | None = None):
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    # a peer that only connects would listen on Zenoh's default, every interface
    c.insert_json5("listen/endpoints", json.dumps([listen or "tcp/127.0.0.1:0"]))
    if connect:
        c.insert_json5("connect/endpoints", json.dumps([connect]))
    return zenoh.open(c)
