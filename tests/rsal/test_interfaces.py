"""The interface registry (rsal/interfaces): one record per Player interface from which the key
space, the proxies and the typed decoding derive; RangerGeometry's beam layout; the bumper and
fiducial messages and geometry (encode/decode round trips, validation)."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from rsal import devices, interfaces, keys, msgs
from rsal.interfaces.bumper import Bumper, BumperData, BumperGeometry, BumperSegment
from rsal.interfaces.fiducial import Fiducial, FiducialData, FiducialGeometry, FiducialItem
from rsal.interfaces.ranger import RangerGeometry
from rsal.msgs import Describe, GoalCmd, MessageError, Position2dData, RangerData, VelocityCmd, decode, encode


# ---------------------------------------------------------------------------- the registry
def test_key_space_interfaces_come_from_the_registry():
    assert keys.INTERFACES == interfaces.names()
    for name in ("position2d", "ranger", "laser", "sonar", "localize", "planner", "map", "gripper"):
        assert name in keys.INTERFACES
    for name in ("blobfinder", "simulation", "power", "dio", "actarray", "audio", "bumper", "fiducial"):
        assert name in keys.INTERFACES


def test_proxy_classes_come_from_the_registry():
    assert devices.proxy_class("position2d") is devices.Position2d
    assert devices.proxy_class("laser") is devices.Laser and issubclass(devices.Laser, devices.Ranger)
    assert devices.proxy_class("bumper") is Bumper
    assert devices.proxy_class("fiducial") is Fiducial
    assert devices.proxy_class("no_such_thing") is devices.Device
    for rec in interfaces.REGISTRY.values():
        assert issubclass(rec.proxy, devices.Device)
        if rec.data is not None and rec.proxy.data_type is not None:
            assert rec.proxy.data_type is rec.data, rec.name


def test_old_import_paths_still_work():
    from rsal.devices import Gripper, Planner  # noqa: F401
    from rsal.msgs import BlobfinderData, GripperCmd, PlannerData  # noqa: F401

    assert msgs.Position2dData is interfaces.get("position2d").data
    assert msgs.BumperData is BumperData  # any interface's message resolves through rsal.msgs
    with pytest.raises(AttributeError):
        msgs.NoSuchMessage  # noqa: B018


def test_every_data_type_round_trips_a_payload_through_its_record():
    sample = {
        "position2d": Position2dData(1.0, (1.0, 2.0, 0.5), (0.1, 0.0, 0.2)),
        "bumper": BumperData(2.0, (0, 1)),
        "fiducial": FiducialData(3.0, [FiducialItem.at(4, (1.0, 0.0, 0.0))]),
    }
    for name, msg in sample.items():
        assert interfaces.decode_data(name, encode(msg)) == msg
        assert interfaces.get(name).summary(msg)  # the live view's one line
    assert interfaces.decode_data("audio", encode({"x": 1})) == {"x": 1}  # no data type: a plain map
    with pytest.raises(MessageError, match="bumpers"):
        interfaces.decode_data("bumper", encode({"t": 1.0}))


def test_cmd_types_follow_the_driver_declaration_or_the_interface():
    assert interfaces.cmd_types("position2d") == (VelocityCmd, GoalCmd)
    assert interfaces.cmd_types("position2d", "VelocityCmd") == (VelocityCmd,)
    assert interfaces.cmd_types("position2d", "GoalCmd | VelocityCmd") == (GoalCmd, VelocityCmd)
    assert interfaces.cmd_types("dio", "MyOwnCmd") == ()  # a driver's own type: it gets the map
    assert interfaces.cmd_types("bumper") == ()


def test_decode_as_picks_the_fitting_type_and_names_the_right_error():
    kinds = (VelocityCmd, GoalCmd)
    assert interfaces.decode_as(kinds, {"v": 0.1, "w": 0.0}) == VelocityCmd(0.1, 0.0)
    assert interfaces.decode_as(kinds, {"goal": [1.0, 2.0, 0.0]}) == GoalCmd((1.0, 2.0, 0.0))
    with pytest.raises(MessageError, match="goal"):  # a bad goal, not a velocity without 'v'
        interfaces.decode_as(kinds, {"goal": [1.0, 2.0]})
    with pytest.raises(MessageError, match="'v'"):
        interfaces.decode_as(kinds, {})
    v = VelocityCmd(0.2, 0.1)
    assert interfaces.decode_as(kinds, v) is v  # already typed: handed through
    with pytest.raises(MessageError, match="not one of"):
        interfaces.decode_as((GoalCmd,), v)


def test_from_dict_accepts_an_already_typed_message():
    v = VelocityCmd(0.3, 0.0)
    assert VelocityCmd.from_dict(v) is v  # drivers written against maps keep working
    assert VelocityCmd.from_dict({"v": 0.3, "w": 0.0}) == v


# ---------------------------------------------------------------------------- ranger geometry
def test_laser_beams_fan_from_the_sensor_in_the_mount_frame():
    g = RangerGeometry({"kind": "laser", "pose": [0.1, 0.0, math.pi / 2], "sensors": [{"pose": [0.05, 0.0, 0.0]}]})
    origins, bearings = g.layout(3, -0.5, 0.5)
    # the sensor sits 0.05 m ahead of a mount turned 90 degrees: (0.1, 0.05) in the robot frame
    assert np.allclose(origins, [[0.1, 0.05]] * 3)
    assert np.allclose(bearings, [math.pi / 2 - 0.5, math.pi / 2, math.pi / 2 + 0.5])
    assert g.beam_poses(3, -0.5, 0.5).shape == (3, 3)


def test_sonar_ring_has_one_beam_per_transducer_and_repeats_the_last():
    geo = {
        "kind": "sonar",
        "pose": [0.0, 0.0, 0.0],
        "sensors": [{"pose": [0.1, 0.1, 1.0]}, {"pose": [0.1, -0.1, -1.0]}],
    }
    g = RangerGeometry.from_describe(Describe("r0", "sonar", 0, "sim", 10.0, geo))
    o, b = g.layout(2)
    assert np.allclose(o, [[0.1, 0.1], [0.1, -0.1]]) and np.allclose(b, [1.0, -1.0])
    o3, b3 = RangerGeometry(geo).layout(3)
    assert np.allclose(o3[2], [0.1, -0.1]) and b3[2] == pytest.approx(-1.0)
    assert RangerGeometry(geo).beam_width(RangerData(0.0, np.ones(2, np.float32))) == 0.0


def test_several_multi_sample_sensors_each_fan_over_their_fov():
    geo = {
        "sensors": [{"pose": [0, 0, 0], "fov": 1.0, "samples": 3}, {"pose": [0, 0, math.pi], "fov": 1.0, "samples": 3}]
    }
    _, b = RangerGeometry(geo).layout(6)
    assert np.allclose(b, [-0.5, 0.0, 0.5, math.pi - 0.5, math.pi, math.pi + 0.5])


def test_override_pose_replaces_the_mount_and_points_land_in_the_robot_frame():
    g = RangerGeometry({"pose": [5.0, 5.0, 1.0], "sensors": [{"pose": [0, 0, 0]}]}, override_pose=(0.2, 0.0, 0.0))
    scan = RangerData(0.0, np.array([1.0, 5.6, 2.0], np.float32), -math.pi / 2, math.pi / 2, 0.02, 5.6)
    pts = g.points(scan)  # the max-range beam is dropped
    assert np.allclose(pts, [[0.2, -1.0], [0.2, 2.0]], atol=1e-6)


# ---------------------------------------------------------------------------- bumper
def test_bumper_data_round_trip_and_stock_msgpack_form():
    msg = BumperData(1.5, (0, 1, 1, 0))
    wire = msgpack.unpackb(encode(msg), raw=False)
    assert wire == {"t": 1.5, "bumpers": [0, 1, 1, 0]}
    back = decode(BumperData, encode(msg))
    assert back == msg and back.pressed == (1, 2)


@pytest.mark.parametrize(
    "bad", [{"t": 0.0, "bumpers": [0, 2]}, {"t": 0.0, "bumpers": [True]}, {"t": 0.0, "bumpers": 3}]
)
def test_bumper_data_rejects_values_other_than_zero_or_one(bad):
    with pytest.raises(MessageError, match="bumpers"):
        decode(BumperData, encode(bad))


def test_bumper_geometry_from_describe_and_segment_ends():
    geo = {
        "pose": [0.1, 0.0, 0.0],
        "segments": [{"pose": [0.2, 0.0, 0.0], "length": 0.2}, {"pose": [0.0, 0.2, math.pi / 2], "length": 0.1}],
    }
    g = BumperGeometry.from_describe(Describe("r0", "bumper", 0, "sim", 10.0, geo))
    assert g.segments[0] == BumperSegment((0.2, 0.0, 0.0), 0.2, 0.0)
    assert BumperGeometry.from_describe(g.to_dict()) == g
    ends = g.segment_ends()
    assert ends.shape == (2, 2, 2)
    assert np.allclose(ends[0], [[0.3, -0.1], [0.3, 0.1]])  # facing +x: the segment runs along y
    assert np.allclose(ends[1], [[0.15, 0.2], [0.05, 0.2]])  # facing +y: along x
    with pytest.raises(MessageError, match="length"):
        BumperGeometry.from_describe({"segments": [{"pose": [0, 0, 0], "length": -1.0}]})


# ---------------------------------------------------------------------------- fiducial
def test_fiducial_data_round_trip_with_range_and_bearing():
    msg = FiducialData(2.0, [FiducialItem.at(3, (1.0, 1.0, 0.2)), FiducialItem.at(-1, (2.0, 0.0, 0.0))])
    back = decode(FiducialData, encode(msg))
    assert back == msg
    assert back.fiducials[0].range == pytest.approx(math.sqrt(2)) and back.fiducials[0].bearing == pytest.approx(
        math.pi / 4
    )


def test_fiducial_range_and_bearing_are_optional_on_the_wire():
    back = decode(FiducialData, encode({"t": 1.0, "fiducials": [{"id": 5, "pose": [0.0, 2.0, 0.0]}]}))
    item = back.fiducials[0]
    assert item.id == 5 and item.range == pytest.approx(2.0) and item.bearing == pytest.approx(math.pi / 2)


@pytest.mark.parametrize(
    "bad, field",
    [
        ({"t": 0.0}, "fiducials"),
        ({"t": 0.0, "fiducials": [{"id": 1, "pose": [0, 0]}]}, "pose"),
        ({"t": 0.0, "fiducials": [{"id": -2, "pose": [0, 0, 0]}]}, "id"),
        ({"t": 0.0, "fiducials": [7]}, "map"),
    ],
)
def test_fiducial_data_rejects_bad_fields(bad, field):
    with pytest.raises(MessageError, match=field):
        decode(FiducialData, encode(bad))


def test_fiducial_geometry_defaults_and_robot_frame():
    g = FiducialGeometry.from_describe({"pose": [0.2, 0.0, math.pi / 2], "range_max": 4.0})
    assert (g.fov, g.range_min, g.range_max, g.range_max_id) == (math.pi, 0.0, 4.0, 4.0)
    assert FiducialGeometry.from_describe(g.to_dict()) == g
    x, y, a = g.to_robot(FiducialItem.at(1, (1.0, 0.0, 0.0)))  # 1 m ahead of a sensor facing left
    assert (x, y, a) == pytest.approx((0.2, 1.0, math.pi / 2))
    with pytest.raises(MessageError, match="fov"):
        FiducialGeometry.from_describe({"fov": 7.0})
