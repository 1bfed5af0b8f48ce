"""The rmw_zenoh wire: topic keys, the per-message attachment, QoS strings and graph tokens.

What ROS 2's Zenoh middleware (``rmw_zenoh_cpp``, Jazzy and later) puts on plain Zenoh, re-stated
from its source (``liveliness_utils.cpp``, ``attachment_helpers.cpp``, ``qos.cpp``,
``rmw_publisher_data.cpp``) so that any Zenoh peer can join a ROS 2 graph without ROS:

- **topic key** ``<domain>/<topic without leading or trailing '/'>/<DDS type>/<type hash>``,
  e.g. ``0/r0/scan/sensor_msgs::msg::dds_::LaserScan_/RIHS01_64c1...``; the payload is CDR
  (:mod:`mrs_bridge.ros2.types`).
- **attachment** on every put, 33 bytes in Zenoh's own serialisation format: int64 sequence
  number (little-endian, from 1 per publisher), int64 source timestamp (ns since the epoch),
  the GID as a byte sequence (LEB128 length 16, then 16 bytes). rmw_zenoh drops messages
  without it.
- **graph tokens** (liveliness) ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/<kind>/<enclave>/
  <namespace>/<node>[/<topic>/<type>/<hash>/<qos>]``, kind ``NN`` (node), ``MP`` (publisher),
  ``MS`` (subscription), ``SS`` (service), ``SC`` (client); every ``/`` inside a name is written
  ``%`` (the root namespace ``/`` and the default enclave ``/`` become ``%``).
- **QoS** in a token: ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:
  <lifespan s>,<ns>:<liveliness>,<lease s>,<ns>``, each field empty when it equals rmw_zenoh's
  default (reliable, volatile, keep-last 42, infinite durations, automatic liveliness); the
  numbers are the enums of ``rmw/types.h``.

rmw_zenoh derives an entity's GID from the XXH3-128 hash of its token; this module derives it
from BLAKE2b-128 of the token instead (standard library): the GID only has to be unique and
stable, no peer recomputes it.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass, field
from enum import StrEnum

from rsal.errors import RsalError

__all__ = [
    "ADMIN_SPACE",
    "Kind",
    "QoS",
    "DEFAULT_QOS",
    "SENSOR_QOS",
    "Attachment",
    "Entity",
    "topic_key",
    "topic_keyexpr_any_hash",
    "parse_topic_key",
    "mangle",
    "demangle",
    "gid_of",
    "WireError",
]

ADMIN_SPACE = "@ros2_lv"


class WireError(RsalError, ValueError):
    """A key, token or attachment that is not what rmw_zenoh writes."""


class Kind(StrEnum):
    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


def mangle(name: str) -> str:
    """Every ``/`` of a ROS name as ``%`` (one key chunk)."""
    return name.replace("/", "%")


def demangle(chunk: str) -> str:
    return chunk.replace("%", "/")


# ---------------------------------------------------------------------------- topic keys
def _strip(topic: str) -> str:
    t = topic[1:] if topic.startswith("/") else topic
    return t[:-1] if t.endswith("/") else t


def topic_key(domain: int, topic: str, dds_type: str, type_hash: str) -> str:
    """The Zenoh key of a ROS topic: ``<domain>/<topic>/<dds type>/<hash>``."""
    return f"{int(domain)}/{_strip(topic)}/{dds_type}/{type_hash}"


def topic_keyexpr_any_hash(domain: int, topic: str, dds_type: str) -> str:
    """A key expression that matches the topic with any hash chunk (RIHS01 or Humble's
    ``TypeHashNotSupported``): subscribers check the chunk themselves."""
    return f"{int(domain)}/{_strip(topic)}/{dds_type}/*"


def parse_topic_key(key: str) -> tuple[int, str, str, str]:
    """``(domain, "/topic", dds type, hash)`` of a topic key (the topic may hold ``/``)."""
    parts = key.split("/")
    if len(parts) < 4 or not parts[0].isdigit():
        raise WireError(f"key {key!r} is not an rmw_zenoh topic key '<domain>/<topic>/<type>/<hash>'")
    return int(parts[0]), "/" + "/".join(parts[1:-2]), parts[-2], parts[-1]


# ---------------------------------------------------------------------------- QoS
_INF_S, _INF_NS = 9223372036, 854775807  # RMW_DURATION_INFINITE


@dataclass(frozen=True)
class QoS:
    """A ROS 2 QoS profile, enum values of ``rmw/types.h``: reliability 1 reliable, 2 best effort;
    durability 1 transient local, 2 volatile; history 1 keep last, 2 keep all; liveliness 1
    automatic. Durations are ``(sec, nsec)``."""

    reliability: int = 1
    durability: int = 2
    history: int = 1
    depth: int = 42
    deadline: tuple[int, int] = (_INF_S, _INF_NS)
    lifespan: tuple[int, int] = (_INF_S, _INF_NS)
    liveliness: int = 1
    lease: tuple[int, int] = (_INF_S, _INF_NS)

    def to_keyexpr(self) -> str:
        d = _RMW_DEFAULT

        def f(v, dv) -> str:
            return "" if v == dv else str(v)

        return (
            f"{f(self.reliability, d.reliability)}:{f(self.durability, d.durability)}:"
            f"{f(self.history, d.history)},{f(self.depth, d.depth)}:"
            f"{f(self.deadline[0], d.deadline[0])},{f(self.deadline[1], d.deadline[1])}:"
            f"{f(self.lifespan[0], d.lifespan[0])},{f(self.lifespan[1], d.lifespan[1])}:"
            f"{f(self.liveliness, d.liveliness)},{f(self.lease[0], d.lease[0])},{f(self.lease[1], d.lease[1])}"
        )

    @classmethod
    def from_keyexpr(cls, text: str) -> QoS:
        parts = text.split(":")
        try:
            if len(parts) != 6:
                raise ValueError("six ':'-separated fields")
            hist, dl, ls, lv = (p.split(",") for p in parts[2:6])
            if len(hist) != 2 or len(dl) != 2 or len(ls) != 2 or len(lv) != 3:
                raise ValueError("history, deadline, lifespan and liveliness fields")
            d = _RMW_DEFAULT

            def n(s: str, dv: int) -> int:
                if s == "":
                    return dv
                if not s.isdigit():
                    raise ValueError(f"{s!r} is not a number")
                return int(s)

            return cls(
                n(parts[0], d.reliability),
                n(parts[1], d.durability),
                n(hist[0], d.history),
                n(hist[1], d.depth),
                (n(dl[0], d.deadline[0]), n(dl[1], d.deadline[1])),
                (n(ls[0], d.lifespan[0]), n(ls[1], d.lifespan[1])),
                n(lv[0], d.liveliness),
                (n(lv[1], d.lease[0]), n(lv[2], d.lease[1])),
            )
        except ValueError as e:
            raise WireError(f"QoS {text!r} is not rmw_zenoh's form 'R:D:H,depth:s,ns:s,ns:L,s,ns' ({e})") from None


_RMW_DEFAULT = QoS()
#: rclcpp's default publisher/subscription QoS: reliable, volatile, keep last 10
DEFAULT_QOS = QoS(depth=10)
#: rclcpp's sensor-data QoS (``rmw_qos_profile_sensor_data``): best effort, volatile, keep last 5
SENSOR_QOS = QoS(reliability=2, depth=5)


# ---------------------------------------------------------------------------- attachment
_ATT = struct.Struct("<qqB16s")


@dataclass(frozen=True)
class Attachment:
    """The 33-byte attachment of every rmw_zenoh put."""

    sequence: int
    timestamp_ns: int
    gid: bytes

    def to_bytes(self) -> bytes:
        if len(self.gid) != 16:
            raise WireError(f"GID must be 16 bytes, not {len(self.gid)}")
        return _ATT.pack(self.sequence, self.timestamp_ns, 16, self.gid)

    @classmethod
    def from_bytes(cls, data: bytes | bytearray | memoryview | None) -> Attachment:
        if data is None or len(data) != _ATT.size:
            n = "none" if data is None else f"{len(data)} bytes"
            raise WireError(f"attachment must be {_ATT.size} bytes (seq, timestamp, GID), got {n}")
        seq, ts, n, gid = _ATT.unpack(bytes(data))
        if n != 16:
            raise WireError(f"attachment GID length must be 16, got {n}")
        return cls(seq, ts, gid)


def gid_of(token: str) -> bytes:
    """A 16-byte GID for the entity of a graph token (stable, unique per token)."""
    return hashlib.blake2b(token.encode(), digest_size=16).digest()


# ---------------------------------------------------------------------------- graph tokens
@dataclass(frozen=True)
class Entity:
    """One entity of a ROS graph as rmw_zenoh announces it. ``namespace`` and ``node`` as ROS
    writes them (``/r0``, ``rsal``); ``topic`` fully qualified (``/r0/scan``); ``type`` the DDS
    name; ``nid``/``eid`` the node's and the entity's numbers within the session (a node's
    ``eid`` is its ``nid``)."""

    domain: int
    zid: str
    nid: int
    eid: int
    kind: Kind
    namespace: str
    node: str
    enclave: str = "/"
    topic: str = ""
    type: str = ""
    type_hash: str = ""
    qos: QoS = field(default_factory=QoS)

    def __post_init__(self):
        if not self.namespace.startswith("/") or not self.node or "/" in self.node:
            raise WireError(f"node {self.namespace!r}/{self.node!r}: namespace must start with '/', node name no '/'")
        if self.kind is not Kind.NODE and not (self.topic.startswith("/") and self.type and self.type_hash):
            raise WireError(f"{self.kind.name.lower()} needs a fully qualified topic, a type and a hash")

    @property
    def token(self) -> str:
        parts = [
            ADMIN_SPACE,
            str(self.domain),
            self.zid,
            str(self.nid),
            str(self.eid),
            self.kind.value,
            mangle(self.enclave),
            mangle(self.namespace),
            mangle(self.node),
        ]
        if self.kind is not Kind.NODE:
            parts += [mangle(self.topic), mangle(self.type), mangle(self.type_hash), self.qos.to_keyexpr()]
        return "/".join(parts)

    @property
    def gid(self) -> bytes:
        return gid_of(self.token)

    @classmethod
    def parse(cls, token: str) -> Entity:
        """The entity of a graph token (a node's, a publisher's, ...): the inverse of :attr:`token`."""
        parts = token.split("/")
        if len(parts) < 9 or parts[0] != ADMIN_SPACE or any(p == "" for p in parts):
            raise WireError(f"token {token!r} is not an rmw_zenoh graph token '{ADMIN_SPACE}/<domain>/<zid>/...'")
        try:
            kind = Kind(parts[5])
        except ValueError:
            raise WireError(f"token {token!r}: entity kind {parts[5]!r} is none of NN, MP, MS, SS, SC") from None
        if not (parts[1].isdigit() and parts[3].isdigit() and parts[4].isdigit()):
            raise WireError(f"token {token!r}: domain, node id and entity id must be numbers")
        common = dict(
            domain=int(parts[1]),
            zid=parts[2],
            nid=int(parts[3]),
            eid=int(parts[4]),
            kind=kind,
            enclave=demangle(parts[6]),
            namespace=demangle(parts[7]),
            node=demangle(parts[8]),
        )
        if kind is Kind.NODE:
            if len(parts) != 9:
                raise WireError(f"token {token!r}: a node token has 9 parts, not {len(parts)}")
            return cls(**common)
        if len(parts) != 13:
            raise WireError(f"token {token!r}: a {kind.name.lower()} token has 13 parts, not {len(parts)}")
        return cls(
            **common,
            topic=demangle(parts[9]),
            type=demangle(parts[10]),
            type_hash=demangle(parts[11]),
            qos=QoS.from_keyexpr(parts[12]),
        )
