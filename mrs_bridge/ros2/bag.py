"""``rsal rosbag2 RUN.mcap -o DIR``: a fabric recording as a rosbag2 bag that ``ros2 bag play``,
Foxglove and Rerun open (docs/ros2.md, "Bags").

Reads an ``rsal record`` recording (:class:`rsal.record.Recording`, docs/recording.md)
and writes a rosbag2 directory (``metadata.yaml`` + one MCAP file with CDR messages and their
``ros2msg`` schemas, written by rosbags' rosbag2 writer) with the messages the exporter would have
published live (:mod:`mrs_bridge.ros2.export`): ``/<robot>/scan`` from each laser,
``/<robot>/odom`` and ``/tf`` (odom -> base_link, base_link -> laser from the laser's recorded
``describe``) from ``position2d:0``, ``/<robot>/amcl_pose`` from ``localize:0``. A message's bag
time is its source time (the recorded ``publish_time``: the sample's own ``t``), its header stamp
the same. Other channels (commands, services, events, other interfaces) are counted and left out.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path
from typing import Any

from rsal.interfaces.localize import LocalizeData
from rsal.interfaces.position2d import Position2dData
from rsal.interfaces.ranger import RangerData
from rsal.keys import parse_key
from rsal.msgs import decode_map

__all__ = ["convert", "register"]


def _describe(data: bytes) -> dict:
    try:
        m = decode_map(data)
    except Exception:
        return {}
    return m if m.get("ok", True) else {}


def convert(paths: list[str], out: str | Path, *, frame_prefix: str = "{robot}/", map_frame: str = "map") -> Counter:
    """Write the bag; returns the number of messages per ROS topic (and ``skipped``)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from rsal.record import Recording

    from . import types  # here, not at the top: every rsal command registers rosbag2

    rec = Recording(*paths)
    out = Path(out)
    if out.exists():
        raise FileExistsError(f"{out} exists; rosbag2 writes a new directory: choose another -o or remove it")
    counts: Counter = Counter()
    mounts: dict[tuple[str, int], tuple[float, float, float]] = {}
    rates: dict[tuple[str, int], float] = {}
    conns: dict[tuple[str, str], Any] = {}

    def frame(robot: str, name: str) -> str:
        return frame_prefix.format(robot=robot) + name

    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:

        def write(topic: str, ros_type: str, stamp_ns: int, msg) -> None:
            c = conns.get((topic, ros_type))
            if c is None:
                c = conns[(topic, ros_type)] = w.add_connection(topic, ros_type, typestore=types.TYPESTORE)
            w.write(c, stamp_ns, types.encode(msg, ros_type))
            counts[topic] += 1

        for s in rec.samples():
            parsed = parse_key(s.key)
            if parsed is None:
                counts["skipped"] += 1
                continue
            addr, channel, op = parsed
            robot, iface, idx = addr.node, addr.interface, addr.index
            if s.kind == "rpc" and op == "describe":
                d = _describe(s.data)
                pose = (d.get("geometry") or {}).get("pose")
                if iface == "laser" and isinstance(pose, list) and len(pose) >= 3:
                    mounts[(robot, idx)] = (float(pose[0]), float(pose[1]), float(pose[2]))
                if iface == "laser" and d.get("rate"):
                    rates[(robot, idx)] = float(d["rate"])
                continue
            if s.kind != "data" or channel != "data":
                counts["skipped"] += 1
                continue
            t_ns = s.publish_time
            if iface == "laser":
                scan = RangerData.from_bytes(s.data)
                suffix = "" if idx == 0 else f"_{idx}"
                rate = rates.get((robot, idx), 0.0)
                msg = types.laser_scan(scan, frame(robot, f"laser{suffix}"), 1.0 / rate if rate else 0.0)
                write(f"/{robot}/scan{suffix}", "sensor_msgs/msg/LaserScan", t_ns, msg)
            elif iface == "position2d" and idx == 0:
                d = Position2dData.from_bytes(s.data)
                f_odom, f_base = frame(robot, "odom"), frame(robot, "base_link")
                write(f"/{robot}/odom", "nav_msgs/msg/Odometry", t_ns, types.odometry(d, f_odom, f_base))
                tfs = [(f_odom, f_base, d.pose)]
                for (r, i), m in sorted(mounts.items()):
                    if r == robot:
                        tfs.append((f_base, frame(robot, "laser" if i == 0 else f"laser_{i}"), m))
                write("/tf", "tf2_msgs/msg/TFMessage", t_ns, types.tf_message(d.t, tfs))
            elif iface == "localize" and idx == 0:
                d = LocalizeData.from_bytes(s.data)
                msg = types.pose_with_covariance_stamped(d, map_frame)
                write(f"/{robot}/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped", t_ns, msg)
            else:
                counts["skipped"] += 1
    if rec.skipped:
        print(f"rsal rosbag2: {rec.skipped}", file=sys.stderr)
    return counts


def register(sub) -> None:
    p = sub.add_parser("rosbag2", help="convert a recording (rsal record) into a rosbag2 bag (MCAP, CDR)")
    p.add_argument("recording", nargs="+", metavar="RUN.mcap", help="the recording (the parts of a split one in order)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="the bag directory to create")
    p.add_argument("--frame-prefix", default="{robot}/", metavar="TEMPLATE", help="as rsal ros2's (default '{robot}/')")
    p.add_argument("--map-frame", default="map", help="as rsal ros2's (default map)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    counts = convert(args.recording, args.output, frame_prefix=args.frame_prefix, map_frame=args.map_frame)
    skipped = counts.pop("skipped", 0)
    topics = ", ".join(f"{t} {n}" for t, n in sorted(counts.items())) or "none"
    print(f"rsal rosbag2: {args.output}: {sum(counts.values())} messages ({topics}); {skipped} samples not mapped")
    return 0
