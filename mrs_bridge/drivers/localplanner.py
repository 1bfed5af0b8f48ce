"""``vfh``, ``nd`` and ``snd`` drivers: local planners on the fabric (Player's drivers, thesis A.3).

Each binds one algorithm of :mod:`mrs_bridge.nav` (:class:`~mrs_bridge.nav.vfh.VFH`,
:class:`~mrs_bridge.nav.nd.ND`, :class:`~mrs_bridge.nav.snd.SND`) to the device server::

    [[driver]]
    name = "vfh"
    provides = ["r0:position2d:1"]
    requires = ["r0:position2d:0", "r0:laser:0"]
    safety_dist_0ms = 0.1
    safety_dist_1ms = 0.4
    max_speed = 0.4

It requires the base's ``position2d`` (odometry) and one or more range devices (``laser``,
``ranger``, ``sonar``: their points are merged, each beam placed by the device's described
geometry). It provides a ``position2d`` in the base's odometry frame that accepts a goal
(:class:`rsal.msgs.GoalCmd` on ``cmd``, or ``rpc/goto``), drives the base there around what the
sensors see, and reports the base's pose as its data. A :class:`~rsal.msgs.VelocityCmd` on the same
``cmd`` key cancels the goal and is passed to the base (manual driving through the planner).
Events: ``{"event": "done"}`` when the goal pose is reached, ``{"event": "blocked"}`` when the
planner starts an escape. Parameters are the algorithm's, by Player's names and units (angles in
degrees); the robot's size comes from the base's describe geometry.
"""

from __future__ import annotations

import math

from rsal.msgs import ErrorCode, GoalCmd, MessageError, Position2dData, RangerData, RpcError, VelocityCmd, get_vec

from ..config import ConfigError
from ..driver import Driver, OutOfRange, register
from .navcommon import BeamGeometry

__all__ = ["LocalPlannerDriver"]

RANGE_IFACES = ("laser", "ranger", "sonar")
STALE_SCAN = 1.0  # s (wall): a range device silent this long no longer counts (its points are dropped)


class LocalPlannerDriver(Driver):
    interfaces = ("position2d",)
    default_rate = 0.0  # event driven: one cycle per odometry message of the base
    data_types = {"position2d": "Position2dData"}
    cmd_types = {"position2d": "GoalCmd | VelocityCmd"}
    algorithm: type | None = None

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        bases = self.required("position2d")
        self.ranges = [r.without_key() for r in cfg.requires if r.interface in RANGE_IFACES]
        if len(bases) != 1 or not self.ranges or len(cfg.provides) != 1:
            raise ConfigError(
                f"{cfg.where}: {self.driver_name} provides one position2d and requires the base position2d and a "
                'laser (or ranger/sonar), e.g. requires = ["r0:position2d:0", "r0:laser:0"]'
            )
        self.base = bases[0].without_key()
        self.out = cfg.provides[0]
        try:  # validate now, so a bad parameter is a config error at start
            self.planner = self.algorithm(dict(cfg.params))
        except ValueError as e:
            raise ConfigError(f"{cfg.where}: {e}") from None
        self.geometry_of: dict = {}
        self.scans: dict = {}  # addr -> (received_at, points)
        self.pose = None
        self.vel = (0.0, 0.0, 0.0)
        self.stall = False
        self._last_t: float | None = None
        self._last_status = "idle"
        self._sent_stop = True
        self.base_size = None
        self._base_described = False

    def setup(self) -> None:
        self.request(self.base, "describe")
        for r in self.ranges:
            self.request(r, "describe")

    def ready(self) -> bool:
        # the base's size and every ranger's beam geometry are in: the first cycle can avoid obstacles
        return self._base_described and len(self.geometry_of) == len(self.ranges)

    def on_reply(self, addr, op, result, error) -> None:
        a = addr.without_key()
        if error is not None:
            self.warn(f"retry:{op}", f"{self.cfg.where}: {a} rpc/{op} failed ({error}); retrying")
            self.request(a, op)
            return
        g = result.get("geometry", {}) or {}
        if a == self.base:
            self._base_described = True
            size = g.get("size")
            if (
                isinstance(size, list)
                and len(size) >= 2
                and all(isinstance(v, int | float) and v > 0 for v in size[:2])
            ):
                self.base_size = (float(size[0]), float(size[1]))
                goal = self.planner.goal
                self.planner = self.algorithm(dict(self.cfg.params), geometry=self.base_size)
                if goal is not None:
                    self.planner.set_goal(goal)
        else:
            self.geometry_of[a] = BeamGeometry(g)

    # ------------------------------------------------------------------ inputs
    def on_input(self, addr, channel, msg) -> None:
        if channel != "data":
            return
        a = addr.without_key()
        if a == self.base:
            try:
                d = Position2dData.from_dict(msg)
            except MessageError:
                return
            self.pose, self.vel, self.stall = d.pose, d.vel, d.stall
            self.publish(self.out, d)
            # One control cycle per odometry message, timed by the base's own clock (simulated time
            # under a simulator at any speed-up).
            dt = 0.0 if self._last_t is None else min(max(d.t - self._last_t, 0.0), 1.0)
            self._last_t = d.t
            self._control(dt)
        elif a in self.geometry_of:
            try:
                scan = RangerData.from_dict(msg)
            except MessageError:
                return
            self.scans[a] = (self._now(), self.geometry_of[a].points(scan))

    def _now(self) -> float:
        import time

        return time.monotonic()

    # ------------------------------------------------------------------ control
    def _control(self, dt: float) -> None:
        import numpy as np

        now = self._now()
        fresh = [p for (t, p) in self.scans.values() if now - t <= STALE_SCAN]
        pts = np.concatenate(fresh) if fresh else np.zeros((0, 2))
        active = self.planner.goal is not None and self.planner.status not in ("idle", "done")
        cmd = self.planner.step(self.pose, (self.vel[0], self.vel[2]), pts, dt)
        if active or self.planner.status == "driving":
            if not fresh:  # blind: do not drive on stale data
                cmd = (0.0, 0.0)
            self.send(self.base, VelocityCmd(float(cmd[0]), float(cmd[1])))
            self._sent_stop = cmd[0] == 0.0 and cmd[1] == 0.0
        elif not self._sent_stop:
            self.send(self.base, VelocityCmd(0.0, 0.0))
            self._sent_stop = True
        status = str(self.planner.status)
        if status != self._last_status:
            if status in ("done", "blocked"):
                self.event(self.out, {"event": status, "pose": list(self.pose)})
            self._last_status = status

    def on_cmd(self, addr, msg) -> None:
        if "goal" in msg:
            self._goto(GoalCmd.from_dict(msg).goal)
            return
        v = VelocityCmd.from_dict(msg)
        self.planner.stop()
        self.send(self.base, v)
        self._sent_stop = v.v == 0.0 and v.w == 0.0

    def _goto(self, goal) -> None:
        if not all(math.isfinite(x) for x in goal):
            raise OutOfRange("goal must be finite")
        self.planner.set_goal(goal)
        self._last_status = "driving"

    def ops(self, addr):
        return ["goto", "stop", "status"]

    def on_rpc(self, addr, op, args):
        if op == "goto":
            self._goto(get_vec(args, "goal", 3))
            return {"status": str(self.planner.status)}
        if op == "stop":
            self.planner.stop()
            self.send(self.base, VelocityCmd(0.0, 0.0))
            self._sent_stop = True
            return {"status": "idle"}
        if op == "status":
            g = self.planner.goal
            return {"status": str(self.planner.status), "goal": list(g) if g is not None else []}
        raise RpcError(ErrorCode.UNKNOWN_OP, f"{addr} has no operation {op!r}; it has: {', '.join(self.all_ops(addr))}")

    def shutdown(self) -> None:
        try:
            self.send(self.base, VelocityCmd(0.0, 0.0))
        except Exception:
            pass

    def publish_rate(self, addr) -> float:
        return 10.0  # the base's odometry rate, which paces this driver

    def geometry(self, addr):
        g = {"base": str(self.base), "ranges": [str(r) for r in self.ranges], "algorithm": self.driver_name}
        g["frame"] = "odom"
        if self.base_size:
            g["size"] = list(self.base_size)
        g["robot_radius"] = float(self.planner.robot_radius)
        return g


def _make(name: str, module: str, cls_name: str):
    import importlib

    algo = getattr(importlib.import_module(f"mrs_bridge.nav.{module}"), cls_name)
    cls = type(f"{cls_name}Driver", (LocalPlannerDriver,), {"algorithm": algo, "__doc__": f"``{name}`` driver."})
    return register(name)(cls)


VFHDriver = _make("vfh", "vfh", "VFH")
NDDriver = _make("nd", "nd", "ND")
SNDDriver = _make("snd", "snd", "SND")
