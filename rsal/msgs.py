"""The message schema: every payload on the key space, defined once, validated on decode.

Payloads are msgpack maps with short string keys; numbers are SI (m, rad, s); arrays of ranges
travel as packed little-endian float32 ``bytes``. Every type here is a frozen dataclass with
``to_dict()`` / ``from_dict()`` and :func:`encode` / :func:`decode` for bytes. Decoding checks
types, finiteness and required fields and raises :class:`MessageError`, whose text names the
field and what was expected, so a device server can answer or log one line and carry on.

RPC replies: success is ``{"ok": true, ...result}``; failure is sent with Zenoh's ``reply_err``
as ``{"ok": false, "code": <ErrorCode>, "message": str}``. ``docs/protocol.md`` documents every
message; this module is the implementation of that document.
"""

from __future__ import annotations

import math
import struct
from dataclasses import asdict, dataclass, field, fields
from enum import StrEnum
from typing import Any, ClassVar

import msgpack
import numpy as np
import ormsgpack

from .errors import RsalError

__all__ = [
    "MessageError",
    "ErrorCode",
    "RpcError",
    "encode",
    "decode",
    "decode_map",
    "ok_reply",
    "error_reply",
    "parse_reply",
    "VelocityCmd",
    "Position2dData",
    "RangerData",
    "BlobData",
    "BlobfinderData",
    "GripperData",
    "GripperCmd",
    "PowerData",
    "DioData",
    "DioCmd",
    "ActArrayData",
    "ACTUATOR_STATES",
    "SimulationData",
    "MapData",
    "GoalCmd",
    "Hypothesis",
    "LocalizeData",
    "PlannerData",
    "PLANNER_STATUS",
    "Describe",
    "f32_bytes",
    "f32_array",
    "get_float",
    "get_vec",
    "get_str",
    "get_bool",
    "get_int",
]

PROTOCOL_VERSION = 1


class MessageError(RsalError, ValueError):
    """A payload that does not match its schema; the text names the field."""


class ErrorCode(StrEnum):
    """Error codes of RPC replies."""

    BAD_REQUEST = "bad_request"  # not msgpack, wrong fields or types, NaN/inf
    OUT_OF_RANGE = "out_of_range"  # well-formed but outside what the device accepts
    UNKNOWN_OP = "unknown_op"  # the device has no such operation
    NOT_FOUND = "not_found"  # a named thing (model, goal) does not exist
    UNAVAILABLE = "unavailable"  # the device cannot do it now (required device lost, busy)
    ESTOP = "estop"  # the base's emergency stop is latched: it refuses to move until released
    INTERNAL = "internal"  # the driver failed; see the server log
    TOO_LARGE = "too_large"  # the request payload is over the server's limit; not decoded
    BUSY = "busy"  # the server's inbox is full; try again later
    TIMEOUT = "timeout"  # (client side) no reply within the deadline


class RpcError(RsalError):
    """An RPC answered with an error (or not at all)."""

    def __init__(self, code: str, message: str, key: str = ""):
        self.code = str(code)
        self.message = str(message)
        self.key = key
        super().__init__(f"{key + ': ' if key else ''}{self.code}: {self.message}")


# ---------------------------------------------------------------------------- codec
# Encoding uses ormsgpack (Rust): 2.7x faster than msgpack-python's ``packb`` on a laser scan
# (0.29 vs 0.79 us per scan map, timeit on the reference machine), with the same bytes for every
# type the schema uses (a fuzz of 3,000 random maps found no difference).
# Numpy scalars and int map keys are accepted as msgpack-python accepts them; anything ormsgpack
# refuses (e.g. an int beyond 64 bits) goes to msgpack-python, which packs it or names the problem.
# Decoding stays with msgpack-python: it rejects trailing bytes after the map, ormsgpack ignores them.
_packb = msgpack.packb
_orpack = ormsgpack.packb
_OR_OPTS = ormsgpack.OPT_NON_STR_KEYS | ormsgpack.OPT_SERIALIZE_NUMPY
_unpackb = msgpack.unpackb


def _pack_map(m: Any) -> bytes:
    try:
        return _orpack(m, None, _OR_OPTS)
    except TypeError:
        return _packb(m, use_bin_type=True)


def encode(obj: Any) -> bytes:
    """msgpack bytes of a message (a class here, or any object with ``to_dict``) or a plain map."""
    if type(obj) is not dict:  # the hot path: a message class
        pack = getattr(obj, "to_msgpack", None)
        if pack is not None:
            return pack()
        to_dict = getattr(obj, "to_dict", None)
        if to_dict is not None:
            obj = to_dict()
    return _pack_map(obj)


def decode_map(data: bytes | bytearray | memoryview | None) -> dict:
    """Bytes to a msgpack map; raises MessageError for anything else. Empty payload = ``{}``."""
    try:
        obj = _unpackb(data, raw=False, strict_map_key=False)  # any buffer; None raises
    except Exception as e:  # msgpack raises several unrelated exception types
        if data is None or len(data) == 0:
            return {}
        raise MessageError(f"payload is not msgpack ({type(e).__name__})") from None
    if type(obj) is not dict:
        raise MessageError(f"payload must be a msgpack map, not {type(obj).__name__}")
    return obj


def decode(cls, data: bytes | bytearray | memoryview | None):
    """Bytes to an instance of the message class ``cls`` (validated)."""
    from_bytes = getattr(cls, "from_bytes", None)
    return from_bytes(data) if from_bytes is not None else cls.from_dict(decode_map(data))


def ok_reply(**result: Any) -> bytes:
    return encode({"ok": True, **result})


def error_reply(code: ErrorCode | str, message: str) -> bytes:
    return encode({"ok": False, "code": str(code), "message": str(message)})


def parse_reply(data: bytes, *, is_error: bool = False, key: str = "", timeout: float | None = None) -> dict:
    """Decode an RPC reply; raise :class:`RpcError` for an error reply or a malformed one
    (``timeout``, the query's, is named in a transport timeout's message)."""
    try:
        m = decode_map(data)
    except MessageError as e:
        if is_error:  # an error from the transport itself (e.g. Zenoh's "Timeout"), not from a device
            text = bytes(data).decode("utf-8", "replace").strip() or "error"
            code = ErrorCode.TIMEOUT if "timeout" in text.lower() else ErrorCode.UNAVAILABLE
            within = f" within {timeout:g} s" if timeout is not None else ""
            raise RpcError(code, f"no answer from the device{within}: {text}", key) from None
        raise RpcError(ErrorCode.BAD_REQUEST, f"malformed reply: {e}", key) from None
    if is_error or not m.get("ok", False):
        raise RpcError(m.get("code", ErrorCode.INTERNAL), m.get("message", "error without a message"), key)
    return m


# ---------------------------------------------------------------------------- field readers
def _need(m: dict, name: str, required: bool):
    if name not in m or m[name] is None:
        if required:
            raise MessageError(f"field {name!r} is missing")
        return None
    return m[name]


def get_float(m: dict, name: str, default: float | None = None, *, lo: float = -math.inf, hi: float = math.inf):
    v = m.get(name)
    if type(v) is float and lo <= v <= hi and v - v == 0.0:  # fast path: a finite float in range
        return v
    v = _need(m, name, default is None)
    if v is None:
        return default
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MessageError(f"field {name!r} must be a number, not {type(v).__name__}")
    v = float(v)
    if not math.isfinite(v):
        raise MessageError(f"field {name!r} must be finite, not {v}")
    if not lo <= v <= hi:
        raise MessageError(f"field {name!r} = {v} is outside [{lo}, {hi}]")
    return v


def get_int(m: dict, name: str, default: int | None = None, *, lo: int | None = None, hi: int | None = None):
    v = _need(m, name, default is None)
    if v is None:
        return default
    if isinstance(v, bool) or not isinstance(v, int):
        raise MessageError(f"field {name!r} must be an integer, not {type(v).__name__}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise MessageError(f"field {name!r} = {v} is outside [{lo}, {hi}]")
    return v


def get_bool(m: dict, name: str, default: bool | None = None) -> bool:
    v = _need(m, name, default is None)
    if v is None:
        return bool(default)
    if not isinstance(v, bool):
        raise MessageError(f"field {name!r} must be true or false, not {type(v).__name__}")
    return v


def get_str(m: dict, name: str, default: str | None = None, *, choices=None, optional: bool = False):
    v = _need(m, name, default is None and not optional)
    if v is None:
        return default
    if not isinstance(v, str):
        raise MessageError(f"field {name!r} must be a string, not {type(v).__name__}")
    if choices is not None and v not in choices:
        raise MessageError(f"field {name!r} = {v!r} must be one of {', '.join(map(str, choices))}")
    return v


def get_vec(m: dict, name: str, n: int, default: tuple | None = None) -> tuple[float, ...]:
    v = _need(m, name, default is None)
    if v is None:
        return default  # type: ignore[return-value]
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise MessageError(f"field {name!r} must be a list of {n} numbers")
    out = []
    for i, x in enumerate(v):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(float(x)):
            raise MessageError(f"field {name!r}[{i}] must be a finite number, not {x!r}")
        out.append(float(x))
    return tuple(out)


_F32 = np.dtype("<f4")
_frombuffer = np.frombuffer


def f32_bytes(a) -> bytes:
    return np.ascontiguousarray(a, dtype="<f4").tobytes()


def f32_array(m: dict, name: str) -> np.ndarray:
    v = m.get(name)
    if type(v) is bytes and not len(v) & 3:  # fast path
        return np.frombuffer(v, dtype="<f4")
    v = _need(m, name, True)
    if not isinstance(v, (bytes, bytearray)):
        raise MessageError(f"field {name!r} must be packed float32 bytes, not {type(v).__name__}")
    if len(v) % 4:
        raise MessageError(f"field {name!r} has {len(v)} bytes, not a whole number of float32")
    return np.frombuffer(v, dtype="<f4")


class _Msg:
    """Common ``to_dict`` for message dataclasses (tuples become lists, arrays float32 bytes)."""

    __slots__ = ()
    _field_names: ClassVar[tuple[str, ...]] = ()

    def to_msgpack(self) -> bytes:
        """The message's payload bytes (what :func:`encode` returns for it)."""
        return _pack_map(self.to_dict())

    @classmethod
    def from_bytes(cls, data: bytes | bytearray | memoryview | None):
        """Decode and validate a payload (what :func:`decode` does for this class)."""
        return cls.from_dict(decode_map(data))

    def to_dict(self) -> dict:
        names = type(self).__dict__.get("_field_names")
        if not names:  # computed once per class: dataclasses.fields() is slow on a hot path
            names = tuple(f.name for f in fields(self))  # type: ignore[arg-type]
            type(self)._field_names = names
        d = {}
        for name in names:
            v = getattr(self, name)
            if type(v) is float or type(v) is int or type(v) is str:
                pass
            elif isinstance(v, np.ndarray):
                v = f32_bytes(v)
            elif isinstance(v, tuple):
                v = list(v)
            elif isinstance(v, list) and v and hasattr(v[0], "to_dict"):
                v = [x.to_dict() for x in v]
            d[name] = v
        return d


# ---------------------------------------------------------------------------- position2d
@dataclass(frozen=True)
class VelocityCmd(_Msg):
    """position2d ``cmd``: forward speed ``v`` (m/s), sideways ``vy`` (m/s, 0 for a diff drive),
    turn rate ``w`` (rad/s). Player's ``SetSpeed``."""

    v: float
    w: float
    vy: float = 0.0

    @classmethod
    def from_dict(cls, m: dict) -> VelocityCmd:
        return cls(get_float(m, "v"), get_float(m, "w"), get_float(m, "vy", 0.0))


@dataclass(slots=True)  # not frozen: a frozen init costs 4x on this hot path; treat as immutable
class Position2dData(_Msg):
    """position2d ``data``: pose (x, y, yaw) in the device's frame (odometry or map), velocity
    (vx, vy, w) in the robot frame, stall flag; ``timed_out``: the base stopped itself because its
    velocity command was not refreshed within its ``cmd_timeout``; ``estop``: its emergency stop is
    latched."""

    t: float
    pose: tuple[float, float, float]
    vel: tuple[float, float, float]
    stall: bool = False
    timed_out: bool = False
    estop: bool = False

    @classmethod
    def from_dict(cls, m: dict) -> Position2dData:
        return cls(
            get_float(m, "t"),
            get_vec(m, "pose", 3),
            get_vec(m, "vel", 3),
            get_bool(m, "stall", False),
            get_bool(m, "timed_out", False),
            get_bool(m, "estop", False),
        )


# ---------------------------------------------------------------------------- ranger / laser / sonar
@dataclass(slots=True, eq=False)  # not frozen: a frozen init costs 4x on this hot path; treat as immutable
class RangerData(_Msg):
    """ranger, laser and sonar ``data``: ``ranges`` (float32 bytes on the wire, metres). For a
    laser, beam ``i`` points at ``angle_min + i * angle_step`` (rad, in the ranger's frame, whose
    pose on the robot is ``rpc/describe`` geometry ``pose``); a sonar's transducer poses are in
    ``rpc/describe`` geometry ``sensors``."""

    t: float
    ranges: np.ndarray
    angle_min: float = 0.0
    angle_step: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0

    @classmethod
    def from_dict(cls, m: dict) -> RangerData:
        try:
            t, r, a0, da = m["t"], m["ranges"], m["angle_min"], m["angle_step"]
            lo, hi = m["range_min"], m["range_max"]
        except KeyError:
            pass
        else:
            if (  # fast path: every field present and well-typed; x - x is NaN for inf and NaN
                type(t) is type(a0) is type(da) is type(lo) is type(hi) is float
                and (t - t) + (a0 - a0) + (da - da) + (lo - lo) + (hi - hi) == 0.0
                and type(r) is bytes
                and not len(r) & 3
            ):
                return cls(t, _frombuffer(r, _F32), a0, da, lo, hi)
        return cls(
            get_float(m, "t"),
            f32_array(m, "ranges"),
            get_float(m, "angle_min", 0.0),
            get_float(m, "angle_step", 0.0),
            get_float(m, "range_min", 0.0),
            get_float(m, "range_max", 0.0),
        )

    def to_dict(self) -> dict:  # explicit: the hottest message on the fabric
        r = self.ranges
        return {
            "t": self.t,
            "ranges": r.tobytes() if r.dtype is _F32 else f32_bytes(r),
            "angle_min": self.angle_min,
            "angle_step": self.angle_step,
            "range_min": self.range_min,
            "range_max": self.range_max,
        }

    # The wire fast path. Every scan a server sends has the same layout: this map's six keys in
    # field order, five float64 and one bin. Packing that layout with two precompiled structs and
    # reading it back the same way (the ranges a view into the payload, no copy) takes about half
    # the time of building and walking a generic map (docs/benchmarks.md). The bytes are exactly
    # msgpack's (a test compares them); any other layout -- another key order, float32 or integer
    # fields, extra keys, trailing bytes -- takes the generic path, with its checks and errors.
    def to_msgpack(self) -> bytes:
        t, r, a0, da, lo, hi = self.t, self.ranges, self.angle_min, self.angle_step, self.range_min, self.range_max
        if (
            type(t) is type(a0) is type(da) is type(lo) is type(hi) is float
            and type(r) is np.ndarray
            and r.dtype is _F32
        ):
            rb = r.tobytes()
            n = len(rb)
            if n < 0x10000:
                head = _RD_HEAD16.pack(_RD_T, t, _RD_R16, n) if n > 0xFF else _RD_HEAD8.pack(_RD_T, t, _RD_R8, n)
                return b"".join((head, rb, _RD_TAIL.pack(_RD_K0, a0, _RD_K1, da, _RD_K2, lo, _RD_K3, hi)))
        return _pack_map(self.to_dict())

    @classmethod
    def from_bytes(cls, data: bytes | bytearray | memoryview | None) -> RangerData:
        if type(data) is bytes and len(data) >= _RD_MIN:
            head, t, key, n = _RD_HEAD16.unpack_from(data)
            if head == _RD_T and key == _RD_R16 and len(data) == _RD_MIN + 1 + n and not n & 3:
                k0, a0, k1, da, k2, lo, k3, hi = _RD_TAIL.unpack_from(data, 22 + n)
                if (k0, k1, k2, k3) == _RD_KEYS and (t - t) + (a0 - a0) + (da - da) + (lo - lo) + (hi - hi) == 0.0:
                    return cls(t, _frombuffer(data, _F32, n >> 2, 22), a0, da, lo, hi)
        return cls.from_dict(decode_map(data))


# RangerData's wire layout: fixmap(6) "t" float64, "ranges" bin8/bin16 <n bytes>, then the four
# float64 fields. Only bin16 payloads (256 B to 64 kB of ranges: 64 to 16383 beams) are read by
# the fast path; shorter and longer scans are still written by it where they fit, and read generically.
_RD_T = 0x86A174CB  # fixmap(6), fixstr "t", float64 marker
_RD_R8, _RD_R16 = b"\xa6ranges\xc4", b"\xa6ranges\xc5"
_RD_HEAD8 = struct.Struct(">Id8sB")
_RD_HEAD16 = struct.Struct(">Id8sH")
_RD_K0, _RD_K1, _RD_K2, _RD_K3 = (
    b"\xa9angle_min\xcb",
    b"\xaaangle_step\xcb",
    b"\xa9range_min\xcb",
    b"\xa9range_max\xcb",
)
_RD_KEYS = (_RD_K0, _RD_K1, _RD_K2, _RD_K3)
_RD_TAIL = struct.Struct(">11sd12sd11sd11sd")
_RD_MIN = _RD_HEAD8.size + _RD_TAIL.size  # 98: the bin8 header is one byte shorter than bin16's


# ---------------------------------------------------------------------------- blobfinder
@dataclass(frozen=True)
class BlobData(_Msg):
    """One blob: colour 0xRRGGBB, image box and centre (pixels), area, range (m), bearing (rad)."""

    id: int
    color: int
    x: int
    y: int
    left: int
    right: int
    top: int
    bottom: int
    area: int
    range: float
    bearing: float

    @classmethod
    def from_dict(cls, m: dict) -> BlobData:
        if not isinstance(m, dict):
            raise MessageError("each blob must be a map")
        ints = {k: get_int(m, k, 0) for k in ("id", "x", "y", "left", "right", "top", "bottom", "area")}
        return cls(
            color=get_int(m, "color", lo=0, hi=0xFFFFFF),
            range=get_float(m, "range"),
            bearing=get_float(m, "bearing", 0.0),
            **ints,
        )


@dataclass(frozen=True)
class BlobfinderData(_Msg):
    t: float
    width: int
    height: int
    blobs: list[BlobData] = field(default_factory=list)

    @classmethod
    def from_dict(cls, m: dict) -> BlobfinderData:
        raw = _need(m, "blobs", True)
        if not isinstance(raw, list):
            raise MessageError("field 'blobs' must be a list")
        return cls(
            get_float(m, "t"),
            get_int(m, "width", lo=0),
            get_int(m, "height", lo=0),
            [BlobData.from_dict(b) for b in raw],
        )

    def to_dict(self) -> dict:
        return {"t": self.t, "width": self.width, "height": self.height, "blobs": [asdict(b) for b in self.blobs]}


# ---------------------------------------------------------------------------- gripper
GRIPPER_ACTIONS = ("open", "close", "stop", "up", "down")


@dataclass(frozen=True)
class GripperCmd(_Msg):
    """gripper ``cmd``: one of open, close, stop (paddles), up, down (lift)."""

    action: str

    @classmethod
    def from_dict(cls, m: dict) -> GripperCmd:
        return cls(get_str(m, "action", choices=GRIPPER_ACTIONS))


@dataclass(frozen=True)
class GripperData(_Msg):
    """gripper ``data``: paddles open/closed/opening/closing, lift down/up/raising/lowering,
    beams bit 0 inner and bit 1 outer, ``stored`` objects held (0 or 1) and what is carried."""

    t: float
    paddles: str
    lift: str
    beams: int
    stored: int
    carrying: str | None = None

    @classmethod
    def from_dict(cls, m: dict) -> GripperData:
        return cls(
            get_float(m, "t"),
            get_str(m, "paddles", choices=("open", "closed", "opening", "closing", "error")),
            get_str(m, "lift", "down", choices=("down", "up", "raising", "lowering", "error")),
            get_int(m, "beams", 0, lo=0, hi=3),
            get_int(m, "stored", 0, lo=0),
            get_str(m, "carrying", optional=True),
        )


# ---------------------------------------------------------------------------- power
@dataclass(frozen=True)
class PowerData(_Msg):
    t: float
    volts: float
    percent: float
    charging: bool = False

    @classmethod
    def from_dict(cls, m: dict) -> PowerData:
        return cls(
            get_float(m, "t"),
            get_float(m, "volts"),
            get_float(m, "percent", lo=0, hi=100),
            get_bool(m, "charging", False),
        )


# ---------------------------------------------------------------------------- dio / actarray
@dataclass(frozen=True)
class DioData(_Msg):
    """dio ``data``: ``count`` digital inputs as the bit field ``bits`` (input i is bit i) and the
    current digital outputs ``outputs``. Player's ``player_dio_data``."""

    t: float
    count: int
    bits: int
    outputs: int = 0

    @classmethod
    def from_dict(cls, m: dict) -> DioData:
        count = get_int(m, "count", lo=0, hi=32)
        hi = (1 << count) - 1
        return cls(get_float(m, "t"), count, get_int(m, "bits", lo=0, hi=hi), get_int(m, "outputs", 0, lo=0, hi=0xFFFF))


@dataclass(frozen=True)
class DioCmd(_Msg):
    """dio ``cmd``: set the digital outputs selected by ``mask`` to the matching bits of ``bits``."""

    bits: int
    mask: int = 0xFF

    @classmethod
    def from_dict(cls, m: dict) -> DioCmd:
        return cls(get_int(m, "bits", lo=0, hi=0xFF), get_int(m, "mask", 0xFF, lo=0, hi=0xFF))


ACTUATOR_STATES = ("idle", "moving", "braked", "stalled")


@dataclass(frozen=True)
class ActArrayData(_Msg):
    """actarray ``data``: per actuator its position (m for a linear joint, rad for a rotary one),
    speed and state (idle, moving, braked, stalled). Player's ``player_actarray_data``."""

    t: float
    positions: tuple[float, ...]
    speeds: tuple[float, ...]
    states: tuple[str, ...]

    @classmethod
    def from_dict(cls, m: dict) -> ActArrayData:
        pos, spd, st = (_need(m, k, True) for k in ("positions", "speeds", "states"))
        if not all(isinstance(v, (list, tuple)) for v in (pos, spd, st)) or not len(pos) == len(spd) == len(st):
            raise MessageError("fields 'positions', 'speeds' and 'states' must be lists of the same length")
        n = len(pos)
        return cls(
            get_float(m, "t"),
            get_vec(m, "positions", n),
            get_vec(m, "speeds", n),
            tuple(get_str({"state": s}, "state", choices=ACTUATOR_STATES) for s in st),
        )


# ---------------------------------------------------------------------------- simulation
@dataclass(frozen=True)
class SimulationData(_Msg):
    """simulation ``data``: simulated time, steps, paused flag, achieved real-time factor."""

    t: float
    steps: int
    paused: bool
    rtf: float = 0.0

    @classmethod
    def from_dict(cls, m: dict) -> SimulationData:
        return cls(get_float(m, "t"), get_int(m, "steps", lo=0), get_bool(m, "paused"), get_float(m, "rtf", 0.0))


# ---------------------------------------------------------------------------- map
@dataclass(frozen=True, eq=False)
class MapData(_Msg):
    """map ``rpc/get`` reply: ``cells`` int8 row-major from the *bottom* row, Player's values
    (-1 free, 0 unknown, +1 occupied), ``origin`` the world position of the bottom-left corner."""

    width: int
    height: int
    resolution: float
    origin: tuple[float, float]
    cells: np.ndarray  # int8, shape (height, width)

    def to_dict(self) -> dict:
        return {
            "width": self.width,
            "height": self.height,
            "resolution": self.resolution,
            "origin": list(self.origin),
            "cells": np.ascontiguousarray(self.cells, dtype=np.int8).tobytes(),
        }

    @classmethod
    def from_dict(cls, m: dict) -> MapData:
        w = get_int(m, "width", lo=1)
        h = get_int(m, "height", lo=1)
        raw = _need(m, "cells", True)
        if not isinstance(raw, (bytes, bytearray)) or len(raw) != w * h:
            raise MessageError(f"field 'cells' must be {w * h} bytes (width x height int8)")
        return cls(
            w,
            h,
            get_float(m, "resolution", lo=1e-6),
            get_vec(m, "origin", 2),
            np.frombuffer(raw, dtype=np.int8).reshape(h, w),
        )


# ---------------------------------------------------------------------------- navigation
@dataclass(frozen=True)
class GoalCmd(_Msg):
    """position2d ``cmd`` of a local planner (vfh, nd, snd): drive to ``goal`` (x, y, yaw) in the
    device's frame. Player's ``GoTo``; a :class:`VelocityCmd` on the same key cancels the goal."""

    goal: tuple[float, float, float]

    @classmethod
    def from_dict(cls, m: dict) -> GoalCmd:
        return cls(get_vec(m, "goal", 3))


def _cov9(m: dict, name: str) -> tuple[float, ...]:
    c = get_vec(m, name, 9)
    if c[0] < 0 or c[4] < 0 or c[8] < 0:
        raise MessageError(f"field {name!r} must be a covariance (non-negative diagonal)")
    return c


@dataclass(frozen=True)
class Hypothesis(_Msg):
    """One pose hypothesis of a localizer: ``weight`` in [0, 1], ``pose`` mean (x, y, yaw) in the map
    frame, ``cov`` its 3x3 covariance row-major (m², rad²)."""

    weight: float
    pose: tuple[float, float, float]
    cov: tuple[float, ...]

    @classmethod
    def from_dict(cls, m: dict) -> Hypothesis:
        if not isinstance(m, dict):
            raise MessageError("each hypothesis must be a map")
        return cls(get_float(m, "weight", lo=0.0, hi=1.0 + 1e-9), get_vec(m, "pose", 3), _cov9(m, "cov"))


@dataclass(frozen=True)
class LocalizeData(_Msg):
    """localize ``data`` (Player's localize interface; thesis eq. 3.3-3.4): the best estimate ``pose``
    with covariance ``cov`` (row-major 3x3), every ``hypotheses`` entry heaviest first, the number of
    ``particles``, and ``pending`` sensor updates skipped (0 when keeping up)."""

    t: float
    pose: tuple[float, float, float]
    cov: tuple[float, ...]
    hypotheses: list[Hypothesis] = field(default_factory=list)
    particles: int = 0
    pending: int = 0

    @classmethod
    def from_dict(cls, m: dict) -> LocalizeData:
        raw = _need(m, "hypotheses", False) or []
        if not isinstance(raw, list):
            raise MessageError("field 'hypotheses' must be a list")
        return cls(
            get_float(m, "t"),
            get_vec(m, "pose", 3),
            _cov9(m, "cov"),
            [Hypothesis.from_dict(h) for h in raw],
            get_int(m, "particles", 0, lo=0),
            get_int(m, "pending", 0, lo=0),
        )


PLANNER_STATUS = ("idle", "driving", "done", "aborted", "invalid")


@dataclass(frozen=True)
class PlannerData(_Msg):
    """planner ``data`` (Player's planner interface): ``status`` one of idle, driving, done, aborted
    (a replan failed), invalid (the goal cannot be planned); ``pose`` the localized pose, ``goal`` and
    ``waypoint`` (current target) in the map frame (empty list when none), ``waypoint_index`` of
    ``waypoint_count``; ``message`` says why for aborted/invalid."""

    t: float
    status: str
    pose: tuple[float, float, float]
    goal: tuple[float, ...] = ()
    waypoint: tuple[float, ...] = ()
    waypoint_index: int = 0
    waypoint_count: int = 0
    message: str = ""

    @classmethod
    def from_dict(cls, m: dict) -> PlannerData:
        def opt3(name: str) -> tuple[float, ...]:
            v = _need(m, name, False)
            return () if v is None or v == [] else get_vec(m, name, 3)

        return cls(
            get_float(m, "t"),
            get_str(m, "status", choices=PLANNER_STATUS),
            get_vec(m, "pose", 3),
            opt3("goal"),
            opt3("waypoint"),
            get_int(m, "waypoint_index", 0, lo=0),
            get_int(m, "waypoint_count", 0, lo=0),
            get_str(m, "message", ""),
        )


# ---------------------------------------------------------------------------- describe
@dataclass(frozen=True)
class Describe(_Msg):
    """``rpc/describe`` reply body: what a device is and how to talk to it."""

    node: str
    interface: str
    index: int
    driver: str
    rate: float  # Hz of data publication (0: on change only)
    geometry: dict = field(default_factory=dict)
    ops: list[str] = field(default_factory=list)
    cmd: str = ""  # name of the cmd message type, "" if the device takes no commands
    data: str = ""  # name of the data message type
    protocol: int = PROTOCOL_VERSION

    KIND: ClassVar[str] = "describe"

    @classmethod
    def from_dict(cls, m: dict) -> Describe:
        geo = m.get("geometry", {})
        ops = m.get("ops", [])
        if not isinstance(geo, dict) or not isinstance(ops, list):
            raise MessageError("describe: 'geometry' must be a map and 'ops' a list")
        return cls(
            get_str(m, "node"),
            get_str(m, "interface"),
            get_int(m, "index", lo=0),
            get_str(m, "driver"),
            get_float(m, "rate", 0.0),
            geo,
            [str(o) for o in ops],
            get_str(m, "cmd", ""),
            get_str(m, "data", ""),
            get_int(m, "protocol", PROTOCOL_VERSION),
        )
