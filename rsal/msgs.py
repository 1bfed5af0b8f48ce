"""The message schema: the codec every payload on the key space goes through, validated on decode.

Payloads are msgpack maps with short string keys; numbers are SI (m, rad, s); arrays of ranges
travel as packed little-endian float32 ``bytes``. Every message is a frozen dataclass with
``to_dict()`` / ``from_dict()`` and :func:`encode` / :func:`decode` for bytes. Decoding checks
types, finiteness and required fields and raises :class:`MessageError`, whose text names the
field and what was expected, so a device server can answer or log one line and carry on.

This module holds the codec, the field readers, the reply envelope (:class:`RpcError`,
:class:`ErrorCode`) and :class:`Describe`. Each interface's messages live with it in
:mod:`rsal.interfaces` (``rsal/interfaces/<name>.py``) and stay importable from here by name
(``from rsal.msgs import Position2dData``).

RPC replies: success is ``{"ok": true, ...result}``; failure is sent with Zenoh's ``reply_err``
as ``{"ok": false, "code": <ErrorCode>, "message": str}``. ``docs/protocol.md`` documents every
message; this module and the interface modules are the implementation of that document.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from enum import StrEnum
from typing import TYPE_CHECKING, Any, ClassVar

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


def get_list(m: dict, name: str, item: Callable[[Any], Any], required: bool = True) -> list:
    """Field ``name`` as a list, each element decoded by ``item`` (a ``from_dict``); an absent
    optional field is the empty list."""
    raw = _need(m, name, required)
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise MessageError(f"field {name!r} must be a list")
    return [item(x) for x in raw]


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

    def __init_subclass__(cls, **kw) -> None:
        # ``from_dict`` also takes a message that is already of the class and returns it as is: the
        # device server hands drivers typed commands and inputs, and a driver written against maps
        # (``VelocityCmd.from_dict(msg)``) keeps working unchanged.
        super().__init_subclass__(**kw)
        raw = cls.__dict__.get("from_dict")
        if raw is None or getattr(raw, "__func__", None) is None or getattr(raw.__func__, "_typed_ok", False):
            return
        plain = raw.__func__

        def from_dict(c, m, _plain=plain):
            return m if isinstance(m, c) else _plain(c, m)

        from_dict._typed_ok = True  # type: ignore[attr-defined]
        from_dict.__doc__ = plain.__doc__
        from_dict.__qualname__ = plain.__qualname__
        cls.from_dict = classmethod(from_dict)  # type: ignore[method-assign]

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


# ---------------------------------------------------------------------------- interface messages
# The messages of each interface live with it in ``rsal/interfaces/<name>.py``. They stay importable
# from here (``from rsal.msgs import Position2dData``), resolved on first use from the registry's
# modules: the interface modules import this codec, so importing them here eagerly would be circular.
# ``__all__`` above keeps the names this module had; any interface's message resolves the same way.
if TYPE_CHECKING:  # what the names resolve to, for type checkers and linters
    from .interfaces.actarray import ACTUATOR_STATES, ActArrayData
    from .interfaces.blobfinder import BlobData, BlobfinderData
    from .interfaces.dio import DioCmd, DioData
    from .interfaces.gripper import GripperCmd, GripperData
    from .interfaces.localize import Hypothesis, LocalizeData
    from .interfaces.map import MapData
    from .interfaces.planner import PLANNER_STATUS, PlannerData
    from .interfaces.position2d import GoalCmd, Position2dData, VelocityCmd
    from .interfaces.power import PowerData
    from .interfaces.ranger import RangerData
    from .interfaces.simulation import SimulationData


def __getattr__(name: str):
    from . import interfaces

    for mod in interfaces.MODULES:
        if name in getattr(mod, "__all__", ()):
            value = getattr(mod, name)
            globals()[name] = value  # later look-ups are plain attribute reads
            return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
