"""ROS 2 message types for the rmw_zenoh bridge: names, type hashes, CDR, and builders from RSAL data.

The message definitions, the CDR (de)serialisation and the type hashes come from ``rosbags``
(a pure-Python ROS 2 type store; the Jazzy store is the default). Hashes are REP-2016's RIHS01:
sha256 of the canonical JSON type description, computed by the type store from the definitions,
never written down here (the tests compare them with the values ROS 2 itself publishes).

Names in three forms:

- the ROS name ``sensor_msgs/msg/LaserScan`` (what ``ros2 topic list -t`` prints);
- the DDS name ``sensor_msgs::msg::dds_::LaserScan_`` (what rmw_zenoh puts in keys and tokens);
- the hash ``RIHS01_64c19139...`` (Humble peers write ``TypeHashNotSupported`` instead).

Builders (:func:`laser_scan`, :func:`odometry`, :func:`tf_message`) turn RSAL data
(``docs/protocol.md``: RangerData, Position2dData) into ROS messages (``docs/ros2.md``); decoders
(:func:`twist_to_velocity`) do the reverse for commands.
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np

__all__ = [
    "TYPESTORE",  # noqa: F822 - made on first use (module __getattr__)
    "HASH_NOT_SUPPORTED",
    "dds_name",
    "ros_name",
    "type_hash",
    "encode",
    "decode",
    "stamp",
    "yaw_quaternion",
    "laser_scan",
    "odometry",
    "tf_message",
    "twist",
    "twist_to_velocity",
    "pose_with_covariance_stamped",
    "path",
    "pose_stamped_to_goal",
    "occupancy_grid",
    "sonar_range",
]

#: what rmw_zenoh on Humble writes where later distributions write a RIHS01 hash
HASH_NOT_SUPPORTED = "TypeHashNotSupported"


@cache
def _store() -> Any:
    """The type store of the ROS 2 distribution whose message definitions (and so hashes) the bridge
    speaks, made on first use: rosbags loads every distribution's definitions, a fifth of a second
    that a device server without a ROS 2 driver (every ``rsal sim``) should not pay."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _t(ros: str) -> Any:
    """The message class of ``ros`` (``sensor_msgs/msg/LaserScan``)."""
    return _store().types[ros]


def __getattr__(name: str) -> Any:
    if name == "TYPESTORE":  # the Jazzy type store (module attribute, made on first use)
        return _store()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def dds_name(ros: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (the DDS mangling rmw_zenoh keeps)."""
    pkg, kind, name = _split(ros)
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_name(dds: str) -> str:
    """``pkg::msg::dds_::Name_`` -> ``pkg/msg/Name`` (inverse of :func:`dds_name`)."""
    parts = dds.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        raise ValueError(f"type name {dds!r} is not a DDS name like 'sensor_msgs::msg::dds_::LaserScan_'")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def _split(ros: str) -> tuple[str, str, str]:
    parts = ros.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"type name {ros!r} must look like 'sensor_msgs/msg/LaserScan'")
    return parts[0], parts[1], parts[2]


@cache
def type_hash(ros: str) -> str:
    """REP-2016 hash ``RIHS01_<64 hex>`` of a message type, computed from its definition."""
    if ros not in _store().types:
        raise ValueError(f"unknown ROS 2 message type {ros!r} (the bridge knows the Jazzy standard messages)")
    return _store().hash_rihs01(ros)


def encode(msg: Any, ros: str) -> bytes:
    """CDR little-endian with its 4-byte encapsulation header ``00 01 00 00``."""
    return bytes(_store().serialize_cdr(msg, ros))


def decode(data: bytes | bytearray | memoryview, ros: str) -> Any:
    """The message of a CDR payload (raises on malformed bytes)."""
    return _store().deserialize_cdr(bytes(data), ros)


# ---------------------------------------------------------------------------- builders
def stamp(t: float) -> Any:
    """``builtin_interfaces/msg/Time`` of ``t`` seconds (the RSAL clock: wall or simulation)."""
    sec = math.floor(t)
    nsec = min(int(round((t - sec) * 1e9)), 999_999_999)
    return _t("builtin_interfaces/msg/Time")(sec=int(sec), nanosec=nsec)


def _header(t: float, frame: str) -> Any:
    return _t("std_msgs/msg/Header")(stamp=stamp(t), frame_id=frame)


def yaw_quaternion(yaw: float) -> Any:
    """``geometry_msgs/msg/Quaternion`` of a rotation by ``yaw`` about z."""
    h = 0.5 * yaw
    return _t("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=math.sin(h), w=math.cos(h))


_ZERO36 = np.zeros(36, dtype=np.float64)


def laser_scan(scan, frame: str, scan_time: float = 0.0) -> Any:
    """``sensor_msgs/msg/LaserScan`` from a RangerData (angles in the laser's frame, metres)."""
    r = np.asarray(scan.ranges, dtype=np.float32)
    n = int(r.shape[0])
    return _t("sensor_msgs/msg/LaserScan")(
        header=_header(scan.t, frame),
        angle_min=float(scan.angle_min),
        angle_max=float(scan.angle_min + (n - 1) * scan.angle_step) if n else float(scan.angle_min),
        angle_increment=float(scan.angle_step),
        time_increment=0.0,
        scan_time=float(scan_time),
        range_min=float(scan.range_min),
        range_max=float(scan.range_max),
        ranges=r,
        intensities=np.zeros(0, dtype=np.float32),
    )


def _pose(x: float, y: float, yaw: float) -> Any:
    return _t("geometry_msgs/msg/Pose")(
        position=_t("geometry_msgs/msg/Point")(x=float(x), y=float(y), z=0.0), orientation=yaw_quaternion(yaw)
    )


def _vec(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
    return _t("geometry_msgs/msg/Vector3")(x=float(x), y=float(y), z=float(z))


def twist(v: float, w: float, vy: float = 0.0) -> Any:
    """``geometry_msgs/msg/Twist``: forward ``v`` and sideways ``vy`` m/s, turn rate ``w`` rad/s."""
    return _t("geometry_msgs/msg/Twist")(linear=_vec(v, vy), angular=_vec(0.0, 0.0, w))


def odometry(data, frame: str, child_frame: str) -> Any:
    """``nav_msgs/msg/Odometry`` from a Position2dData: pose in ``frame`` (odom), twist in
    ``child_frame`` (base_link). Covariances are zero: the simulator and P2OS report none."""
    x, y, yaw = data.pose
    vx, vy, w = data.vel
    return _t("nav_msgs/msg/Odometry")(
        header=_header(data.t, frame),
        child_frame_id=child_frame,
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=_pose(x, y, yaw), covariance=_ZERO36),
        twist=_t("geometry_msgs/msg/TwistWithCovariance")(twist=twist(vx, w, vy), covariance=_ZERO36),
    )


def tf_message(t: float, transforms: list[tuple[str, str, tuple[float, float, float]]]) -> Any:
    """``tf2_msgs/msg/TFMessage`` of planar transforms ``(parent, child, (x, y, yaw))`` at time ``t``."""
    tfs = []
    for parent, child, (x, y, yaw) in transforms:
        tfs.append(
            _t("geometry_msgs/msg/TransformStamped")(
                header=_header(t, parent),
                child_frame_id=child,
                transform=_t("geometry_msgs/msg/Transform")(translation=_vec(x, y), rotation=yaw_quaternion(yaw)),
            )
        )
    return _t("tf2_msgs/msg/TFMessage")(transforms=tfs)


def twist_to_velocity(msg: Any) -> tuple[float, float, float]:
    """``(v, w, vy)`` of a Twist: linear.x, angular.z, linear.y (a planar base ignores the rest)."""
    return float(msg.linear.x), float(msg.angular.z), float(msg.linear.y)


def _cov6(cov3) -> np.ndarray:
    """A planar 3x3 covariance (x, y, yaw; row-major) in ROS's 6x6 (x, y, z, roll, pitch, yaw)."""
    c3 = np.asarray(cov3, dtype=np.float64).reshape(3, 3)
    c6 = np.zeros((6, 6), dtype=np.float64)
    idx = np.array([0, 1, 5])
    c6[np.ix_(idx, idx)] = c3
    return c6.ravel()


def pose_with_covariance_stamped(data, frame: str) -> Any:
    """``geometry_msgs/msg/PoseWithCovarianceStamped`` from a LocalizeData (AMCL's ``amcl_pose``)."""
    return _t("geometry_msgs/msg/PoseWithCovarianceStamped")(
        header=_header(data.t, frame),
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=_pose(*data.pose), covariance=_cov6(data.cov)),
    )


def path(t: float, frame: str, poses: list[tuple[float, float, float]]) -> Any:
    """``nav_msgs/msg/Path`` through planar ``poses`` (x, y, yaw) in ``frame``."""
    return _t("nav_msgs/msg/Path")(
        header=_header(t, frame),
        poses=[_t("geometry_msgs/msg/PoseStamped")(header=_header(t, frame), pose=_pose(*p)) for p in poses],
    )


def pose_stamped_to_goal(msg: Any) -> tuple[str, tuple[float, float, float]]:
    """``(frame_id, (x, y, yaw))`` of a ``geometry_msgs/msg/PoseStamped`` (yaw about z)."""
    q = msg.pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    return msg.header.frame_id, (float(msg.pose.position.x), float(msg.pose.position.y), yaw)


def occupancy_grid(m, t: float, frame: str) -> Any:
    """``nav_msgs/msg/OccupancyGrid`` from a MapData: Player's cells (-1 free, 0 unknown, +1
    occupied; row-major from the bottom row, as ROS's) as ROS's (0 free, -1 unknown, 100 occupied),
    the origin the bottom-left corner's world position."""
    cells = np.asarray(m.cells, dtype=np.int8).reshape(-1)
    data = np.where(cells > 0, 100, np.where(cells < 0, 0, -1)).astype(np.int8)
    info = _t("nav_msgs/msg/MapMetaData")(
        map_load_time=stamp(t),
        resolution=float(m.resolution),
        width=int(m.width),
        height=int(m.height),
        origin=_pose(float(m.origin[0]), float(m.origin[1]), 0.0),
    )
    return _t("nav_msgs/msg/OccupancyGrid")(header=_header(t, frame), info=info, data=data)


def sonar_range(scan, k: int, frame: str, fov: float) -> Any:
    """``sensor_msgs/msg/Range`` (ultrasound) of transducer ``k`` of a sonar ring's RangerData."""
    R = _t("sensor_msgs/msg/Range")
    return R(
        header=_header(scan.t, frame),
        radiation_type=R.ULTRASOUND,
        field_of_view=float(fov),
        min_range=float(scan.range_min),
        max_range=float(scan.range_max),
        range=float(scan.ranges[k]),
        variance=0.0,
    )
