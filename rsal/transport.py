"""Opening Zenoh sessions the RSAL way: loopback by default, multicast scouting off.

Every ``rsal`` command takes the transport flags of the zenoh examples, defined once here:
``--mode``, ``--connect``, ``--listen``, ``--config`` and ``--cfg KEY:VALUE``. With none of them a
device server listens on ``tcp/127.0.0.1:7447`` (or, if another server already does, on a free
loopback port and connects to 7447) and every other process connects to ``tcp/127.0.0.1:7447``;
peers then find each other by gossip. Multicast scouting stays off unless a config file turns it
on (only inside network namespaces the tests create).

A peer that only connects still listens, so that the peers it learns of by gossip can reach it
directly; Zenoh's own default for that is every interface (``tcp/[::]:0``). When every endpoint it
connects to is on this machine (loopback or a Unix socket) it listens on ``tcp/127.0.0.1:0``
instead: a fabric on loopback opens no port to the network.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import os
import socket
from dataclasses import dataclass, field

import zenoh

from .errnet import ENDPOINT_FORM, zenoh_summary, zenoh_text

__all__ = [
    "DEFAULT_ENDPOINT",
    "LOOPBACK_ANY",
    "ZENOH_RUNTIME",
    "TransportArgs",
    "add_transport_args",
    "make_config",
    "free_port",
    "open_session",
    "port_free",
]

DEFAULT_ENDPOINT = os.environ.get("RSAL_ENDPOINT", "tcp/127.0.0.1:7447")
#: where a peer that connects only to this machine listens (any free loopback port)
LOOPBACK_ANY = "tcp/127.0.0.1:0"

#: Zenoh's runtimes for the sessions of this process (the ``ZENOH_RUNTIME`` environment variable,
#: read once, when the first session opens; a value set by the user wins). With Zenoh's built-in
#: receive runtime, the tokens of a host whose cable was cut outlived their lease by Zenoh's 10 s
#: TCP linger in about half of the cuts when a peer had two links to that host; with eight
#: receive workers and fifty blocking threads they went within the lease in every cut measured
#: (docs/deployment.md, "Leases and cut links").
ZENOH_RUNTIME = "(rx: (worker_threads: 8, max_blocking_threads: 50))"


@dataclass
class TransportArgs:
    mode: str | None = None  # None: the config file's mode, else peer
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    config: str | None = None
    cfg: list[str] = field(default_factory=list)

    @classmethod
    def from_namespace(cls, ns: argparse.Namespace) -> TransportArgs:
        return cls(
            mode=getattr(ns, "mode", None),
            connect=list(getattr(ns, "connect", None) or []),
            listen=list(getattr(ns, "listen", None) or []),
            config=getattr(ns, "config", None),
            cfg=list(getattr(ns, "cfg", None) or []),
        )


def add_transport_args(p: argparse.ArgumentParser) -> None:
    """The zenoh examples' transport flags."""
    g = p.add_argument_group("transport (Zenoh)")
    g.add_argument(
        "--mode",
        "-m",
        choices=("peer", "client", "router"),
        help="Zenoh mode (default: the --config file's, else peer)",
    )
    g.add_argument(
        "--connect",
        "-e",
        action="append",
        metavar="ENDPOINT",
        help=f"endpoint to connect to (repeatable; default {DEFAULT_ENDPOINT})",
    )
    g.add_argument("--listen", "-l", action="append", metavar="ENDPOINT", help="endpoint to listen on (repeatable)")
    g.add_argument("--config", "-c", metavar="FILE", help="a Zenoh JSON5 configuration file")
    g.add_argument(
        "--cfg",
        action="append",
        metavar="KEY:VALUE",
        help="a Zenoh configuration entry, VALUE in JSON5, e.g. --cfg 'transport/shared_memory/enabled:false'",
    )


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (for a child or a fabric to listen on)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_free(endpoint: str) -> bool:
    """True if a ``tcp/HOST:PORT`` endpoint can be bound now."""
    try:
        proto, addr = endpoint.split("/", 1)
        host, port = addr.rsplit(":", 1)
        if proto != "tcp":
            return True
        with socket.socket(socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((host.strip("[]"), int(port)))
        return True
    except (OSError, ValueError):
        return False


def _insert_endpoints(conf: zenoh.Config, what: str, endpoints: list[str]) -> None:
    try:
        conf.insert_json5(f"{what}/endpoints", json.dumps(endpoints))
    except Exception as e:  # ZError: the syntax of one of them
        bad = [x for x in endpoints if not _endpoint_ok(what, x)] or endpoints
        raise ValueError(f"bad --{what} endpoint {' '.join(bad)!r} ({zenoh_text(e)}); {ENDPOINT_FORM}") from None


def _on_this_machine(endpoint: str) -> bool:
    """Whether ``endpoint`` (``proto/address[?meta][#config]``) is a loopback address or a Unix socket."""
    proto, _, address = endpoint.partition("/")
    if proto.startswith("unixsock"):
        return True
    host = address.split("?", 1)[0].split("#", 1)[0].rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a name: it may be another machine
        return False


def _endpoint_ok(what: str, endpoint: str) -> bool:
    try:
        zenoh.Config().insert_json5(f"{what}/endpoints", json.dumps([endpoint]))
        return True
    except Exception:
        return False


def make_config(args: TransportArgs | None = None, *, server: bool = False) -> zenoh.Config:
    """A Zenoh config from the flags; ``server`` applies the device server's listen default."""
    a = args or TransportArgs()
    if a.config:
        try:
            conf = zenoh.Config.from_file(a.config)
        except Exception as e:  # zenoh raises ZError with the parser's message
            raise ValueError(f"Zenoh config {a.config!r} cannot be read: {zenoh_text(e)}") from None
    else:
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
    if a.mode or not a.config:
        conf.insert_json5("mode", json.dumps(a.mode or "peer"))
    listen = list(a.listen)
    connect = list(a.connect)
    if not a.config and not listen and not connect:
        if server and port_free(DEFAULT_ENDPOINT):
            listen = [DEFAULT_ENDPOINT]
        elif server:
            listen = [LOOPBACK_ANY]
            connect = [DEFAULT_ENDPOINT]
        else:
            connect = [DEFAULT_ENDPOINT]
    if not a.config and not listen and connect and (a.mode or "peer") == "peer" and all(map(_on_this_machine, connect)):
        listen = [LOOPBACK_ANY]  # not Zenoh's every-interface default: see the module docstring
    if listen:
        _insert_endpoints(conf, "listen", listen)
    if connect:
        _insert_endpoints(conf, "connect", connect)
        # Keep retrying the connection so a client may start before its server.
        conf.insert_json5("connect/timeout_ms", "-1")
        conf.insert_json5("connect/exit_on_failure", "false")
    for item in a.cfg:
        if ":" not in item:
            raise ValueError(f"--cfg {item!r} must be KEY:VALUE")
        k, v = item.split(":", 1)
        try:
            conf.insert_json5(k, v)
        except Exception as e:
            raise ValueError(f"--cfg {item!r}: {zenoh_text(e)}") from None
    return conf


def open_session(args: TransportArgs | None = None, *, server: bool = False) -> zenoh.Session:
    """Open a Zenoh session; errors become ``ValueError`` with one line."""
    conf = make_config(args, server=server)
    os.environ.setdefault("ZENOH_RUNTIME", ZENOH_RUNTIME)
    try:
        return zenoh.open(conf)
    except Exception as e:
        text = zenoh_text(e)
        raise ValueError(zenoh_summary(text) or f"cannot open a Zenoh session: {text}") from None
