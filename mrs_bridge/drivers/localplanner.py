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
degrees), plus ``cmd_timeout``; the robot's size comes from the base's describe geometry.

Safety (:mod:`mrs_bridge.baseguard`): a VelocityCmd passed through holds for ``cmd_timeout`` s
(the planner then commands its base zero); a goal is not a held velocity and is pursued without
refresh, the planner refreshing its base at least every :data:`REFRESH` s while it drives. The
output answers ``estop`` and ``release`` like a base: latched, it drops its goal, stops the base,
presses the base's own emergency stop, and refuses goals and velocities until released.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from rsal.interfaces import decode_as
from rsal.interfaces.ranger import RangerGeometry
from rsal.msgs import ErrorCode, GoalCmd, MessageError, Position2dData, RangerData, RpcError, VelocityCmd, get_vec

from ..baseguard import ESTOP_OPS, BaseGuard
from ..config import ConfigError
from ..driver import Driver, OutOfRange, register
from ..params import param, parse_params

__all__ = ["LocalPlannerDriver"]

RANGE_IFACES = ("laser", "ranger", "sonar")
STALE_SCAN = 1.0  # s (wall): a range device silent this long no longer counts (its points are dropped)
REFRESH = 0.2  # s (wall): while driving to a goal, the base's command is re-sent at least this often


@dataclass(frozen=True)
class LocalPlannerParams:
    """The driver's own keys; the algorithm's parameters are the rest (``LocalPlanner.PARAMS``)."""

    cmd_timeout: Any = param(None, doc="s, read by the base guard (mrs_bridge.baseguard)")


class LocalPlannerDriver(Driver):
    interfaces = ("position2d",)
    default_rate = 10.0  # control is event driven (one cycle per odometry message); update() refreshes and times out
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
        self.guard = BaseGuard.for_driver(self, self.out.node)
        # cmd_timeout is the base guard's; every other key is the algorithm's (mrs_bridge.nav.local
        # checks them against its PARAMS table: ranges, units, "did you mean")
        self.settings, self.params = parse_params(LocalPlannerParams, cfg, rest=True)
        try:  # validate now, so a bad parameter is a config error at start
            self.planner = self.algorithm(dict(self.params))
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
        self._last_cmd = (0.0, 0.0)  # the last velocity sent to the base, and when (wall)
        self._last_send = -math.inf
        self._last_odom = -math.inf
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
        if op == "estop":
            if error is not None:
                self.log.error("%s: could not latch the emergency stop of %s: %s", self.cfg.where, a, error)
            return
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
                self.planner = self.algorithm(dict(self.params), geometry=self.base_size)
                if goal is not None:
                    self.planner.set_goal(goal)
        else:
            self.geometry_of[a] = RangerGeometry(g)

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
            self._last_odom = self._now()
            g = self.guard
            if g.timed_out or g.estop:
                d = Position2dData(d.t, d.pose, d.vel, d.stall, d.timed_out or g.timed_out, d.estop or g.estop)
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
        return self.guard.clock()

    def _drive(self, v: float, w: float) -> None:
        """Command the base (and remember it for the refresh)."""
        self.send(self.base, VelocityCmd(v, w))
        self._last_cmd = (v, w)
        self._last_send = self._now()
        self._sent_stop = v == 0.0 and w == 0.0

    def update(self, now: float) -> None:
        """Wall-clock duties between odometry cycles: the passed-through velocity's timeout, and the
        refresh of the base's command while driving to a goal (a slow simulation's odometry may come
        less often than the base's command timeout)."""
        if self.guard.expired():
            self._drive(0.0, 0.0)
            return
        t = self._now()
        active = self.planner.goal is not None and self.planner.status not in ("idle", "done")
        if (
            active
            and not self.guard.estop
            and self._last_cmd != (0.0, 0.0)
            and t - self._last_send >= REFRESH
            and t - self._last_odom <= STALE_SCAN
        ):
            self._drive(*self._last_cmd)

    # ------------------------------------------------------------------ control
    def _control(self, dt: float) -> None:
        import numpy as np

        now = self._now()
        fresh = [p for (t, p) in self.scans.values() if now - t <= STALE_SCAN]
        pts = np.concatenate(fresh) if fresh else np.zeros((0, 2))
        active = self.planner.goal is not None and self.planner.status not in ("idle", "done")
        cmd = self.planner.step(self.pose, (self.vel[0], self.vel[2]), pts, dt)
        if self.guard.estop:  # latched: the goal was dropped; nothing is sent
            pass
        elif active or self.planner.status == "driving":
            if not fresh:  # blind: do not drive on stale data
                cmd = (0.0, 0.0)
            self._drive(float(cmd[0]), float(cmd[1]))
        elif not self._sent_stop:
            self._drive(0.0, 0.0)
        status = str(self.planner.status)
        if status != self._last_status:
            if status in ("done", "blocked"):
                self.event(self.out, {"event": status, "pose": list(self.pose)})
            self._last_status = status

    def on_cmd(self, addr, msg) -> None:
        # The server hands over a GoalCmd or a VelocityCmd (cmd_types); a plain map is decoded here.
        msg = decode_as((GoalCmd, VelocityCmd), msg)
        if isinstance(msg, GoalCmd):
            self._goto(msg.goal)
            return
        self._velocity(msg)

    def _velocity(self, v: VelocityCmd, *, rpc: bool = False) -> None:
        """A velocity passed through to the base: cancels the goal, held for ``cmd_timeout``."""
        self.guard.check(rpc=rpc)
        self.planner.stop()
        self.guard.command(v.v, v.w)
        self.send(self.base, v)
        self._last_cmd, self._last_send = (v.v, v.w), self._now()
        self._sent_stop = v.v == 0.0 and v.w == 0.0

    def _goto(self, goal, *, rpc: bool = False) -> None:
        if not all(math.isfinite(x) for x in goal):
            raise OutOfRange("goal must be finite")
        self.guard.check(rpc=rpc)
        self.guard.stopped()  # a goal replaces a passed-through velocity; it needs no refresh
        self.planner.set_goal(goal)
        self._last_status = "driving"

    def ops(self, addr):
        return ["goto", "stop", "status", *ESTOP_OPS]

    def on_rpc(self, addr, op, args):
        if op == "goto":
            self._goto(get_vec(args, "goal", 3), rpc=True)
            return {"status": str(self.planner.status)}
        if op == "stop":
            self.planner.stop()
            self.guard.stopped()
            self._drive(0.0, 0.0)
            return {"status": "idle"}
        if op == "set_velocity":
            self._velocity(VelocityCmd.from_dict(args), rpc=True)
            return {}
        if op == "estop":
            self.guard.press()
            self.planner.stop()
            self._drive(0.0, 0.0)
            self.request(self.base, "estop")  # whoever else commands the base, it must stop too
            return {"estop": True}
        if op == "release":  # the planner's own latch; the base is released by its own rpc/release
            self.guard.release()
            return {"estop": False}
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
