"""``virtual_ranger`` driver: a real robot's laser that also sees the robots of a virtual world
(mixed reality, thesis 4.3).

In the thesis's mixed reality the virtual robots sense the real ones (their proxies in the
simulation), but "proxy robots have no possibility of sensing simulated robots via ranger sensors
... [this] can be worked around by implementing a driver handling virtual-to-real sensory mapping,
such as is done in [CMW09]". This is that driver::

    [[driver]]
    name = "virtual_ranger"
    provides = ["r0:laser:1"]
    requires = ["r0:laser:0", "r0:position2d:0"]
    simulation = "sim:simulation:0"   # the virtual world (default)
    radius = 0.22          # m: every virtual robot is seen as a disc of this radius
    exclude = ["r0"]       # virtual models not to merge (default: the provided laser's node)

It requires the real robot's range device (``laser``, ``ranger`` or ``sonar``) and its pose in the
map frame of the virtual world (a ``position2d``: amcl's ``position2d:2``, or odometry anchored to
the map). The virtual world's ``simulation`` device is a parameter, not a requirement: the real
robot's server runs before, during and after a mixed run, and the virtual world may come and go
(listing it in ``requires`` instead makes the driver wait for it). Every ``rate`` Hz (default 10)
the driver asks the simulation for the pose of each virtual robot (``rpc/get_pose``; the names come
from ``rpc/models``, asked again every ``refresh`` seconds, or from the ``models`` parameter),
never blocking. Every scan of the real device is republished on the provided laser with each
beam's range the minimum of the real reading and the distance along the beam to the nearest
virtual robot's disc, so that obstacle avoidance on the real robot treats virtual robots as
obstacles. A beam that starts inside a disc reads ``range_min``. Virtual poses older than ``stale``
seconds (default 1) are ignored, so without a virtual world the scan passes through unchanged, as
it does until the beam geometry and the robot's pose are known. The provided laser describes the
real device's geometry, so clients place its beams the same way (``rpc/describe`` answers
``unavailable`` until that geometry is known).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from rsal.interfaces.ranger import RangerGeometry
from rsal.keys import parse_device
from rsal.msgs import ErrorCode, MessageError, Position2dData, RangerData, RpcError

from ..config import ConfigError
from ..driver import Driver, register
from ..params import param, parse_params

__all__ = ["VirtualRanger", "merge_discs"]

RANGE_IFACES = ("laser", "ranger", "sonar")


def merge_discs(
    ranges: np.ndarray,
    origins: np.ndarray,
    bearings: np.ndarray,
    pose: tuple[float, float, float],
    centres: np.ndarray,
    radius: float | np.ndarray,
    range_min: float = 0.0,
) -> np.ndarray:
    """The ranges of a scan with discs added: ``min(ranges, distance along each beam to a disc)``.

    ``origins`` ``(n, 2)`` and ``bearings`` ``(n,)`` place the beams in the robot frame (as
    :meth:`RangerGeometry.beams` gives them), ``pose`` ``(x, y, yaw)`` places the robot in the world,
    ``centres`` ``(m, 2)`` are the discs' centres in the world and ``radius`` their radius (a
    number or ``(m,)``). A beam whose origin lies inside a disc reads ``range_min``. Discs out of
    reach of every beam are dropped first; the rest are done all at once (numpy broadcasting,
    ``n x m``). The dtype of ``ranges`` is kept.
    """
    r = np.asarray(ranges)
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    if c.shape[0] == 0 or r.shape[0] == 0:
        return r.copy()
    x, y, a = pose
    ca, sa = math.cos(a), math.sin(a)
    dx, dy = c[:, 0] - x, c[:, 1] - y
    local = np.column_stack([ca * dx + sa * dy, -sa * dx + ca * dy])  # the centres in the robot frame
    rad = np.broadcast_to(np.asarray(radius, dtype=float), (c.shape[0],))
    org = np.asarray(origins, dtype=float)
    # discs beyond the longest reading (plus the beams' offset from the centre) cannot shorten any beam
    reach = float(np.max(np.where(np.isnan(r), 0.0, r))) + float(np.max(np.hypot(org[:, 0], org[:, 1])))
    keep = np.hypot(local[:, 0], local[:, 1]) - rad <= reach
    if not keep.all():
        local, rad = local[keep], rad[keep]
        if local.shape[0] == 0:
            return r.copy()
    f = local[None, :, :] - org[:, None, :]  # (n, m, 2) beam origin -> centre
    b = np.asarray(bearings, dtype=float)
    tc = f[..., 0] * np.cos(b)[:, None] + f[..., 1] * np.sin(b)[:, None]  # along the beam to the closest point
    ff = np.einsum("nmk,nmk->nm", f, f)
    h = rad[None, :] ** 2 - (ff - tc * tc)  # > 0: the beam's line crosses the disc
    t = tc - np.sqrt(np.maximum(h, 0.0))  # the entry point
    inside = ff <= rad[None, :] ** 2
    hit = (h >= 0.0) & (t >= 0.0)
    dist = np.where(inside, range_min, np.where(hit, t, np.inf)).min(axis=1)
    out = np.fmin(r.astype(float), np.maximum(dist, range_min))  # an invalid (NaN) reading takes the disc's
    return out.astype(r.dtype, copy=False)


_SIM_EXPECT = 'a simulation device, e.g. "sim:simulation:0"'
_NAMES = 'a list of model names, e.g. ["r1", "r2"]'


@dataclass(frozen=True)
class VirtualRangerParams:
    """The ``virtual_ranger`` driver's parameters (module docstring)."""

    simulation: str = param("sim:simulation:0", expect=_SIM_EXPECT, doc="the virtual world, if not required")
    radius: float = param(0.22, min=0.01, max=10.0, doc="m, the virtual robots' discs")
    stale: float = param(1.0, min=0.05, max=60.0, doc="s: a pose older than this is dropped")
    refresh: float = param(5.0, min=0.1, max=3600.0, doc="s between rpc/models")
    exclude: tuple[str, ...] | None = param(None, expect=_NAMES, doc="default: the provided laser's node")
    models: tuple[str, ...] | None = param(None, expect=_NAMES, doc="default: asked with rpc/models")


@register("virtual_ranger")
class VirtualRanger(Driver):
    interfaces = ("laser", "ranger")
    default_rate = 10.0  # Hz: polls of the virtual robots' poses
    data_types = {"laser": "RangerData", "ranger": "RangerData"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        scans = [r.without_key() for r in cfg.requires if r.interface in RANGE_IFACES]
        poses = self.required("position2d")
        sims = self.required("simulation")
        if len(scans) != 1 or len(poses) != 1 or len(sims) > 1 or len(cfg.provides) != 1:
            raise ConfigError(
                f"{cfg.where}: virtual_ranger provides one laser and requires the real robot's laser and its "
                'position2d in the map frame, e.g. provides = ["r0:laser:1"], requires = ["r0:laser:0", '
                '"r0:position2d:0"]'
            )
        self.source = scans[0]
        self.pose_addr = poses[0].without_key()
        p = self.settings = parse_params(VirtualRangerParams, cfg)
        if sims:
            self.sim = sims[0].without_key()
        else:
            try:
                self.sim = parse_device(p.simulation)
            except ValueError:
                self.sim = None
            if self.sim is None or self.sim.interface != "simulation":
                raise ConfigError(f"{cfg.where}: simulation = {p.simulation!r} must be {_SIM_EXPECT}")
        self.out = cfg.provides[0]
        self.radius, self.stale, self.refresh = p.radius, p.stale, p.refresh
        self.exclude = set(p.exclude if p.exclude is not None else (self.out.node,))
        self.fixed = p.models is not None
        self.names: list[str] = [n for n in (p.models or ()) if n not in self.exclude]
        self.geometry_dict: dict | None = None
        self.beams: RangerGeometry | None = None
        self.pose: tuple[float, float, float] | None = None
        self.virtual: dict[str, tuple[tuple[float, float, float], float]] = {}  # name -> (pose, received at)
        self._outstanding = 0  # get_pose requests of the current poll round not answered yet
        self._models_pending = False
        self._next_models = 0.0
        self._sim_up: bool | None = None  # whether the virtual simulation answered ``models`` last time
        self.scans = 0  # scans republished
        self.merged = 0  # of them with at least one virtual robot in view

    # ------------------------------------------------------------------ requests
    def setup(self) -> None:
        self.request(self.source, "describe")
        self.log.info("%s: adding the robots of %s to %s as %s", self.cfg.where, self.sim, self.source, self.out)

    def ready(self) -> bool:
        return self.beams is not None  # the real ranger's beam geometry is in

    def update(self, now: float) -> None:
        t = time.monotonic()
        if not self.fixed and not self._models_pending and t >= self._next_models:
            self._models_pending = True
            self._next_models = t + self.refresh
            self.request(self.sim, "models", timeout=2.0)
        if self._outstanding == 0:  # one round at a time: a slow simulation is not flooded
            for n in self.names:
                self._outstanding += 1
                self.request(self.sim, "get_pose", {"name": n}, timeout=1.0)

    def on_reply(self, addr, op, result, error) -> None:
        if op == "describe":
            if error is not None:
                self.server._warn(f"virtual_ranger:{self.source}", f"{self.cfg.where}: {self.source} describe: {error}")
                self.request(self.source, "describe")
                return
            g = result.get("geometry", {}) or {}
            self.geometry_dict = g
            self.beams = RangerGeometry(g)
        elif op == "models":
            self._models_pending = False
            if error is not None:
                if self._sim_up is not False:  # once per disappearance: the virtual world may come and go
                    self.log.info("%s: no virtual world at %s (%s); scans unchanged", self.cfg.where, self.sim, error)
                self._sim_up = False
                self.names = []
                return
            robots = result.get("robots", [])
            if isinstance(robots, list):
                names = [n for n in robots if isinstance(n, str) and n not in self.exclude]
                if not self._sim_up or names != self.names:
                    self.warn(
                        "models",
                        f"{self.cfg.where}: virtual robots of {self.sim}: {', '.join(names) or 'none'}",
                        logging.INFO,
                    )
                self._sim_up = True
                self.names = names
                for gone in set(self.virtual) - set(self.names):
                    del self.virtual[gone]
        elif op == "get_pose":
            self._outstanding = max(0, self._outstanding - 1)
            if error is not None:
                if error.code == ErrorCode.NOT_FOUND and not self.fixed:
                    self._next_models = 0.0  # a model was removed: ask for the names again
                self.server._warn(f"virtual_ranger:{self.sim}:pose", f"{self.cfg.where}: {self.sim} get_pose: {error}")
                return
            name, pose = result.get("name"), result.get("pose")
            if (
                isinstance(name, str)
                and isinstance(pose, list)
                and len(pose) == 3
                and all(isinstance(v, int | float) for v in pose)
            ):
                self.virtual[name] = ((float(pose[0]), float(pose[1]), float(pose[2])), time.monotonic())

    # ------------------------------------------------------------------ inputs
    def on_input(self, addr, channel, msg) -> None:
        if channel != "data":
            return
        a = addr.without_key()
        if a == self.pose_addr:
            try:
                self.pose = Position2dData.from_dict(msg).pose
            except MessageError:
                return
        elif a == self.source:
            try:
                scan = RangerData.from_dict(msg)
            except MessageError as e:
                self.server._warn(f"virtual_ranger:{a}", f"{self.cfg.where}: malformed scan from {a}: {e}")
                return
            self.publish(self.out, self.merge(scan))
            self.scans += 1

    def merge(self, scan: RangerData) -> RangerData:
        """The scan with the fresh virtual robots added (unchanged while geometry or pose is unknown)."""
        if self.beams is None or self.pose is None:
            return scan
        now = time.monotonic()
        centres = [p[:2] for p, t in self.virtual.values() if now - t <= self.stale]
        if not centres:
            return scan
        origins, bearings = self.beams.beams(scan)
        ranges = merge_discs(scan.ranges, origins, bearings, self.pose, np.array(centres), self.radius, scan.range_min)
        if bool(np.any(ranges < scan.ranges)):
            self.merged += 1
        return RangerData(scan.t, ranges, scan.angle_min, scan.angle_step, scan.range_min, scan.range_max)

    # ------------------------------------------------------------------ describe
    def publish_rate(self, addr) -> float:
        return 10.0

    def geometry(self, addr):
        if self.geometry_dict is None:  # clients cache describe: never hand out a laser without beams
            raise RpcError(ErrorCode.UNAVAILABLE, f"{addr}: waiting for the geometry of {self.source}")
        g = dict(self.geometry_dict)
        g.update(
            {
                "source": str(self.source),
                "simulation": str(self.sim),
                "virtual": sorted(self.virtual),
                "radius": self.radius,
            }
        )
        return g
