"""The live view's drawing hooks: one function per interface, looked up by the interface's name.

:func:`hook` answers, for any interface of the registry (:mod:`rsal.interfaces`), the function
that turns one decoded data message into Rerun entities: the hooks below for the interfaces the
view draws, else :func:`draw_summary`, which logs the interface's registry ``summary`` text. A new
interface is therefore shown (as text) with no change here; drawing it = one function decorated
with ``@draws("<name>")`` (the name is checked against the registry at import). Hooks run on the
logger thread with the :class:`~rsal.watch.app.Watcher` as ``w`` (its robots, the devices'
``describe`` geometry, ``w.log``). Entity paths are documented in ``docs/watch.md``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import interfaces
from ..geometry import compose_array
from ..interfaces.bumper import BumperData, BumperGeometry
from ..interfaces.fiducial import FiducialData, FiducialGeometry
from ..keys import DeviceAddr
from ..msgs import BlobfinderData, PlannerData, RangerData
from .convert import (
    BUMPER_GREEN,
    FIDUCIAL_MAGENTA,
    LASER_RED,
    RED,
    SONAR_BLUE,
    YELLOW,
    beam_layout,
    entity,
    scan_to_world,
)

if TYPE_CHECKING:
    from .app import Watcher

__all__ = ["HOOKS", "draws", "hook", "draw_summary"]

Hook = Callable[["Watcher", DeviceAddr, Any], None]

#: interface name -> drawing hook (interfaces without one are logged as their summary text)
HOOKS: dict[str, Hook] = {}


def draws(*names: str) -> Callable[[Hook], Hook]:
    """Register the decorated function as the drawing hook of the interfaces ``names``."""

    def deco(fn: Hook) -> Hook:
        for name in names:
            if interfaces.get(name) is None:
                raise RuntimeError(f"{fn.__name__}: {name!r} is not an interface of rsal.interfaces")
            HOOKS[name] = fn
        return fn

    return deco


def hook(interface: str) -> Hook:
    """The drawing hook of ``interface``: its own, else :func:`draw_summary`."""
    return HOOKS.get(interface, draw_summary)


def _suffix(addr: DeviceAddr, name: str) -> str:
    return name if addr.index == 0 else f"{name}{addr.index}"


# ---------------------------------------------------------------------------- robot state
@draws("position2d")
def draw_position2d(w: Watcher, addr: DeviceAddr, msg) -> None:
    """Odometry, ground truth (``gps``) or a localized pose (``map``), by the device's frame."""
    frame = w._geometry.get(addr, {}).get("frame")
    if frame is None:
        frame = {0: "odom", 2: "map"}.get(addr.index)
    if addr.index == 1 and frame == "odom":
        return  # a local planner republishing its base's odometry
    rb = w.robot(addr.node)
    if frame == "odom":
        rb.odom = msg.pose
        if rb.anchor is not None and rb.anchor[1] is None:  # truth came first: anchor it here
            rb.anchor = (rb.anchor[0], np.asarray(msg.pose))
        rb.speed = msg.vel[0]
    elif frame == "gps":
        rb.gps = msg.pose
        rb.speed = msg.vel[0]
    elif frame == "map":
        rb.loc = msg.pose
    else:
        return
    rb.dirty = True


@draws("localize")
def draw_localize(w: Watcher, addr: DeviceAddr, msg) -> None:
    rb = w.robot(addr.node)
    rb.loc, rb.cov = msg.pose, msg.cov
    rb.dirty = rb.cov_dirty = True


@draws("gripper")
def draw_gripper(w: Watcher, addr: DeviceAddr, g) -> None:
    rb = w.robot(addr.node)
    if g.carrying != rb.carrying:
        rb.carrying = g.carrying
        rb.dirty = True
        if g.carrying is None:
            w.log(entity("world", "robots", addr.node, "carried"), w.rr.Clear(recursive=False))


@draws("power")
def draw_power(w: Watcher, addr: DeviceAddr, p) -> None:
    w.robot(addr.node).battery = p.percent
    w.log(entity("plots", addr.node, "battery"), w.rr.Scalars(p.percent))


@draws("simulation")
def draw_simulation(w: Watcher, addr: DeviceAddr, msg) -> None:
    w._sim_time = msg.t


# ---------------------------------------------------------------------------- sensors
@draws("laser", "sonar", "ranger")
def draw_scan(w: Watcher, addr: DeviceAddr, scan: RangerData) -> None:
    now = time.monotonic()
    geo = w._geometry.get(addr)
    rb = w._robots.get(addr.node)
    pose = rb.best() if rb is not None else None
    if geo is None or pose is None:
        return
    n = len(scan.ranges)
    if n == 0:
        return
    key = (n, scan.angle_min, scan.angle_step)
    lay = w._layout.get(addr)
    if lay is None or lay[0] != key:
        lay = (key, *beam_layout(geo, n, scan.angle_min, scan.angle_step))
        w._layout[addr] = lay
    stride = max(1, math.ceil(n / w.opts.max_beams))
    pts = scan_to_world(scan.ranges, lay[1], lay[2], pose, scan.range_min, scan.range_max, stride)
    w._last_scan[addr] = now
    name = addr.interface if addr.index == 0 else f"{addr.interface}{addr.index}"
    color = SONAR_BLUE if addr.interface == "sonar" else LASER_RED
    w.log(entity("world", "robots", addr.node, name), w.rr.Points2D(pts, radii=0.03, colors=color))


@draws("planner")
def draw_planner(w: Watcher, addr: DeviceAddr, p: PlannerData) -> None:
    rr = w.rr
    node = addr.node
    color = w.robot(node).color
    base = entity("world", "robots", node)
    state = (p.status, p.goal, p.waypoint_count)
    old = w._planner.get(node)
    if old is None or old[0] != state:
        if p.status == "driving" and p.waypoint_count >= 2:
            w._rpc("waypoints", addr, "waypoints")
        elif p.status != "driving":
            w.log(base + "/path", rr.Clear(recursive=True))
            w.log(base + "/waypoint", rr.Clear(recursive=False))
        if p.goal:
            w.log(base + "/goal", rr.Points2D([p.goal[:2]], radii=0.1, colors=color, labels=[f"goal {node}"]))
            w.log(
                base + "/goal",
                rr.Arrows2D(origins=[p.goal[:2]], vectors=[[0.4 * math.cos(p.goal[2]), 0.4 * math.sin(p.goal[2])]]),
            )
        if old is None or old[0][0] != p.status:
            msg = f"{node}: {p.status}" + (f" ({p.message})" if p.message else "")
            level = "WARN" if p.status in ("aborted", "invalid") else "INFO"
            w.log(entity("log", "planner", node), rr.TextLog(msg, level=level))
    if p.status == "driving" and p.waypoint and (old is None or old[1] != p.waypoint):
        w.log(base + "/waypoint", rr.Points2D([p.waypoint[:2]], radii=0.07, colors=YELLOW))
    w._planner[node] = (state, p.waypoint)


@draws("blobfinder")
def draw_blobs(w: Watcher, addr: DeviceAddr, b: BlobfinderData) -> None:
    rr = w.rr
    rb = w._robots.get(addr.node)
    pose = rb.best() if rb is not None else None
    path = entity("world", "robots", addr.node, "blobs" if addr.index == 0 else f"blobs{addr.index}")
    if pose is None:
        return
    if not b.blobs:
        if w._last_scan.get(addr) != 0.0:
            w.log(path, rr.Clear(recursive=False))
            w._last_scan[addr] = 0.0
        return
    now = time.monotonic()
    if now - w._last_scan.get(addr, -math.inf) < 1.0 / w.opts.scan_rate:
        return
    w._last_scan[addr] = now
    cam = np.asarray(w._geometry.get(addr, {}).get("pose") or (0.0, 0.0, 0.0), dtype=float)
    rng = np.array([x.range for x in b.blobs])
    brg = np.array([x.bearing for x in b.blobs])
    local = np.column_stack([rng * np.cos(brg), rng * np.sin(brg), np.zeros_like(rng)])
    pts = compose_array(compose_array(pose, cam), local)[:, :2]
    colors = np.array([(x.color << 8) | 255 for x in b.blobs], dtype=np.uint32)
    w.log(path, rr.Points2D(pts, radii=0.06, colors=colors))
    w._last_scan[addr] = now


def draw_summary(w: Watcher, addr: DeviceAddr, msg: Any) -> None:
    """An interface the view does not draw (dio, actarray, map data, ...): its registry summary as
    a text log under ``log/devices/<node>``, each time the text changes."""
    rec = interfaces.get(addr.interface)
    if rec is None:
        return
    text = rec.summary(msg)
    if not text or w._summaries.get(addr) == text:
        return
    w._summaries[addr] = text
    w.log(entity("log", "devices", addr.node), w.rr.TextLog(f"{addr}: {text}", level="INFO"))


def _robot_frame_entity(w: Watcher, addr: DeviceAddr, name: str) -> str | None:
    """The entity of ``name`` in the frame of ``addr``'s robot: under its ground-truth footprint
    when the view has ground truth, else under its localized one (both move by transform, so
    what is logged there in robot coordinates moves with the robot). None before either exists."""
    rb = w._robots.get(addr.node)
    if rb is None:
        return None
    kind = "truth" if rb.truth() is not None else "pose" if rb.loc is not None else None
    return None if kind is None else entity("world", "robots", addr.node, kind, _suffix(addr, name))


@draws("bumper")
def draw_bumper(w: Watcher, addr: DeviceAddr, b: BumperData) -> None:
    """The bumper segments in the robot's frame from the device's geometry, red while pressed;
    logged again only when the pressed set (or the frame it hangs from) changes."""
    geo = w._geometry.get(addr)
    path = _robot_frame_entity(w, addr, "bumper")
    if geo is None or path is None:
        return
    g = w._typed_geometry(addr, BumperGeometry)
    if len(g.segments) != len(b.bumpers):
        raise ValueError(f"{len(b.bumpers)} bumper values for {len(g.segments)} segments in its geometry")
    state = (path, b.bumpers)
    if w._drawn.get(addr) == state:
        return
    w._drawn[addr] = state
    ends = g.segment_ends()
    colors = np.where(np.asarray(b.bumpers, dtype=bool), RED, BUMPER_GREEN).astype(np.uint32)
    w.log(path, w.rr.LineStrips2D(list(ends), radii=0.015, colors=colors))


@draws("fiducial")
def draw_fiducial(w: Watcher, addr: DeviceAddr, f: FiducialData) -> None:
    """A line from the finder to each fiducial it sees, labelled with the id (``?`` when it
    cannot read it), in the robot's frame; at most ``--scan-rate`` times per second."""
    geo = w._geometry.get(addr)
    path = _robot_frame_entity(w, addr, "fiducial")
    if geo is None or path is None:
        return
    if not f.fiducials:
        if w._drawn.get(addr) is not None:
            w._drawn[addr] = None
            w.log(path, w.rr.Clear(recursive=False))
        return
    now = time.monotonic()
    if now - w._last_scan.get(addr, -math.inf) < 1.0 / w.opts.scan_rate:
        return
    w._last_scan[addr] = now
    g = w._typed_geometry(addr, FiducialGeometry)
    origin = np.asarray(g.pose[:2], dtype=float)
    lines = [np.array([origin, g.to_robot(item)[:2]]) for item in f.fiducials]
    labels = [f"#{item.id}" if item.id >= 0 else "?" for item in f.fiducials]
    w._drawn[addr] = path
    w.log(path, w.rr.LineStrips2D(lines, radii=0.01, colors=FIDUCIAL_MAGENTA, labels=labels))
