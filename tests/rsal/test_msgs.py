"""The message schema (rsal/msgs.py): msgpack round trips, validation on decode, RPC reply envelopes."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from rsal import msgs
from rsal.msgs import (
    ActArrayData,
    BlobData,
    BlobfinderData,
    Describe,
    DioCmd,
    DioData,
    ErrorCode,
    GoalCmd,
    GripperCmd,
    GripperData,
    Hypothesis,
    LocalizeData,
    MapData,
    MessageError,
    PlannerData,
    Position2dData,
    PowerData,
    RangerData,
    RpcError,
    SimulationData,
    VelocityCmd,
    decode,
    decode_map,
    encode,
    error_reply,
    ok_reply,
    parse_reply,
)

NAN = math.nan
INF = math.inf


def roundtrip(msg):
    data = encode(msg)
    assert isinstance(data, bytes)
    return decode(type(msg), data)


def blob(**kw) -> BlobData:
    base = dict(
        id=1, color=0x00FF00, x=40, y=30, left=30, right=50, top=20, bottom=40, area=400, range=1.5, bearing=0.2
    )
    base.update(kw)
    return BlobData(**base)


# ---------------------------------------------------------------------------- round trips
SIMPLE = [
    VelocityCmd(0.3, -0.5),
    VelocityCmd(0.1, 0.0, vy=0.05),
    Position2dData(12.5, (1.0, -2.0, 0.5), (0.3, 0.0, -0.1), stall=True),
    Position2dData(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
    BlobfinderData(3.0, 80, 60, [blob(), blob(id=2, color=0xFF0000, range=0.4, bearing=-1.0)]),
    BlobfinderData(3.0, 80, 60, []),
    GripperCmd("close"),
    GripperData(1.0, "closed", "up", 3, 1, "bin1"),
    GripperData(1.0, "opening", "lowering", 0, 0, None),
    PowerData(5.0, 12.4, 87.5, charging=True),
    DioData(2.0, 8, 0b1010_0101, 0b11),
    DioCmd(0b01, mask=0b11),
    ActArrayData(2.0, (1.0,), (0.0,), ("idle",)),
    SimulationData(100.0, 1000, False, 9.8),
    GoalCmd((1.0, -2.0, 0.5)),
    Hypothesis(0.75, (1.0, 2.0, 0.1), (0.01, 0, 0, 0, 0.02, 0, 0, 0, 0.003)),
    LocalizeData(
        4.0,
        (1.0, 2.0, 0.1),
        (0.01, 0, 0, 0, 0.02, 0, 0, 0, 0.003),
        [Hypothesis(0.75, (1.0, 2.0, 0.1), (0.01, 0, 0, 0, 0.02, 0, 0, 0, 0.003))],
        500,
        0,
    ),
    PlannerData(5.0, "driving", (1.0, 2.0, 0.0), (5.0, 6.0, 1.57), (3.0, 2.0, 0.7), 1, 4),
    PlannerData(5.0, "invalid", (1.0, 2.0, 0.0), message="goal (9, 9) is inside an obstacle"),
    Describe(
        "r0",
        "laser",
        0,
        "sim",
        10.0,
        {"pose": [0.13, 0.0, 0.0], "sensors": [{"pose": [0.0, 0.0, 0.0], "fov": 4.18}]},
        ["describe", "get"],
        "",
        "RangerData",
    ),
]


@pytest.mark.parametrize("msg", SIMPLE, ids=lambda m: type(m).__name__)
def test_roundtrip_through_msgpack(msg):
    assert roundtrip(msg) == msg


def test_roundtrip_of_a_blob_alone():
    b = blob(color=0xFFFFFF)
    assert BlobData.from_dict(msgpack.unpackb(encode(b), raw=False)) == b


def test_ranger_data_roundtrip_carries_float32_bytes():
    ranges = np.array([0.5, 1.25, 5.6, 0.02], dtype=np.float64)
    msg = RangerData(2.0, ranges, -1.0, 0.5, 0.02, 5.6)
    wire = msgpack.unpackb(encode(msg), raw=False)
    assert isinstance(wire["ranges"], bytes) and len(wire["ranges"]) == 4 * 4
    back = roundtrip(msg)
    assert back.ranges.dtype == np.dtype("<f4")
    np.testing.assert_array_equal(back.ranges, ranges.astype(np.float32))
    assert (back.t, back.angle_min, back.angle_step, back.range_min, back.range_max) == (2.0, -1.0, 0.5, 0.02, 5.6)


def test_ranger_data_defaults_for_a_sonar():
    back = decode(RangerData, encode({"t": 1.0, "ranges": msgs.f32_bytes([1.0, 2.0])}))
    assert (back.angle_min, back.angle_step, back.range_min, back.range_max) == (0.0, 0.0, 0.0, 0.0)
    assert back.ranges.tolist() == [1.0, 2.0]


def test_map_data_roundtrip_keeps_rows_and_values():
    cells = np.array([[-1, 0, 1], [1, 1, -1]], dtype=np.int8)
    msg = MapData(3, 2, 0.05, (-1.5, 2.0), cells)
    back = roundtrip(msg)
    assert (back.width, back.height, back.resolution, back.origin) == (3, 2, 0.05, (-1.5, 2.0))
    np.testing.assert_array_equal(back.cells, cells)
    assert back.cells.shape == (2, 3)


@pytest.mark.parametrize(
    "cls, payload, field",
    [
        (GoalCmd, {"goal": [1.0, 2.0]}, "goal"),
        (GoalCmd, {"goal": [1.0, NAN, 0.0]}, "goal"),
        (Hypothesis, {"weight": 2.0, "pose": [0, 0, 0], "cov": [0] * 9}, "weight"),
        (LocalizeData, {"t": 0.0, "pose": [0, 0, 0], "cov": [-1, 0, 0, 0, 1, 0, 0, 0, 1]}, "cov"),
        (PlannerData, {"t": 0.0, "status": "lost", "pose": [0, 0, 0]}, "status"),
    ],
)
def test_navigation_messages_reject_bad_fields(cls, payload, field):
    with pytest.raises(MessageError, match=field):
        decode(cls, encode(payload))


def test_every_message_class_is_covered():
    """A message type added to __all__ needs a round-trip case here too."""
    covered = {type(m) for m in SIMPLE} | {BlobData, RangerData, MapData}
    exported = {
        getattr(msgs, n)
        for n in msgs.__all__
        if isinstance(getattr(msgs, n), type) and hasattr(getattr(msgs, n), "from_dict")
    }
    assert exported == covered


def test_defaults_fill_optional_fields():
    assert decode(VelocityCmd, encode({"v": 0.1, "w": 0.2})) == VelocityCmd(0.1, 0.2, 0.0)
    assert decode(Position2dData, encode({"t": 0, "pose": [0, 0, 0], "vel": [0, 0, 0]})).stall is False
    g = decode(GripperData, encode({"t": 0, "paddles": "open"}))
    assert (g.lift, g.beams, g.stored, g.carrying) == ("down", 0, 0, None)
    d = decode(Describe, encode({"node": "r0", "interface": "map", "index": 0, "driver": "mapfile"}))
    assert (d.rate, d.geometry, d.ops, d.cmd, d.data, d.protocol) == (0.0, {}, [], "", "", msgs.PROTOCOL_VERSION)


def test_integers_are_accepted_where_floats_are_expected():
    m = decode(Position2dData, encode({"t": 3, "pose": [1, 2, 0], "vel": [0, 0, 0]}))
    assert m.pose == (1.0, 2.0, 0.0) and all(isinstance(x, float) for x in m.pose)


# ---------------------------------------------------------------------------- rejection
BAD = [
    # (class, payload map, field named in the error)
    (VelocityCmd, {"w": 0.1}, "v"),
    (VelocityCmd, {"v": "fast", "w": 0.0}, "v"),
    (VelocityCmd, {"v": True, "w": 0.0}, "v"),
    (VelocityCmd, {"v": NAN, "w": 0.0}, "v"),
    (VelocityCmd, {"v": 0.0, "w": INF}, "w"),
    (VelocityCmd, {"v": 0.0, "w": 0.0, "vy": -INF}, "vy"),
    (VelocityCmd, {"v": None, "w": 0.0}, "v"),
    (Position2dData, {"t": 0, "pose": [0, 0], "vel": [0, 0, 0]}, "pose"),
    (Position2dData, {"t": 0, "pose": "0,0,0", "vel": [0, 0, 0]}, "pose"),
    (Position2dData, {"t": 0, "pose": [0, NAN, 0], "vel": [0, 0, 0]}, "pose"),
    (Position2dData, {"t": 0, "pose": [0, 0, 0], "vel": [0, "x", 0]}, "vel"),
    (Position2dData, {"t": 0, "pose": [0, 0, 0], "vel": [0, 0, 0], "stall": 1}, "stall"),
    (Position2dData, {"pose": [0, 0, 0], "vel": [0, 0, 0]}, "t"),
    (RangerData, {"t": 0, "ranges": [1.0, 2.0]}, "ranges"),
    (RangerData, {"t": 0, "ranges": b"\x00\x00\x80"}, "ranges"),
    (RangerData, {"t": 0}, "ranges"),
    (RangerData, {"t": 0, "ranges": b"", "angle_step": NAN}, "angle_step"),
    (BlobfinderData, {"t": 0, "width": 80, "height": 60}, "blobs"),
    (BlobfinderData, {"t": 0, "width": 80, "height": 60, "blobs": {}}, "blobs"),
    (BlobfinderData, {"t": 0, "width": -1, "height": 60, "blobs": []}, "width"),
    (BlobfinderData, {"t": 0, "width": 8.5, "height": 60, "blobs": []}, "width"),
    (BlobfinderData, {"t": 0, "width": 80, "height": 60, "blobs": [{"color": 0x1000000, "range": 1.0}]}, "color"),
    (BlobfinderData, {"t": 0, "width": 80, "height": 60, "blobs": [{"color": 1, "range": NAN}]}, "range"),
    (BlobfinderData, {"t": 0, "width": 80, "height": 60, "blobs": [{"color": 1}]}, "range"),
    (BlobfinderData, {"t": 0, "width": 80, "height": 60, "blobs": [{"color": 1, "range": 1, "area": "big"}]}, "area"),
    (GripperCmd, {"action": "explode"}, "action"),
    (GripperCmd, {}, "action"),
    (GripperCmd, {"action": 1}, "action"),
    (GripperData, {"t": 0, "paddles": "ajar"}, "paddles"),
    (GripperData, {"t": 0, "paddles": "open", "lift": "sideways"}, "lift"),
    (GripperData, {"t": 0, "paddles": "open", "beams": 4}, "beams"),
    (GripperData, {"t": 0, "paddles": "open", "stored": -1}, "stored"),
    (GripperData, {"t": 0, "paddles": "open", "carrying": 7}, "carrying"),
    (PowerData, {"t": 0, "volts": 12.0, "percent": 101}, "percent"),
    (PowerData, {"t": 0, "volts": 12.0, "percent": -0.5}, "percent"),
    (PowerData, {"t": 0, "volts": INF, "percent": 50}, "volts"),
    (PowerData, {"t": 0, "volts": 12.0, "percent": 50, "charging": "yes"}, "charging"),
    (SimulationData, {"t": 0, "steps": -1, "paused": False}, "steps"),
    (SimulationData, {"t": 0, "steps": 1, "paused": "no"}, "paused"),
    (SimulationData, {"t": 0, "steps": 1}, "paused"),
    (MapData, {"width": 0, "height": 1, "resolution": 0.1, "origin": [0, 0], "cells": b""}, "width"),
    (MapData, {"width": 2, "height": 2, "resolution": 0.1, "origin": [0, 0], "cells": b"\x00" * 3}, "cells"),
    (MapData, {"width": 1, "height": 1, "resolution": 0.0, "origin": [0, 0], "cells": b"\x00"}, "resolution"),
    (MapData, {"width": 1, "height": 1, "resolution": 0.1, "origin": [0], "cells": b"\x00"}, "origin"),
    (MapData, {"width": 1, "height": 1, "resolution": 0.1, "origin": [0, 0], "cells": [0]}, "cells"),
    (Describe, {"interface": "laser", "index": 0, "driver": "sim"}, "node"),
    (Describe, {"node": "r0", "interface": "laser", "index": -1, "driver": "sim"}, "index"),
    (Describe, {"node": "r0", "interface": "laser", "index": 0, "driver": "sim", "rate": INF}, "rate"),
    (Describe, {"node": "r0", "interface": "laser", "index": 0, "driver": "sim", "geometry": []}, "geometry"),
    (Describe, {"node": "r0", "interface": "laser", "index": 0, "driver": "sim", "ops": "get"}, "ops"),
]


@pytest.mark.parametrize(("cls", "payload", "name"), BAD, ids=lambda x: x.__name__ if isinstance(x, type) else None)
def test_decode_rejects_with_the_field_named(cls, payload, name):
    data = msgpack.packb(payload, use_bin_type=True)
    with pytest.raises(MessageError) as ei:
        decode(cls, data)
    assert f"'{name}'" in str(ei.value)


@pytest.mark.parametrize(
    ("payload", "fragment"),
    [
        ({"v": NAN, "w": 0.0}, "must be finite"),
        ({"v": "fast", "w": 0.0}, "must be a number, not str"),
        ({"w": 0.0}, "is missing"),
    ],
)
def test_error_text_says_what_was_expected(payload, fragment):
    with pytest.raises(MessageError, match=fragment):
        decode(VelocityCmd, msgpack.packb(payload))


def test_range_limits_are_in_the_message():
    with pytest.raises(MessageError) as ei:
        decode(PowerData, encode({"t": 0, "volts": 12.0, "percent": 150}))
    assert "'percent' = 150.0 is outside [0, 100]" in str(ei.value)


def test_vector_element_errors_name_the_index():
    with pytest.raises(MessageError, match=r"'pose'\[2\] must be a finite number"):
        decode(Position2dData, encode({"t": 0, "pose": [0, 0, INF], "vel": [0, 0, 0]}))


# ---------------------------------------------------------------------------- decode_map
@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        (b"\xc1", "not msgpack"),
        (b"\x92\x01", "not msgpack"),  # truncated array
        (b"\x00garbage", "not msgpack"),  # extra data after a value
        (msgpack.packb([1, 2, 3]), "must be a msgpack map, not list"),
        (msgpack.packb("text"), "must be a msgpack map, not str"),
        (msgpack.packb(3.5), "must be a msgpack map, not float"),
    ],
)
def test_decode_map_rejects_what_is_not_a_map(data, fragment):
    with pytest.raises(MessageError, match=fragment):
        decode_map(data)


@pytest.mark.parametrize("empty", [None, b"", bytearray(), memoryview(b"")])
def test_an_empty_payload_is_an_empty_map(empty):
    assert decode_map(empty) == {}


def test_decode_map_accepts_bytearray_and_memoryview():
    raw = encode({"v": 1.0, "w": 0.0})
    assert decode_map(bytearray(raw)) == decode_map(memoryview(raw)) == {"v": 1.0, "w": 0.0}


def test_encode_takes_plain_maps_and_messages_alike():
    assert msgpack.unpackb(encode({"a": 1}), raw=False) == {"a": 1}
    assert msgpack.unpackb(encode(VelocityCmd(1.0, 2.0)), raw=False) == {"v": 1.0, "w": 2.0, "vy": 0.0}


# ---------------------------------------------------------------------------- replies
def test_ok_reply_envelope():
    data = ok_reply(pose=[1.0, 2.0, 0.0], paused=True)
    assert msgpack.unpackb(data, raw=False) == {"ok": True, "pose": [1.0, 2.0, 0.0], "paused": True}
    assert parse_reply(data) == {"ok": True, "pose": [1.0, 2.0, 0.0], "paused": True}


def test_error_reply_envelope_uses_the_code_value():
    data = error_reply(ErrorCode.NOT_FOUND, "no model 'r9'")
    assert msgpack.unpackb(data, raw=False) == {"ok": False, "code": "not_found", "message": "no model 'r9'"}


@pytest.mark.parametrize("is_error", [True, False])
def test_parse_reply_raises_rpc_error_with_code_and_message(is_error):
    data = error_reply(ErrorCode.OUT_OF_RANGE, "v = 9 m/s is over 0.5")
    with pytest.raises(RpcError) as ei:
        parse_reply(data, is_error=is_error, key="rsal/r0/position2d/0/rpc/set")
    e = ei.value
    assert e.code == ErrorCode.OUT_OF_RANGE == "out_of_range"
    assert e.message == "v = 9 m/s is over 0.5"
    assert e.key == "rsal/r0/position2d/0/rpc/set"
    assert str(e) == "rsal/r0/position2d/0/rpc/set: out_of_range: v = 9 m/s is over 0.5"


def test_parse_reply_treats_an_error_sample_as_an_error_even_if_it_says_ok():
    with pytest.raises(RpcError) as ei:
        parse_reply(ok_reply(), is_error=True)
    assert ei.value.code == ErrorCode.INTERNAL


def test_parse_reply_without_ok_is_an_error():
    with pytest.raises(RpcError) as ei:
        parse_reply(encode({"pose": [0, 0, 0]}))
    assert ei.value.code == ErrorCode.INTERNAL
    assert ei.value.message == "error without a message"


def test_parse_reply_of_garbage_is_a_bad_request_error():
    with pytest.raises(RpcError) as ei:
        parse_reply(b"\xc1\xc1", key="k")
    assert ei.value.code == ErrorCode.BAD_REQUEST
    assert "malformed reply" in ei.value.message and "not msgpack" in ei.value.message


def test_rpc_error_without_key():
    assert str(RpcError(ErrorCode.TIMEOUT, "no reply")) == "timeout: no reply"


def test_message_error_is_a_value_error():
    assert issubclass(MessageError, ValueError)


@pytest.mark.parametrize(("raw", "code"), [(b"Timeout", ErrorCode.TIMEOUT), (b"no route", ErrorCode.UNAVAILABLE)])
def test_a_transport_error_reply_is_not_a_device_error(raw, code):
    """Zenoh itself answers a query it could not complete with a plain-text error."""
    with pytest.raises(RpcError) as ei:
        parse_reply(raw, is_error=True, key="rsal/r0/planner/0/rpc/set_goal")
    assert ei.value.code == code
    assert raw.decode() in ei.value.message


# ---------------------------------------------------------------------------- RangerData wire fast path
def _scan(n: int = 682, **kw) -> RangerData:
    rng = np.random.default_rng(n)
    f = dict(t=12.5, angle_min=-2.0944, angle_step=0.00614, range_min=0.02, range_max=5.6) | kw
    return RangerData(ranges=rng.uniform(0.02, 5.6, n).astype("<f4"), **f)


@pytest.mark.parametrize("n", [0, 1, 16, 63, 64, 181, 682, 1081, 16383, 16384, 70000])
def test_ranger_fast_encoding_is_byte_for_byte_msgpack(n):
    scan = _scan(n)
    assert scan.to_msgpack() == msgpack.packb(scan.to_dict(), use_bin_type=True)
    assert encode(scan) == scan.to_msgpack()


@pytest.mark.parametrize("n", [0, 1, 16, 64, 682, 16383, 16384, 70000])
def test_ranger_fast_decoding_equals_the_generic_decoding(n):
    scan = _scan(n)
    data = msgpack.packb(scan.to_dict(), use_bin_type=True)
    fast, generic = RangerData.from_bytes(data), RangerData.from_dict(msgs.decode_map(data))
    for name in ("t", "angle_min", "angle_step", "range_min", "range_max"):
        assert getattr(fast, name) == getattr(generic, name) == getattr(scan, name)
    assert fast.ranges.dtype == np.dtype("<f4")
    np.testing.assert_array_equal(fast.ranges, scan.ranges)
    np.testing.assert_array_equal(decode(RangerData, data).ranges, scan.ranges)


def test_ranger_encoding_of_non_float_fields_and_other_dtypes_takes_the_generic_path():
    for scan in (
        _scan(t=3),  # an int stamp stays an int on the wire, as msgpack packs it
        _scan(angle_min=np.float64(-1.0)),
        RangerData(1.0, np.ones(100), 0.0, 0.1, 0.0, 5.0),  # float64 ranges become float32
        RangerData(1.0, np.ones((200, 2), dtype="<f4")[:, 0], 0.0, 0.1, 0.0, 5.0),  # a strided view
    ):
        assert scan.to_msgpack() == msgpack.packb(scan.to_dict(), use_bin_type=True)
        back = RangerData.from_bytes(scan.to_msgpack())
        np.testing.assert_array_equal(back.ranges, np.asarray(scan.ranges, dtype="<f4"))
        assert back.t == scan.t


def test_ranger_decoding_of_other_layouts_matches_the_generic_path():
    """Another key order, float32 or integer fields, extra keys: the same message as the generic path."""
    m = _scan(300).to_dict()
    variants = [
        dict(reversed(m.items())),
        m | {"extra": 1},
        m | {"t": 7},
        {k: m[k] for k in ("t", "ranges")},  # optional fields left out
    ]
    f32 = msgpack.Packer(use_bin_type=True, use_single_float=True).pack(m)
    for data in [msgpack.packb(v, use_bin_type=True) for v in variants] + [f32]:
        fast, generic = RangerData.from_bytes(data), RangerData.from_dict(msgs.decode_map(data))
        assert (fast.t, fast.angle_min, fast.range_max) == (generic.t, generic.angle_min, generic.range_max)
        np.testing.assert_array_equal(fast.ranges, generic.ranges)


@pytest.mark.parametrize(
    "mutate, fragment",
    [
        (lambda d: d + b"\x00", "not msgpack"),  # trailing bytes after the map
        (lambda d: d[:-1], "not msgpack"),  # cut short
        (lambda d: d[:4] + msgpack.packb(math.nan)[1:] + d[12:], "'t'"),  # NaN stamp
        (lambda d: d[:-9] + msgpack.packb(math.inf), "'range_max'"),  # inf field
        (lambda d: d[:20] + (int.from_bytes(d[20:22], "big") - 2).to_bytes(2, "big") + d[22:-2], "not msgpack"),
    ],
)
def test_ranger_fast_decoding_rejects_what_the_generic_path_rejects(mutate, fragment):
    data = mutate(_scan(300).to_msgpack())
    with pytest.raises(MessageError, match=fragment):
        RangerData.from_bytes(data)
    with pytest.raises(MessageError, match=fragment):
        RangerData.from_dict(msgs.decode_map(data))


def test_ranger_fast_decoding_reads_the_ranges_in_place_read_only():
    data = _scan(300).to_msgpack()
    back = RangerData.from_bytes(data)
    assert back.ranges.base is data  # a view into the payload: the fast path, no copy
    assert not back.ranges.flags.writeable


def test_encoded_maps_are_byte_for_byte_what_msgpack_packs():
    """The encoder (ormsgpack) against msgpack-python on 3,000 random maps of the schema's types."""
    import random

    rnd = random.Random(7)
    ints = [0, 1, -1, 127, 128, 255, 256, -32, -33, -128, -129, 65535, 65536, 2**32, -(2**31) - 1, 2**63 - 1, -(2**63)]

    def value(depth: int = 0):
        k = rnd.randrange(7 if depth < 3 else 5)
        if k == 0:
            return rnd.choice(ints)
        if k == 1:
            return rnd.random() * 10 ** rnd.randint(-5, 5)
        if k == 2:
            return "x" * rnd.choice([0, 5, 31, 32, 255, 256, 70000])
        if k == 3:
            return rnd.choice([True, False, None])
        if k == 4:
            return bytes(rnd.choice([0, 5, 255, 256, 70000]))
        if k == 5:
            return [value(depth + 1) for _ in range(rnd.choice([0, 3, 15, 16, 20]))]
        return {str(i): value(depth + 1) for i in range(rnd.choice([0, 3, 15, 16, 20]))}

    for _ in range(3000):
        m = {"a": value(), 7: value()}
        assert encode(m) == msgpack.packb(m, use_bin_type=True), repr(m)[:200]
    # what ormsgpack refuses goes to msgpack-python
    assert encode({"big": 2**64 - 1}) == msgpack.packb({"big": 2**64 - 1}, use_bin_type=True)
    with pytest.raises((OverflowError, TypeError)):
        encode({"too big": 2**70})
