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
  each time the device joined or left.
"""

from __future__ import annotations

import math
import struct

import ormsgpack

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
]

PROFILE = "rsal"
META_NAME = "rsal.recording"
FORMAT_VERSION = "1"
ENCODING = "msgpack"
#: what a channel holds: device data, events, commands, agent services, rpc replies, tokens
KINDS = ("data", "event", "cmd", "svc", "rpc", "liveliness")
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
