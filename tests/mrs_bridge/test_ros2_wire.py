"""The ROS 2 wire without ROS: type hashes against the values ROS 2 publishes, CDR bytes against
hand-derived vectors, the rmw_zenoh attachment, topic keys and graph tokens (docs/ros2.md)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import zenoh.ext as zext

from mrs_bridge.ros2 import types, wire
from rsal.interfaces.position2d import Position2dData
from rsal.interfaces.ranger import RangerData

# The hashes `ros2 topic info --verbose` prints on Jazzy (and rmw_zenoh puts in its keys).
PUBLISHED = {
    "geometry_msgs/msg/Twist": "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "sensor_msgs/msg/LaserScan": "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
    "nav_msgs/msg/Odometry": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "nav_msgs/msg/OccupancyGrid": "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "geometry_msgs/msg/PoseWithCovarianceStamped": (
        "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e"
    ),
}


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_type_hash_equals_the_published_rihs01(name):
    assert types.type_hash(name) == PUBLISHED[name]


def test_unknown_type_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown ROS 2 message type 'foo_msgs/msg/Bar'"):
        types.type_hash("foo_msgs/msg/Bar")


def test_dds_names_round_trip():
    assert types.dds_name("sensor_msgs/msg/LaserScan") == "sensor_msgs::msg::dds_::LaserScan_"
    assert types.ros_name("geometry_msgs::msg::dds_::Twist_") == "geometry_msgs/msg/Twist"
    with pytest.raises(ValueError, match="not a DDS name"):
        types.ros_name("geometry_msgs/msg/Twist")


def test_twist_cdr_equals_the_reference_vector():
    # encapsulation CDR_LE 00 01 00 00, then six float64 little-endian, no padding.
    ref = bytes.fromhex("00010000") + struct.pack("<6d", 0.5, -0.25, 0.0, 0.0, 0.0, 1.5)
    assert types.encode(types.twist(0.5, 1.5, -0.25), "geometry_msgs/msg/Twist") == ref
    back = types.decode(ref, "geometry_msgs/msg/Twist")
    assert types.twist_to_velocity(back) == (0.5, 1.5, -0.25)


def test_laser_scan_cdr_equals_the_reference_vector():
    scan = RangerData(1.5, np.array([1.0, 2.0, 4.0], dtype=np.float32), -0.5, 0.5, 0.02, 8.0)
    got = types.encode(types.laser_scan(scan, "r0/laser", scan_time=0.1), "sensor_msgs/msg/LaserScan")
    ref = (
        bytes.fromhex("00010000")
        + struct.pack("<iI", 1, 500_000_000)  # header.stamp
        + struct.pack("<I", 9)
        + b"r0/laser\x00"  # frame_id: length with the NUL, the bytes, the NUL
        + b"\x00\x00\x00"  # align the float32s on 4 (offset 21 -> 24)
        + struct.pack("<7f", -0.5, 0.5, 0.5, 0.0, 0.1, 0.02, 8.0)  # angle_min/max/increment, time_inc, scan_time, range
        + struct.pack("<I3f", 3, 1.0, 2.0, 4.0)  # ranges
        + struct.pack("<I", 0)  # intensities: empty
    )
    assert got == ref


def test_odometry_and_tf_carry_the_pose_as_a_yaw_quaternion():
    d = Position2dData(2.25, (1.0, 2.0, np.pi / 2), (0.3, 0.0, -0.1))
    odom = types.decode(
        types.encode(types.odometry(d, "r0/odom", "r0/base_link"), "nav_msgs/msg/Odometry"), "nav_msgs/msg/Odometry"
    )
    assert (odom.header.frame_id, odom.child_frame_id) == ("r0/odom", "r0/base_link")
    assert (odom.header.stamp.sec, odom.header.stamp.nanosec) == (2, 250_000_000)
    q = odom.pose.pose.orientation
    assert (q.z, q.w) == pytest.approx((np.sqrt(0.5), np.sqrt(0.5)))
    assert (odom.twist.twist.linear.x, odom.twist.twist.angular.z) == pytest.approx((0.3, -0.1))
    tf = types.tf_message(2.25, [("r0/odom", "r0/base_link", (1.0, 2.0, 0.0))])
    back = types.decode(types.encode(tf, "tf2_msgs/msg/TFMessage"), "tf2_msgs/msg/TFMessage")
    assert back.transforms[0].child_frame_id == "r0/base_link"
    assert back.transforms[0].transform.translation.y == 2.0


def test_amcl_pose_path_and_goal_pose():
    from rsal.interfaces.localize import LocalizeData

    cov = (0.04, 0.01, 0.0, 0.01, 0.09, 0.0, 0.0, 0.0, 0.16)
    loc = LocalizeData(3.0, (1.0, -1.0, 0.5), cov)
    name = "geometry_msgs/msg/PoseWithCovarianceStamped"
    m = types.decode(types.encode(types.pose_with_covariance_stamped(loc, "map"), name), name)
    c6 = np.asarray(m.pose.covariance).reshape(6, 6)
    assert (c6[0, 0], c6[0, 1], c6[1, 1], c6[5, 5], c6[2, 2]) == (0.04, 0.01, 0.09, 0.16, 0.0)
    assert m.header.frame_id == "map" and m.pose.pose.position.x == 1.0
    p = types.path(3.0, "map", [(0.0, 0.0, 0.0), (1.0, 2.0, -0.5)])
    back = types.decode(types.encode(p, "nav_msgs/msg/Path"), "nav_msgs/msg/Path")
    assert [(q.pose.position.x, q.pose.position.y) for q in back.poses] == [(0.0, 0.0), (1.0, 2.0)]
    frame, goal = types.pose_stamped_to_goal(back.poses[1])
    assert frame == "map" and goal == pytest.approx((1.0, 2.0, -0.5))


def test_attachment_layout_is_zenohs_serialisation_of_int64_int64_bytes():
    gid = bytes(range(16))
    att = wire.Attachment(7, 1_700_000_000_123_456_789, gid).to_bytes()
    assert len(att) == 33
    # the same bytes as Zenoh's own serialiser of (int64, int64, bytes), as zenoh-cpp writes it
    assert att == zext.z_serialize((zext.Int64(7), zext.Int64(1_700_000_000_123_456_789), gid)).to_bytes()
    assert att[:8] == (7).to_bytes(8, "little") and att[16] == 16 and att[17:] == gid
    assert wire.Attachment.from_bytes(att) == wire.Attachment(7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(wire.WireError, match="attachment must be 33 bytes"):
        wire.Attachment.from_bytes(att[:-1])
    with pytest.raises(wire.WireError, match="got none"):
        wire.Attachment.from_bytes(None)


def test_topic_keys():
    h = PUBLISHED["sensor_msgs/msg/LaserScan"]
    k = wire.topic_key(0, "/r0/scan", types.dds_name("sensor_msgs/msg/LaserScan"), h)
    assert k == "0/r0/scan/sensor_msgs::msg::dds_::LaserScan_/" + PUBLISHED["sensor_msgs/msg/LaserScan"]
    assert wire.parse_topic_key(k) == (
        0,
        "/r0/scan",
        "sensor_msgs::msg::dds_::LaserScan_",
        PUBLISHED["sensor_msgs/msg/LaserScan"],
    )
    assert wire.topic_key(3, "/tf", "t", "h") == "3/tf/t/h"
    assert wire.topic_keyexpr_any_hash(0, "/r0/cmd_vel", "x") == "0/r0/cmd_vel/x/*"


def test_qos_strings_as_rmw_zenoh_writes_them():
    assert wire.QoS().to_keyexpr() == "::,:,:,:,,"
    assert wire.DEFAULT_QOS.to_keyexpr() == "::,10:,:,:,,"
    assert wire.SENSOR_QOS.to_keyexpr() == "2::,5:,:,:,,"
    tl = wire.QoS(durability=1, depth=1)
    assert tl.to_keyexpr() == ":1:,1:,:,:,,"
    for q in (wire.QoS(), wire.DEFAULT_QOS, wire.SENSOR_QOS, tl, wire.QoS(history=2, deadline=(1, 5))):
        assert wire.QoS.from_keyexpr(q.to_keyexpr()) == q
    with pytest.raises(wire.WireError, match="not rmw_zenoh's form"):
        wire.QoS.from_keyexpr("1:2:1,10")  # the pre-Jazzy four-field form


def test_graph_tokens_build_and_parse_back():
    h = PUBLISHED["geometry_msgs/msg/Twist"]
    node = wire.Entity(0, "aabb", 3, 3, wire.Kind.NODE, "/r0", "rsal")
    assert node.token == "@ros2_lv/0/aabb/3/3/NN/%/%r0/rsal"
    sub = wire.Entity(
        0,
        "aabb",
        3,
        5,
        wire.Kind.SUBSCRIPTION,
        "/r0",
        "rsal",
        topic="/r0/cmd_vel",
        type="geometry_msgs::msg::dds_::Twist_",
        type_hash=h,
        qos=wire.DEFAULT_QOS,
    )
    twist = "geometry_msgs::msg::dds_::Twist_"
    assert sub.token == f"@ros2_lv/0/aabb/3/5/MS/%/%r0/rsal/%r0%cmd_vel/{twist}/{h}/::,10:,:,:,,"
    root = wire.Entity(
        7,
        "aabb",
        1,
        2,
        wire.Kind.PUBLISHER,
        "/",
        "talker",
        topic="/chatter",
        type="std_msgs::msg::dds_::String_",
        type_hash=wire.demangle("TypeHashNotSupported"),
        qos=wire.SENSOR_QOS,
    )
    assert root.token.startswith("@ros2_lv/7/aabb/1/2/MP/%/%/talker/%chatter/")
    for e in (node, sub, root):
        assert wire.Entity.parse(e.token) == e
        assert len(e.gid) == 16
    assert node.gid != sub.gid
    # a token as another rmw_zenoh peer wrote it
    seen = wire.Entity.parse(f"@ros2_lv/0/1f2e/0/11/MP/%/%/teleop/%r0%cmd_vel/{twist}/{h}/::,7:,:,:,,")
    assert (seen.kind, seen.namespace, seen.node, seen.topic, seen.qos.depth) == (
        wire.Kind.PUBLISHER,
        "/",
        "teleop",
        "/r0/cmd_vel",
        7,
    )
    for bad, msg in (
        ("@ros2_lv/0/z/0/0/XX/%/%/n", "entity kind 'XX'"),
        ("rsal/r0/laser/0", "not an rmw_zenoh graph token"),
        ("@ros2_lv/0/z/0/0/MP/%/%/n", "13 parts"),
    ):
        with pytest.raises(wire.WireError, match=msg):
            wire.Entity.parse(bad)


def test_the_documented_wire_examples_are_what_the_code_writes():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "ros2.md").read_text()
    h = PUBLISHED["sensor_msgs/msg/LaserScan"]
    assert f"`{wire.topic_key(0, '/r0/scan', types.dds_name('sensor_msgs/msg/LaserScan'), h)}`" in doc
    assert f"profile is `{wire.SENSOR_QOS.to_keyexpr()}`, rclcpp's default `{wire.DEFAULT_QOS.to_keyexpr()}`" in doc
    sub = wire.Entity(
        0,
        "9652c07d455a5b1bed06e17cd8f36b84",
        0,
        3,
        wire.Kind.SUBSCRIPTION,
        "/r0",
        "rsal",
        topic="/r0/cmd_vel",
        type=types.dds_name("geometry_msgs/msg/Twist"),
        type_hash=PUBLISHED["geometry_msgs/msg/Twist"],
        qos=wire.DEFAULT_QOS,
    )
    head, tail = sub.token.split("RIHS01_9c45")
    assert f"`{head}RIHS01_9c45...{tail[-len('/::,10:,:,:,,') :]}`" in doc


def test_robot_names_become_ros_namespaces():
    from mrs_bridge.ros2.export import ros_namespace

    assert ros_namespace("r0") == "/r0"
    assert ros_namespace("pioneer-2.a") == "/pioneer_2_a"
    assert ros_namespace("7up") == "/_7up"
