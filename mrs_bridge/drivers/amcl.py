"""``amcl`` driver: adaptive Monte Carlo localization on the fabric (Player's amcl, thesis 3.3, A.3).

Binds :class:`mrs_bridge.nav.amcl.Amcl` (KLD-sampling particle filter, likelihood-field sensor
model, odometry motion model) to the device server::

    [[driver]]
    name = "amcl"
    provides = ["r0:localize:0", "r0:position2d:2"]
    requires = ["odometry::r0:position2d:0", "r0:laser:0", "laser::r0:map:0"]
    init_pose = [-21.0, 4.0, 0]        # x m, y m, yaw deg
    init_pose_var = [3.0, 3.0, 360]    # m², m², and Player's yaw term (see below)
    laser_max_beams = 50
    pf_max_samples = 5000

It requires an odometry ``position2d`` (role key ``odometry::`` or the only position2d), one range
device (a ``laser``, ``ranger`` or ``sonar``: the filter reads every beam's pose from the device's
``rpc/describe`` geometry, so sonar-only localization works the same way) and a ``map``. It provides
``localize`` (:class:`rsal.msgs.LocalizeData`: mean pose, 3x3 covariance, hypotheses) after every
filter update, and ``position2d`` (the localized pose in the map frame, at the odometry's rate:
the last estimate moved on by the odometry since; read-only like Player's).

Parameters are the filter's (Player names: ``pf_*``, ``odom_alpha1..4``, ``laser_*``,
``update_thresh``, ``resample_interval``, ``recover_alpha_*``, ``init_pose``, ``init_pose_var``,
``seed``) with Player's units in the file: ``init_pose`` yaw and ``update_thresh``'s angle in
degrees; ``init_pose_var``'s third value is read like an angle and used as the yaw variance in
rad², as Player does (360 gives 2π rad²: any heading). Also: ``laser_pose`` ``[x, y, yaw deg]``
overrides the described sensor mount, ``laser_range_max`` caps the ranges used, ``global = true``
starts with global localization over all free space. ``odom_init``, ``enable_gui``,
``laser_range_bad``, ``laser_range_var`` and ``odom_drift`` are Player options with no effect here
(a warning says so).

Operations: ``set_pose`` (``pose`` [x, y, yaw rad], ``cov`` 9 values) re-initialises around a pose
(the thesis's fix when a robot cannot find itself), ``set_global`` spreads the particles over the
map, ``get_particles`` returns ``particles`` (float32 x, y, yaw triplets) and ``weights``, and
``set_obstacles`` (``obstacles`` [[x, y, radius], ...] m in the map frame, ``ttl`` s) declares known
moving obstacles -- a swarm's neighbours where their broadcasts put them -- whose echoes the filter
leaves out (:mod:`mrs_bridge.nav.knownobstacles`) until ``ttl`` s of the odometry's clock have passed
or the next ``set_obstacles`` replaces them. The same declaration also goes as a command, fire and
forget (``cmd``, :class:`rsal.interfaces.localize.ObstaclesCmd`: ``obstacles``, ``ttl``): a swarm
declares at its broadcast rate and needs no reply.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rsal.cliutil import FirstFew
from rsal.geometry import compose, relative
from rsal.interfaces.localize import ObstaclesCmd
from rsal.interfaces.ranger import RangerGeometry
from rsal.msgs import (
    ErrorCode,
    Hypothesis,
    LocalizeData,
    MapData,
    MessageError,
    Position2dData,
    RangerData,
    RpcError,
    get_vec,
)

from ..config import ConfigError
from ..driver import Driver, register
from ..nav.knownobstacles import parse_obstacles
from ..params import param, parse_params

__all__ = ["AmclDriver"]

#: one "map ... init at" line each for a few robots, then at debug level
_STARTED = FirstFew("localizers started")

RANGE_IFACES = ("laser", "ranger", "sonar")
LOCALIZE_PERIOD = 0.5  # s: localize data at least this often, even without filter updates
OBSTACLES_TTL = 1.5  # s: known obstacles are dropped this long after set_obstacles (default ttl)


@dataclass(frozen=True)
class AmclDriverParams:
    """The ``amcl`` driver's own parameters; every other key is the filter's (``AmclParams``)."""

    IGNORED: ClassVar[tuple[str, ...]] = (
        "odom_init", "enable_gui", "laser_range_bad", "laser_range_var", "odom_drift", "alwayson",
    )  # fmt: skip

    laser_pose: tuple[float, float, float] | None = param(None, expect="[x m, y m, yaw deg]")
    laser_range_max: float | None = param(None, gt=0.0, expect="a positive number of metres")
    global_: bool = param(False, doc="start with global localization")


@register("amcl")
class AmclDriver(Driver):
    interfaces = ("localize", "position2d")
    default_rate = 0.0  # event driven: odometry and scans
    data_types = {"localize": "LocalizeData", "position2d": "Position2dData"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        from ..nav.amcl import AmclParams

        pos = self.required("position2d", "odometry") or self.required("position2d")
        rng = [r for r in cfg.requires if r.interface in RANGE_IFACES]
        maps = self.required("map")
        if len(pos) != 1 or len(rng) != 1 or len(maps) != 1:
            raise ConfigError(
                f"{cfg.where}: amcl requires one odometry position2d, one laser (or ranger/sonar) and one map, "
                'e.g. requires = ["odometry::r0:position2d:0", "r0:laser:0", "r0:map:0"]'
            )
        self.odom_addr, self.range_addr, self.map_addr = pos[0].without_key(), rng[0].without_key(), maps[0]
        p, raw = parse_params(AmclDriverParams, cfg, rest=True, log=self.log)  # the rest: the filter's
        self.settings = p
        lp = p.laser_pose
        self.laser_pose = None if lp is None else (lp[0], lp[1], math.radians(lp[2]))
        self.range_cap = p.laser_range_max
        self.start_global = p.global_
        # Player's units in the file -> SI
        if "init_pose" in raw and _is_vec(raw["init_pose"], 3):
            x, y, a = raw["init_pose"]
            raw["init_pose"] = (x, y, math.radians(a))
        if "init_pose_var" in raw and _is_vec(raw["init_pose_var"], 3):
            vx, vy, va = raw["init_pose_var"]
            raw["init_pose_var"] = (vx, vy, math.radians(va))
        if "update_thresh" in raw and _is_vec(raw["update_thresh"], 2):
            d, a = raw["update_thresh"]
            raw["update_thresh"] = (d, math.radians(a))
        try:
            self.params = AmclParams.from_dict(raw)
        except ValueError as e:
            raise ConfigError(f"{cfg.where}: {e}") from None
        self.filter = None
        self.beams: RangerGeometry | None = None
        self.map_info: tuple[int, int, float] | None = None
        self._odom: tuple[float, float, float] | None = None
        self._odom_vel = (0.0, 0.0, 0.0)
        self._odom_t = 0.0  # time of the last odometry message (the device's clock)
        self._est = None  # (pose at the last update, odometry then, covariance)
        self._hyps: list[Hypothesis] | None = []  # None: not clustered since the last update
        self.updates = 0
        self.skipped = 0
        self.update_ms = 0.0
        self._last_localize = -math.inf
        self._obstacles_until = -math.inf  # odometry time the known obstacles expire at

    # ------------------------------------------------------------------ set-up
    def setup(self) -> None:
        from ..kernels import prepare

        prepare("nav", label="nav")  # the filter's kernels, before its devices are announced
        self.request(self.map_addr, "get", timeout=30.0)
        self.request(self.range_addr, "describe")

    def ready(self) -> bool:
        return self.filter is not None and self.beams is not None

    def on_reply(self, addr, op, result, error) -> None:
        if error is not None:
            self.warn(f"retry:{op}", f"{self.cfg.where}: {addr} rpc/{op} failed ({error}); retrying")
            self.request(addr, op, timeout=30.0 if op == "get" else 5.0)
            return
        if op == "get" and addr.without_key() == self.map_addr.without_key():
            from ..nav.amcl import Amcl
            from ..nav.grid import NavGrid

            m = MapData.from_dict(result)
            grid = NavGrid.shared(m)  # one per map in the server, its derived grids too
            self.map_info = (m.width, m.height, m.resolution)
            try:
                self.filter = Amcl(grid, self.params)
            except ValueError as e:
                raise ConfigError(f"{self.cfg.where}: {e}") from None
            if self.start_global:
                self.filter.init_global()
            _STARTED.log(
                self.log,
                logging.INFO,
                "%s: map %dx%d at %g m; %s",
                self.cfg.where,
                m.width,
                m.height,
                m.resolution,
                "global localization" if self.start_global else f"init at {self.params.init_pose}",
            )
        elif op == "describe":
            self.beams = RangerGeometry(result.get("geometry", {}) or {}, self.laser_pose)

    # ------------------------------------------------------------------ inputs
    def on_input(self, addr, channel, msg) -> None:
        if channel != "data":
            return
        a = addr.without_key()
        if a == self.odom_addr:
            try:
                d = Position2dData.from_dict(msg)
            except MessageError:
                return
            self._odom = d.pose
            self._odom_vel = d.vel
            self._odom_t = d.t
            if self.filter is not None:
                self.filter.odometry(d.pose)
                self._publish_pose(d.t)
                if time.monotonic() - self._last_localize >= LOCALIZE_PERIOD:
                    self._publish_localize(d.t)
        elif a == self.range_addr and self.filter is not None and self.beams is not None and self._odom is not None:
            try:
                scan = RangerData.from_dict(msg)
            except MessageError:
                return
            origins, bearings = self.beams.beams(scan)
            rmax = scan.range_max if scan.range_max > 0 else float(np.nanmax(scan.ranges))
            if self.range_cap is not None:
                rmax = min(rmax, self.range_cap)
            t0 = time.perf_counter()
            if self.filter.obstacles.shape[0] and scan.t > self._obstacles_until:
                self.filter.set_obstacles(())  # stale: the neighbours have moved on
            width = self.beams.beam_width(scan)
            if self.filter.sensor(scan.ranges, bearings, origins, scan.range_min, rmax, beam_width=width):
                self.update_ms = (time.perf_counter() - t0) * 1e3
                self.updates += 1
                self._after_update(scan.t)

    def _after_update(self, t: float) -> None:
        mean, cov = self.filter.estimate()
        self._est = (tuple(float(v) for v in mean), self._odom, cov)
        self._hyps = None  # clustered when a localize message goes out (hypotheses()), not per update
        self._publish_localize(t)
        self._publish_pose(t)

    def _publish_localize(self, t: float) -> None:
        """The estimate (moved on by odometry since the last update) with its covariance; also sent
        every ``LOCALIZE_PERIOD`` s without updates (a robot standing still), so late subscribers
        learn where it is."""
        p = self.localized_pose()
        if p is None:
            return
        self._last_localize = time.monotonic()
        to = [a for a in self.provided("localize") if self.listened(a)]
        if not to:  # nobody subscribes: no message, and no clustering for one
            return
        cov = tuple(float(v) for v in self._est[2].ravel())
        msg = LocalizeData(t, p, cov, self.hypotheses(), int(self.filter.particles.shape[0]), 0)
        for a in to:
            self.publish(a, msg)

    def hypotheses(self) -> list[Hypothesis]:
        """The filter's hypotheses (at most 8, heaviest first) as of its last update, clustered on
        the first call after it: the clustering costs about as much as a sonar update, and only a
        ``localize`` message that goes out needs it (the map-frame ``position2d`` does not)."""
        if self._hyps is None:
            self._hyps = [
                Hypothesis(min(1.0, float(w)), tuple(float(v) for v in m), tuple(float(v) for v in c.ravel()))
                for w, m, c in self.filter.hypotheses()[:8]
            ]
        return self._hyps

    def localized_pose(self) -> tuple[float, float, float] | None:
        """The last estimate moved on by the odometry since (map frame)."""
        if self._est is None or self._odom is None:
            return None
        pose, odom_then, _ = self._est
        return compose(pose, relative(odom_then, self._odom))

    def _publish_pose(self, t: float) -> None:
        p = self.localized_pose()
        if p is None:
            return
        for a in self.provided("position2d"):
            self.publish(a, Position2dData(t, p, self._odom_vel, False))

    # ------------------------------------------------------------------ operations
    def ops(self, addr):
        return ["set_pose", "set_global", "get_particles", "set_obstacles"]

    def on_rpc(self, addr, op, args):
        if op in ("set_pose", "set_global", "get_particles", "set_obstacles") and self.filter is None:
            raise RpcError(ErrorCode.UNAVAILABLE, f"{addr}: no map yet (waiting for {self.map_addr})")
        if op == "set_pose":
            pose = get_vec(args, "pose", 3)
            cov = np.asarray(get_vec(args, "cov", 9, (0.25, 0, 0, 0, 0.25, 0, 0, 0, 0.07)), dtype=float).reshape(3, 3)
            try:
                self.filter.init_pose(pose, cov)
            except ValueError as e:
                raise RpcError(ErrorCode.OUT_OF_RANGE, str(e)) from None
            self._est = (tuple(pose), self._odom, cov) if self._odom is not None else None
            self._publish_pose(self._odom_t)  # stamped on the odometry's clock, like every other sample
            return {"pose": list(pose), "particles": int(self.filter.particles.shape[0])}
        if op == "set_global":
            self.filter.init_global()
            self._est = None
            return {"particles": int(self.filter.particles.shape[0])}
        if op == "set_obstacles":
            try:
                discs = parse_obstacles(args.get("obstacles"), f"{addr} set_obstacles obstacles")
            except ValueError as e:
                raise RpcError(ErrorCode.BAD_REQUEST, str(e)) from None
            ttl = args.get("ttl", OBSTACLES_TTL)
            if not isinstance(ttl, int | float) or isinstance(ttl, bool) or not ttl > 0:
                raise RpcError(
                    ErrorCode.BAD_REQUEST, f"{addr} set_obstacles: ttl {ttl!r} must be a positive number of s"
                )
            self._set_obstacles(discs, float(ttl))
            return {"obstacles": int(discs.shape[0])}
        if op == "get_particles":
            q = self.filter.particles
            return {
                "particles": np.ascontiguousarray(q, dtype="<f4").tobytes(),
                "weights": np.ascontiguousarray(self.filter.weights, dtype="<f4").tobytes(),
                "count": int(q.shape[0]),
            }
        return super().on_rpc(addr, op, args)

    def on_cmd(self, addr, msg) -> None:
        """``localize`` ``cmd``: an :class:`ObstaclesCmd`, ``rpc/set_obstacles`` without a reply (the
        server decoded and checked it in its intake; a malformed one never gets here)."""
        if addr.interface != "localize" or not isinstance(msg, ObstaclesCmd):
            super().on_cmd(addr, msg)
        if self.filter is None:
            return  # no map yet: nothing to leave out, and the next declaration comes soon
        self._set_obstacles(np.asarray(msg.obstacles, dtype=float).reshape(-1, 3), msg.ttl)

    def _set_obstacles(self, discs: np.ndarray, ttl: float) -> None:
        self.filter.set_obstacles(discs)
        self._obstacles_until = self._odom_t + ttl

    def geometry(self, addr):
        g = {
            "odometry": str(self.odom_addr),
            "ranger": str(self.range_addr),
            "map": str(self.map_addr.without_key()),
            "pf_min_samples": self.params.pf_min_samples,
            "pf_max_samples": self.params.pf_max_samples,
            "frame": "map",
        }
        if self.map_info:
            g["map_size"] = list(self.map_info)
        if self.filter is not None:
            g["obstacles"] = int(self.filter.obstacles.shape[0])  # known obstacles declared now
        return g

    def publish_rate(self, addr) -> float:
        return 10.0


def _is_vec(v, n: int) -> bool:
    return isinstance(v, list | tuple) and len(v) == n and all(isinstance(x, int | float) for x in v)
