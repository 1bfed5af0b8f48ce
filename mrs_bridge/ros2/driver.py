"""``ros2`` driver: a ROS 2 robot as RSAL devices, over rmw_zenoh's wire (thesis 4.5, "Adoption
of another MRS").

Provides ``position2d`` (from the robot's ``odom``, ``nav_msgs/msg/Odometry``; velocity commands
out as ``cmd_vel``, ``geometry_msgs/msg/Twist``) and ``laser`` (from its ``scan``,
``sensor_msgs/msg/LaserScan``), so that the RSAL layer, every agent and every scenario drive a
ROS 2 robot unchanged::

    [[driver]]
    name = "ros2"
    provides = ["r5:position2d:0", "r5:laser:0"]
    namespace = "/robot5"      # the ROS robot's namespace: /robot5/odom, /robot5/scan, /robot5/cmd_vel
    domain = 0                 # ROS domain id
    max_speed = [0.5, 1.0]     # m/s, rad/s: commands over it are rejected, as by every base
    laser_pose = [0.13, 0, 0]  # the laser on the robot (x m, y m, yaw deg)

The driver joins the ROS graph on the server's own Zenoh session as the node
``<namespace>/rsal_import`` (subscriptions ``odom`` and ``scan``, publisher ``cmd_vel``; graph
tokens as rmw_zenoh writes them, :mod:`mrs_bridge.ros2.rmw`). Messages arrive on Zenoh threads and
are only parked there; the scheduler publishes each new one as Position2dData or RangerData.
Safety as for every base (:mod:`mrs_bridge.baseguard`): a velocity holds for ``cmd_timeout``,
then the driver sends a zero Twist itself; the emergency stop latches. The devices are announced
once the first odometry and the first scan came in (a token means the device answers).
Ranges ROS marks invalid (NaN, +inf) are reported as ``range_max``, as RSAL scans are clipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rsal.msgs import ErrorCode, MessageError, Position2dData, RangerData, RpcError, VelocityCmd

from ..baseguard import ESTOP_OPS, BaseGuard
from ..config import ConfigError
from ..driver import Driver, OutOfRange, register
from ..params import param, parse_params
from . import types
from .rmw import Participant
from .wire import DEFAULT_QOS, SENSOR_QOS

__all__ = ["Ros2Import"]


@dataclass(frozen=True)
class Ros2ImportParams:
    namespace: str = param(doc="the ROS robot's namespace", example='"/robot5"')
    domain: int = param(0, min=0, max=232)
    max_speed: tuple[float, float] = param((0.5, 1.0), doc="m/s, rad/s: the base's limits")
    laser_pose: tuple[float, float, float] = param((0.0, 0.0, 0.0), doc="x m, y m, yaw deg of the laser on the robot")
    node_name: str = param("rsal_import")
    cmd_timeout: Any = param(None, doc="s, read by the base guard (mrs_bridge.baseguard)")

    def __post_init__(self):
        ns = self.namespace
        if not ns.startswith("/") or "//" in ns or (len(ns) > 1 and ns.endswith("/")):
            raise ValueError(f"namespace = {self.namespace!r} must be a ROS namespace like '/robot5'")


@register("ros2")
class Ros2Import(Driver):
    driver_name = "ros2"
    interfaces = ("position2d", "laser")
    default_rate = 20.0
    data_types = {"position2d": "Position2dData", "laser": "RangerData"}
    cmd_types = {"position2d": "VelocityCmd"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        self.p = parse_params(Ros2ImportParams, cfg)
        self.base = next(iter(self.provided("position2d")), None)
        self.laser = next(iter(self.provided("laser")), None)
        if self.base is None and self.laser is None:
            raise ConfigError(f"{cfg.where}: provides neither a position2d nor a laser")
        self.guard = BaseGuard.for_driver(self, (self.base or self.laser).node)
        self._odom: Any = None  # latest messages, set on Zenoh threads, read by the scheduler
        self._scan: Any = None
        self._sent_odom: Any = None
        self._sent_scan: Any = None
        self._node = None
        self._cmd = None

    # ------------------------------------------------------------------ lifecycle
    def setup(self) -> None:
        part = Participant(self.server.session, self.p.domain)
        self._node = part.node(self.p.namespace, self.p.node_name)
        if self.base is not None:
            self._node.subscription("odom", "nav_msgs/msg/Odometry", self._on_odom, DEFAULT_QOS)
            self._cmd = self._node.publisher("cmd_vel", "geometry_msgs/msg/Twist", DEFAULT_QOS)
        if self.laser is not None:
            self._node.subscription("scan", "sensor_msgs/msg/LaserScan", self._on_scan, SENSOR_QOS)

    def _on_odom(self, msg, att) -> None:  # Zenoh thread: park it
        self._odom = msg

    def _on_scan(self, msg, att) -> None:
        self._scan = msg

    def ready(self) -> bool:
        return (self.base is None or self._odom is not None) and (self.laser is None or self._scan is not None)

    def update(self, now: float) -> None:
        if self.base is not None and self.guard.expired():
            self._twist(0.0, 0.0)
        o = self._odom
        if self.base is not None and o is not None and o is not self._sent_odom:
            self._sent_odom = o
            self.publish(self.base, self._position(o))
        s = self._scan
        if self.laser is not None and s is not None and s is not self._sent_scan:
            self._sent_scan = s
            self.publish(self.laser, self._ranger(s))

    def shutdown(self) -> None:
        if self._cmd is not None and not self._cmd.closed:
            try:
                self._twist(0.0, 0.0)
            except Exception:  # the session is closing
                pass
        if self._node is not None:
            self._node.close()

    # ------------------------------------------------------------------ conversions
    @staticmethod
    def _t(header) -> float:
        return header.stamp.sec + header.stamp.nanosec * 1e-9

    def _position(self, o) -> Position2dData:
        q = o.pose.pose.orientation
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        p, tw = o.pose.pose.position, o.twist.twist
        return Position2dData(
            self._t(o.header),
            (float(p.x), float(p.y), yaw),
            (float(tw.linear.x), float(tw.linear.y), float(tw.angular.z)),
            timed_out=self.guard.timed_out,
            estop=self.guard.estop,
        )

    @staticmethod
    def _ranger(s) -> RangerData:
        lo, hi = float(s.range_min), float(s.range_max)
        r = np.asarray(s.ranges, dtype=np.float32)
        r = np.clip(np.nan_to_num(r, nan=hi, posinf=hi, neginf=lo), lo, hi).astype(np.float32)
        return RangerData(Ros2Import._t(s.header), r, float(s.angle_min), float(s.angle_increment), lo, hi)

    # ------------------------------------------------------------------ commands
    def _twist(self, v: float, w: float) -> None:
        self._cmd.publish(types.twist(v, w))

    def _command(self, c: VelocityCmd, *, rpc: bool = False) -> None:
        vmax, wmax = self.p.max_speed
        if abs(c.v) > vmax + 1e-9 or abs(c.w) > wmax + 1e-9:
            raise OutOfRange(f"v={c.v:g} m/s, w={c.w:g} rad/s exceeds the limits |v| <= {vmax:g}, |w| <= {wmax:g}")
        if c.vy != 0.0:
            raise OutOfRange(f"vy={c.vy:g}: this base takes no sideways speed")
        self.guard.check(rpc=rpc)
        self._twist(c.v, c.w)
        self.guard.command(c.v, c.w)

    def on_cmd(self, addr, msg) -> None:
        if addr != self.base:
            raise MessageError(f"{addr} takes no commands")
        self._command(VelocityCmd.from_dict(msg))

    def ops(self, addr):
        return ["stop", *ESTOP_OPS] if addr == self.base else []

    def on_rpc(self, addr, op, args):
        if addr == self.base:
            if op == "set_velocity":
                self._command(VelocityCmd.from_dict(args), rpc=True)
                return {}
            if op == "stop":
                self._twist(0.0, 0.0)
                self.guard.stopped()
                return {}
            if op == "estop":
                self.guard.press()
                self._twist(0.0, 0.0)
                return {"estop": True}
            if op == "release":
                self.guard.release()
                return {"estop": False}
        raise RpcError(ErrorCode.UNKNOWN_OP, f"{addr} has no operation {op!r}; it has: {', '.join(self.all_ops(addr))}")

    def geometry(self, addr):
        ns = self.p.namespace.rstrip("/")
        if addr == self.base:
            return {"frame": "odom", "max_speed": list(self.p.max_speed), "ros": f"{ns}/odom, {ns}/cmd_vel"}
        s = self._scan
        x, y, a = self.p.laser_pose
        sensor = {"pose": [0.0, 0.0, 0.0], "fov": 0.0, "samples": 0, "range_min": 0.0, "range_max": 0.0}
        if s is not None:
            n = len(s.ranges)
            sensor = {
                "pose": [0.0, 0.0, 0.0],
                "fov": float(s.angle_increment) * (n - 1),
                "samples": n,
                "range_min": float(s.range_min),
                "range_max": float(s.range_max),
            }
        return {"kind": "laser", "pose": [x, y, math.radians(a)], "sensors": [sensor], "ros": f"{ns}/scan"}
