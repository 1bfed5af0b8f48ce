"""The exporter behind ``rsal ros2``: the RSAL fleet as ROS 2 nodes on rmw_zenoh's wire.

For every robot the fabric discovers (liveliness of ``rsal/<robot>/position2d/0``,
``.../laser/<i>``, ``.../sonar/<i>``, ``.../localize/0``, ``.../planner/0``; thesis 3.5's DeviceNode), one ROS node
``/<robot>/<node name>``:

- publishes ``/<robot>/scan`` (``sensor_msgs/msg/LaserScan``, sensor-data QoS) from ``laser:0``
  (``scan_<i>`` for ``laser:<i>``);
- publishes ``/<robot>/sonar_<k>`` (``sensor_msgs/msg/Range``) per transducer of ``sonar:0``;
- publishes ``/<robot>/odom`` (``nav_msgs/msg/Odometry``) from ``position2d:0`` and, with each
  odometry message, ``/tf`` (``tf2_msgs/msg/TFMessage``): ``odom -> base_link``;
- publishes ``/tf_static`` (transient local, as tf2's static broadcaster): ``base_link -> laser``
  and ``base_link -> sonar_<k>`` (the mounts from the sensors' ``describe`` geometry), again
  whenever a sensor joins or leaves;
- subscribes ``/<robot>/cmd_vel`` (``geometry_msgs/msg/Twist``) and sends each as the base's
  VelocityCmd (clipped to the base's ``max_speed``): the device server's command timeout stops
  the robot when the Twists stop, as for any RSAL commander;
- with a localizer (``localize:0``, the ``amcl`` driver): publishes ``/<robot>/amcl_pose``
  (``geometry_msgs/msg/PoseWithCovarianceStamped`` in the map frame) and ``map -> odom`` on
  ``/tf`` (the estimate composed with the inverse of the latest odometry pose);
- with a global planner (``planner:0``, ``wavefront``): subscribes ``/<robot>/goal_pose``
  (``geometry_msgs/msg/PoseStamped`` in the map frame -> the planner's ``set_goal``) and publishes
  ``/<robot>/plan`` (``nav_msgs/msg/Path``, the planner's waypoints) whenever the goal or the
  number of waypoints changes.

The fleet-wide ``/map`` and ``/clock`` come from :mod:`mrs_bridge.ros2.fleet`.

Frames are ``<prefix>odom``, ``<prefix>base_link``, ``<prefix>laser`` with the prefix
``<robot>/`` by default, so that one rviz2 shows the whole fleet; the map frame (``map``) is
the fleet's shared floor plan and has no prefix. Robots that join later are
exported when their devices appear; a device whose token goes away takes its topics with it,
and a robot with none left takes its node. What maps to what: ``docs/ros2.md``.

Threads: discovery runs on the fabric's dispatcher; RSAL data arrives on Zenoh threads and only
parks the latest sample per topic in an outbox (latest wins); one thread builds, encodes and
puts the ROS messages, so a slow encoder never holds a Zenoh thread (STYLE rule 2).
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rsal import geometry
from rsal.client import Fabric
from rsal.data import Position
from rsal.interfaces.position2d import VelocityCmd
from rsal.interfaces.ranger import RangerGeometry
from rsal.keys import DeviceAddr

from . import types
from .fleet import FleetTopics
from .rmw import Node, Outbox, Participant, Publisher, Subscription
from .wire import DEFAULT_QOS, SENSOR_QOS, QoS

__all__ = ["Exporter", "ExportConfig", "ros_namespace"]

log = logging.getLogger(__name__)

TF_QOS = QoS(depth=100)  # tf2_ros's TransformBroadcaster: reliable, keep last 100
TF_STATIC_QOS = QoS(durability=1, depth=1)  # tf2_ros StaticTransformBroadcaster: transient local, keep last 1


@dataclass(frozen=True)
class ExportConfig:
    """``robots``: node-name patterns (a Zenoh chunk, ``*`` wildcards: ``r*``); ``frame_prefix``
    with ``{robot}`` for the robot's name; ``node_name``: the ROS node in each robot's namespace."""

    domain: int = 0
    robots: tuple[str, ...] = ("*",)
    frame_prefix: str = "{robot}/"
    node_name: str = "rsal"
    map_frame: str = "map"
    map_node: str = "*"  # the node whose map device becomes /map ("" for none)
    clock: bool = True  # /clock from a simulation device, when one runs


@dataclass
class _Laser:
    addr: DeviceAddr
    proxy: Any
    pub: Publisher
    frame: str
    mount: tuple[float, float, float]
    listener: Callable


@dataclass
class _Sonar:
    """A sonar ring: one Range topic and frame per transducer."""

    addr: DeviceAddr
    proxy: Any
    pubs: list[Publisher]
    frames: list[str]
    mounts: list[tuple[float, float, float]]
    listener: Callable


@dataclass
class _Base:
    addr: DeviceAddr
    proxy: Any
    odom: Publisher
    tf: Publisher
    cmd: Subscription
    listener: Callable
    limits: tuple[float, float] | None


@dataclass
class _Nav:
    """A localizer's or a planner's export: its proxy, listener, publisher and subscription."""

    addr: DeviceAddr
    proxy: Any
    listener: Callable
    pub: Publisher
    sub: Subscription | None = None


@dataclass
class _Robot:
    name: str
    node: Node
    base: _Base | None = None
    lasers: dict[int, _Laser] = field(default_factory=dict)
    sonars: dict[int, _Sonar] = field(default_factory=dict)
    localize: _Nav | None = None
    planner: _Nav | None = None
    static: Publisher | None = None  # /tf_static: base_link -> each sensor, made with the first sensor

    def topics(self) -> list[str]:
        t = [lz.pub.entity.topic.rsplit("/", 1)[-1] for _, lz in sorted(self.lasers.items())]
        t += [f"sonar{'' if i == 0 else i}_0..{len(s.pubs) - 1}" for i, s in sorted(self.sonars.items())]
        if self.base is not None:
            t += ["odom", "tf", "cmd_vel"]
        if self.localize is not None:
            t += ["amcl_pose"]
        if self.planner is not None:
            t += ["goal_pose", "plan"]
        return t

    def empty(self) -> bool:
        return (
            self.base is None and not self.lasers and not self.sonars and self.localize is None and self.planner is None
        )


def ros_namespace(robot: str) -> str:
    """The ROS namespace of a robot: ``/<robot>``, with every character ROS names do not allow
    (RSAL node names may hold ``-`` and ``.``) as ``_``, and ``_`` before a leading digit."""
    ns = re.sub(r"[^A-Za-z0-9_]", "_", robot)
    return "/" + ("_" + ns if ns[:1].isdigit() else ns)


class Exporter:
    """Export the robots of a fabric to a ROS 2 domain. Use as a context manager."""

    def __init__(self, fabric: Fabric, config: ExportConfig = ExportConfig(), on_change: Callable | None = None):
        """``on_change(exporter)`` after every change of what is exported (dispatcher thread)."""
        self.fabric = fabric
        self.config = config
        self.part = Participant(fabric.session, config.domain)
        self.outbox = Outbox()
        self.on_change = on_change
        self._robots: dict[str, _Robot] = {}
        self._lock = threading.Lock()
        self._closed = False
        ifaces = ("position2d", "laser", "sonar", "localize", "planner")
        templates = [f"rsal/{r}/{iface}/*" for r in config.robots for iface in ifaces]
        self._dnode = fabric.node(*templates)
        self._dnode.on_join(self._join)
        self._dnode.on_leave(self._leave)
        for a in self._dnode.devices():  # already alive before the listeners were in place
            fabric.dispatcher.submit(self._join, a)
        self.fleet = FleetTopics(self)

    def __enter__(self) -> Exporter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def fleet_topics(self) -> list[str]:
        """The fleet-wide topics exported now (``map``, ``clock``)."""
        fleet = getattr(self, "fleet", None)  # None while __init__ runs and a join comes in
        return fleet.topics() if fleet is not None else []

    def robots(self) -> dict[str, list[str]]:
        """Exported robots and their topics (relative to ``/<robot>``)."""
        with self._lock:
            return {n: r.topics() for n, r in sorted(self._robots.items())}

    # ------------------------------------------------------------------ frames
    def _frame(self, robot: str, name: str) -> str:
        return self.config.frame_prefix.format(robot=robot) + name

    # ------------------------------------------------------------------ discovery (dispatcher thread)
    def _robot(self, name: str) -> _Robot:
        r = self._robots.get(name)
        if r is None:
            ns = ros_namespace(name)
            if ns != f"/{name}":
                log.warning("robot %r: not a ROS name; exported in the namespace %s", name, ns)
            r = _Robot(name, self.part.node(ns, self.config.node_name))
            with self._lock:
                self._robots[name] = r
        return r

    def _describe(self, proxy) -> dict:
        try:
            return proxy.describe(timeout=5.0).geometry or {}
        except Exception as e:  # a silent device still gets its topics, with default geometry
            log.warning("%s: no describe answer (%s); exporting it with default geometry", proxy.addr, e)
            return {}

    def _join(self, addr: DeviceAddr) -> None:
        if self._closed:
            return
        if addr.interface == "position2d" and addr.index == 0:
            self._join_base(addr)
        elif addr.interface == "laser":
            self._join_laser(addr)
        elif addr.interface == "sonar":
            self._join_sonar(addr)
        elif addr.interface == "localize" and addr.index == 0:
            self._join_localize(addr)
        elif addr.interface == "planner" and addr.index == 0:
            self._join_planner(addr)
        else:
            return
        self._changed()

    def _join_base(self, addr: DeviceAddr) -> None:
        r = self._robot(addr.node)
        if r.base is not None:
            return
        proxy = self.fabric.device(addr)
        g = self._describe(proxy)
        ms = g.get("max_speed")
        limits = (float(ms[0]), float(ms[1])) if isinstance(ms, (list, tuple)) and len(ms) >= 2 else None
        odom = r.node.publisher("odom", "nav_msgs/msg/Odometry", DEFAULT_QOS)
        tf = r.node.publisher("/tf", "tf2_msgs/msg/TFMessage", TF_QOS)
        cmd = r.node.subscription("cmd_vel", "geometry_msgs/msg/Twist", self._cmd_vel_handler(r), DEFAULT_QOS)
        f_odom, f_base = self._frame(r.name, "odom"), self._frame(r.name, "base_link")
        post = self.outbox.post

        def build_tf(data):
            return types.tf_message(data.t, [(f_odom, f_base, data.pose)])

        def on_odom(data) -> None:
            post(odom, lambda d: types.odometry(d, f_odom, f_base), data)
            post(tf, build_tf, data)

        r.base = _Base(addr, proxy, odom, tf, cmd, on_odom, limits)
        proxy.add_listener(on_odom, inline=True)

    def _cmd_vel_handler(self, r: _Robot) -> Callable:
        warned = [False, False]

        def on_twist(msg, att) -> None:  # a Zenoh thread: hand the put to the dispatcher
            base = r.base
            if base is None:
                return
            v, w, vy = types.twist_to_velocity(msg)
            if vy != 0.0 and not warned[1]:
                warned[1] = True
                log.warning(
                    "/%s/cmd_vel: linear.y %.3g m/s ignored: the bases are differential drives (said once)", r.name, vy
                )
            vy = 0.0
            if base.limits is not None:
                vmax, wmax = base.limits
                cv, cw = max(-vmax, min(vmax, v)), max(-wmax, min(wmax, w))
                if (cv, cw) != (v, w) and not warned[0]:
                    warned[0] = True
                    log.warning(
                        "/%s/cmd_vel: (%.3g m/s, %.3g rad/s) is over the base's max_speed (%g, %g); clipped "
                        "(said once)",
                        r.name,
                        v,
                        w,
                        vmax,
                        wmax,
                    )
                v, w = cv, cw
            self.fabric.dispatcher.submit(self._send, base.addr, VelocityCmd(v, w, vy))

        return on_twist

    def _send(self, addr: DeviceAddr, cmd: VelocityCmd) -> None:
        if not self._closed:
            self.fabric.send(addr, cmd)

    def _join_laser(self, addr: DeviceAddr) -> None:
        r = self._robot(addr.node)
        if addr.index in r.lasers:
            return
        proxy = self.fabric.device(addr)
        desc = None
        try:
            desc = proxy.describe(timeout=5.0)
        except Exception as e:
            log.warning("%s: no describe answer (%s); exporting it with default geometry", addr, e)
        g = (desc.geometry if desc is not None else None) or {}
        pose = g.get("pose")
        mount = tuple(float(x) for x in pose[:3]) if isinstance(pose, (list, tuple)) and len(pose) >= 3 else (0, 0, 0)
        rate = float(desc.rate) if desc is not None and desc.rate else 0.0
        suffix = "" if addr.index == 0 else f"_{addr.index}"
        pub = r.node.publisher(f"scan{suffix}", "sensor_msgs/msg/LaserScan", SENSOR_QOS)
        frame = self._frame(r.name, f"laser{suffix}")
        scan_time = 1.0 / rate if rate > 0 else 0.0
        post = self.outbox.post

        def build(scan):
            return types.laser_scan(scan, frame, scan_time)

        def on_scan(scan) -> None:
            post(pub, build, scan)

        r.lasers[addr.index] = _Laser(addr, proxy, pub, frame, mount, on_scan)
        proxy.add_listener(on_scan, inline=True)
        self._publish_static(r)

    def _publish_static(self, r: _Robot) -> None:
        """Put the robot's sensor mounts (``base_link -> laser``, ``-> sonar_<k>``) on ``/tf_static``,
        transient local as tf2's static broadcaster does: a late listener gets the latest set."""
        f_base = self._frame(r.name, "base_link")
        tfs = [(f_base, lz.frame, lz.mount) for lz in list(r.lasers.values())]
        for so in list(r.sonars.values()):
            tfs += [(f_base, f, m) for f, m in zip(so.frames, so.mounts, strict=True)]
        if r.static is None:
            if not tfs:
                return
            r.static = r.node.publisher("/tf_static", "tf2_msgs/msg/TFMessage", TF_STATIC_QOS)
        self.outbox.post(r.static, lambda items: types.tf_message(0.0, items), tfs)

    def _join_sonar(self, addr: DeviceAddr) -> None:
        r = self._robot(addr.node)
        if addr.index in r.sonars:
            return
        proxy = self.fabric.device(addr)
        geo = RangerGeometry.from_describe(self._describe(proxy))
        if not geo.sensors:
            log.warning("%s: describe lists no transducers; the sonar ring is not exported", addr)
            return
        poses = [tuple(float(v) for v in p) for p in geo.sensor_poses()]  # robot frame
        fovs = [s.fov for s in geo.sensors]
        ring = "sonar" if addr.index == 0 else f"sonar{addr.index}"
        pubs = [r.node.publisher(f"{ring}_{k}", "sensor_msgs/msg/Range", SENSOR_QOS) for k in range(len(poses))]
        frames = [self._frame(r.name, f"{ring}_{k}") for k in range(len(poses))]
        post = self.outbox.post

        def on_scan(scan) -> None:
            for k, pub in enumerate(pubs[: len(scan.ranges)]):
                post(pub, lambda d, k=k: types.sonar_range(d, k, frames[k], fovs[k]), scan)

        r.sonars[addr.index] = _Sonar(addr, proxy, pubs, frames, poses, on_scan)
        proxy.add_listener(on_scan, inline=True)
        self._publish_static(r)

    def _leave(self, addr: DeviceAddr) -> None:
        r = self._robots.get(addr.node)
        if r is None or self._closed:
            return
        if addr.interface == "position2d" and addr.index == 0 and r.base is not None:
            b, r.base = r.base, None
            b.proxy.remove_listener(b.listener)
            b.proxy.undeclare()
            for e in (b.odom, b.tf, b.cmd):
                e.close()
        elif addr.interface == "laser" and addr.index in r.lasers:
            lz = r.lasers.pop(addr.index)
            lz.proxy.remove_listener(lz.listener)
            lz.proxy.undeclare()
            lz.pub.close()
        elif addr.interface == "sonar" and addr.index in r.sonars:
            so = r.sonars.pop(addr.index)
            so.proxy.remove_listener(so.listener)
            so.proxy.undeclare()
            for p in so.pubs:
                p.close()
        elif addr.interface in ("localize", "planner") and addr.index == 0 and getattr(r, addr.interface):
            nav = getattr(r, addr.interface)
            setattr(r, addr.interface, None)
            nav.proxy.remove_listener(nav.listener)
            nav.proxy.undeclare()
            for e in (nav.pub, nav.sub):
                if e is not None:
                    e.close()
        else:
            return
        if addr.interface in ("laser", "sonar") and not r.empty():
            self._publish_static(r)
        if r.empty():
            if r.static is not None:
                r.static.close()
            r.node.close()
            with self._lock:
                self._robots.pop(r.name, None)
        self._changed()

    def _join_localize(self, addr: DeviceAddr) -> None:
        r = self._robot(addr.node)
        if r.localize is not None:
            return
        proxy = self.fabric.device(addr)
        pub = r.node.publisher("amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped", DEFAULT_QOS)
        f_map, f_odom = self.config.map_frame, self._frame(r.name, "odom")
        post = self.outbox.post

        def build(data):
            return types.pose_with_covariance_stamped(data, f_map)

        def build_tf(data):
            base = r.base
            odom = base.proxy.latest if base is not None else None
            if odom is None:
                return None
            map_odom = geometry.compose(data.pose, geometry.invert(odom.pose))
            return types.tf_message(data.t, [(f_map, f_odom, tuple(map_odom))])

        def on_pose(data) -> None:
            post(pub, build, data)
            base = r.base
            if base is not None:
                post(base.tf, build_tf, data, slot=1)

        r.localize = _Nav(addr, proxy, on_pose, pub)
        proxy.add_listener(on_pose, inline=True)

    def _join_planner(self, addr: DeviceAddr) -> None:
        r = self._robot(addr.node)
        if r.planner is not None:
            return
        proxy = self.fabric.device(addr)
        f_map = self.config.map_frame
        pub = r.node.publisher("plan", "nav_msgs/msg/Path", DEFAULT_QOS)
        submit = self.fabric.dispatcher.submit
        warned = [False]

        def on_goal(msg, att) -> None:  # a Zenoh thread: hand the rpc to the dispatcher
            frame, goal = types.pose_stamped_to_goal(msg)
            if frame not in ("", f_map):
                if not warned[0]:
                    warned[0] = True
                    log.warning(
                        "/%s/goal_pose: frame %r is not the map frame %r; dropped (said once)", r.name, frame, f_map
                    )
                return
            submit(self._set_goal, proxy, goal)

        last: list[Any] = [None]

        def on_status(data) -> None:
            key = (data.goal, data.waypoint_count)
            if key != last[0]:
                last[0] = key
                submit(self._publish_plan, proxy, pub, data.t)

        sub = r.node.subscription("goal_pose", "geometry_msgs/msg/PoseStamped", on_goal, DEFAULT_QOS)
        r.planner = _Nav(addr, proxy, on_status, pub, sub)
        proxy.add_listener(on_status, inline=True)

    def _set_goal(self, planner, goal: tuple[float, float, float]) -> None:
        if self._closed:
            return
        fut = planner.set_goal(Position(*goal))
        if fut.done() and fut.exception() is not None:
            log.warning("%s: goal %s refused: %s", planner.addr, goal, fut.exception())

    def _publish_plan(self, planner, pub: Publisher, t: float) -> None:
        if self._closed or pub.closed:
            return
        try:
            wps = [w.as_tuple() for w in planner.waypoints(timeout=5.0)]
        except Exception as e:
            log.warning("%s: no waypoints (%s); plan not published", planner.addr, e)
            return
        f_map = self.config.map_frame
        self.outbox.post(pub, lambda d: types.path(d[0], f_map, d[1]), (t, wps))

    def _changed(self) -> None:
        if self.on_change is not None:
            try:
                self.on_change(self)
            except Exception:
                log.exception("the exporter's change listener failed")

    # ------------------------------------------------------------------ shutdown
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._dnode.close()
        self.fleet.close()
        self.outbox.close()
        with self._lock:
            robots, self._robots = list(self._robots.values()), {}
        for r in robots:
            r.node.close()
