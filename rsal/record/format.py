"""How a fabric recording is laid out in an MCAP file (https://mcap.dev, the MCAP specification).

MCAP is the robotics log container of ROS 2 and Foxglove: records grouped in compressed chunks,
indexed by channel and time, readable sequentially when the index at the end is missing (a
recorder that was killed). This module holds the conventions ``rsal record`` writes and
``rsal play`` reads, documented in ``docs/recording.md``:

- the header's profile is :data:`PROFILE` (``rsal``); one metadata record :data:`META_NAME`
  (``rsal.recording``) with the format version, the templates and the start time;
- one channel per Zenoh key, its topic *the key itself* (``rsal/r0/laser/0/data``,
  ``svc/hello/a1``), message encoding ``msgpack``, no schema (schema id 0), channel metadata
  ``kind`` (one of :data:`KINDS`) and, for device keys, ``device`` (``r0:laser:0``);
- a sample's message is its wire bytes, unchanged; ``log_time`` is the receive time (ns since the
  Unix epoch), ``publish_time`` the source time: the message's own ``t`` field (s, on the
  publisher's clock, simulated time under a simulator) in ns, else the receive time;
- ``kind = "rpc"`` channels (``rsal/<dev>/rpc/describe``) hold the device's ``describe`` reply as it
  came (msgpack ``{ok: true, ...}``), recorded when the device appeared;
- ``kind = "liveliness"`` channels (the token key ``rsal/<dev>``) hold msgpack ``{"alive": bool}``
  each time the device joined or left;
- ``kind = "truth"`` channels (``truth/<robot>``, written only by ``rsal tour`` from a simulator)
  hold msgpack ``{"t": s, "pose": [x, y, yaw]}``, the robot's true pose in the world frame; a
  player never publishes them, tools that judge a map read them.

:class:`McapWriter` writes these records for a program that makes a recording without a fabric
(``rsal tour``); the live recorder keeps its own writer thread.
"""

from __future__ import annotations

import math
import os
import struct
from pathlib import Path

import ormsgpack

from .. import keys
from ..errors import RsalError

__all__ = [
    "PROFILE",
    "META_NAME",
    "FORMAT_VERSION",
    "ENCODING",
    "KINDS",
    "MAGIC",
    "RecordingError",
    "source_time_ns",
    "liveliness_message",
    "channel_meta",
    "truth_key",
    "McapWriter",
]

PROFILE = "rsal"
META_NAME = "rsal.recording"
FORMAT_VERSION = "1"
ENCODING = "msgpack"
#: what a channel holds: device data, events, commands, agent services, rpc replies, tokens
KINDS = ("data", "event", "cmd", "svc", "rpc", "liveliness", "truth")
#: topic prefix of the simulator's ground-truth poses (kind ``truth``): ``truth/<robot>``
TRUTH_PREFIX = "truth"
#: the 8 bytes every MCAP file starts (and, when finished, ends) with
MAGIC = b"\x89MCAP0\r\n"


class RecordingError(RsalError, ValueError):
    """A recording that cannot be written or read (not MCAP, empty, nothing to play); one line."""


_T_FIRST = b"\xa1t\xcb"  # a fixmap whose first field is "t", a float64 (the fabric's sensor messages)


def source_time_ns(payload: bytes, default: int) -> int:
    """The message's own ``t`` (seconds) in ns, or ``default`` when it has none or is not a map."""
    if len(payload) >= 12 and 0x80 <= payload[0] <= 0x8F and payload[1:4] == _T_FIRST:
        t = struct.unpack_from(">d", payload, 4)[0]  # fast path: no decoding of the rest (a scan)
        return int(t * 1e9) if math.isfinite(t) and t >= 0 else default
    try:
        m = ormsgpack.unpackb(payload)
    except Exception:
        return default
    t = m.get("t") if isinstance(m, dict) else None
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
        return default
    return int(t * 1e9)


def liveliness_message(alive: bool) -> bytes:
    return ormsgpack.packb({"alive": bool(alive)})


def truth_key(robot: str) -> str:
    """The topic of ``robot``'s ground-truth pose (kind ``truth``)."""
    return f"{TRUTH_PREFIX}/{robot}"


def channel_meta(kind: str, key: str) -> dict[str, str]:
    """A channel's metadata: its ``kind`` and, for a device key, ``device`` (``r0:laser:0``)."""
    meta = {"kind": kind}
    parsed = keys.parse_key(key) if kind != "truth" else None
    if parsed is not None:
        meta["device"] = str(parsed[0])
    return meta


class McapWriter:
    """A recording file written in one go: header and metadata as ``rsal record`` writes them,
    then :meth:`write` per message (channels registered on first use), :meth:`close` for the index."""

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        templates: str = "**",
        library: str = "rsal record",
        started_ns: int = 0,
        chunk_size: int = 256 * 1024,
    ):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._w = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile=PROFILE, library=library)
        self._w.add_metadata(
            META_NAME,
            {
                "format_version": FORMAT_VERSION,
                "protocol_version": str(keys.PROTOCOL_VERSION),
                "templates": templates,
                "commands": "false",
                "services": "false",
                "started_unix_ns": str(started_ns),
                "part": "0",
            },
        )
        self._channels: dict[str, int] = {}
        self.messages = 0

    def write(self, kind: str, key: str, payload: bytes, log_ns: int, publish_ns: int | None = None) -> None:
        ch = self._channels.get(key)
        if ch is None:
            ch = self._channels[key] = self._w.register_channel(key, ENCODING, 0, channel_meta(kind, key))
        pub = source_time_ns(payload, log_ns) if publish_ns is None else publish_ns
        self._w.add_message(ch, log_ns, payload, pub, sequence=self.messages & 0xFFFFFFFF)
        self.messages += 1

    def close(self) -> None:
        self._w.finish()
        self._file.close()

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
