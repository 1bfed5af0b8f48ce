"""``wavefront`` driver: the global planner on the fabric (Player's wavefront, thesis 3.4.1, A.3).

Binds :class:`mrs_bridge.nav.wavefront.Wavefront` and its :class:`~mrs_bridge.nav.executive.Executive`::

    [[driver]]
    name = "wavefront"
    provides = ["r0:planner:0"]
    requires = ["output::r0:position2d:1", "input::r0:position2d:2", "r0:map:0"]
    safety_dist = 0.3        # m
    distance_epsilon = 0.4   # m
    angle_epsilon = 10       # deg

``input`` is the localized position2d (the ``amcl`` driver's, map frame), ``output`` a local
planner's position2d (``vfh``/``nd``/``snd``, the base's odometry frame), ``map`` the grid map.
A goal (``rpc/set_goal``, ``goal`` [x, y, yaw rad] in the map frame) is planned at once over the
configuration space (obstacles grown by ``robot_radius + safety_dist``): an invalid goal (outside
the map, in an obstacle, unreachable) is an error reply (``not_found``) naming the reason.
Waypoints are then handed one by one to the local planner, each moved from the map frame into the
odometry frame through the offset between the localized and the odometry pose (and re-sent as
localization corrects it); the next waypoint is taken within ``distance_epsilon``, the goal is
done within ``distance_epsilon`` and ``angle_epsilon``. The plan is redone when the robot is more
than ``replan_dist_thresh`` from the path, at most every ``replan_min_time`` seconds (-1: never).

Data: :class:`rsal.msgs.PlannerData` at ``rate`` Hz (status, pose, goal, current waypoint, index
and count). Events: ``{"event": "done" | "aborted", "goal_id", "message"}``. Operations:
``set_goal``, ``stop``, ``resume``, ``waypoints`` and ``plan`` (a plan from ``start`` [x, y] -- default
the localized pose -- to ``goal`` [x, y], its ``length`` and ``waypoints``, made on a clone of the
planner that shares its configuration space, so the goal being driven is untouched: what a fleet
robot's bid costs, ``docs/dispatch.md``). Other parameters: ``robot_radius`` (m, default
from the output device's size), ``max_radius`` and ``dist_penalty`` (corridor-centring cost),
``replan_dist_thresh`` (m), ``replan_min_time`` (s); ``cspace_file``, ``force_map_refresh``,
``alwayson``, ``add_rotational_waypoints`` are accepted and have no effect.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from rsal.cliutil import FirstFew
from rsal.msgs import ErrorCode, MapData, MessageError, PlannerData, Position2dData, RpcError, VelocityCmd, get_vec

from ..config import ConfigError
from ..driver import Driver, register
from ..params import param, parse_params
from .navcommon import Handover

__all__ = ["WavefrontDriver"]

#: one "configuration space ready" line each for a few planners, then at debug level
_READY = FirstFew("planners ready")

RADIUS_TRIES = 20  # describes of the local planner (every 0.25 s) before its radius is taken as it is


@dataclass(frozen=True)
class WavefrontParams:
    """The ``wavefront`` driver's parameters (Player's names and units; module docstring)."""

    #: Player options that have no effect here: logged and dropped
    IGNORED: ClassVar[tuple[str, ...]] = ("cspace_file", "force_map_refresh", "alwayson", "add_rotational_waypoints")

    safety_dist: float = param(0.25, min=0.0, max=10.0, doc="m")
    distance_epsilon: float = param(0.5, min=0.0, max=10.0, doc="m")
    angle_epsilon: float = param(10.0, min=0.0, max=180.0, doc="deg")
    replan_dist_thresh: float = param(2.0, min=-1.0, doc="m; -1: never")
    replan_min_time: float = param(2.0, min=-1.0, doc="s; -1: never")
    robot_radius: float | None = param(None, min=0.0, max=10.0, doc="m; default: the local planner's")
    max_radius: float = param(1.0, min=0.0, max=50.0, doc="m")
    dist_penalty: float = param(1.0, min=0.0, max=1000.0)


#: the parameter names, in declaration order
PARAMS = tuple(f.name for f in fields(WavefrontParams))


@register("wavefront")
class WavefrontDriver(Driver):
    interfaces = ("planner",)
    default_rate = 10.0
    data_types = {"planner": "PlannerData"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        out = self.required("position2d", "output")
        inp = self.required("position2d", "input")
        maps = self.required("map")
        if len(out) != 1 or len(inp) != 1 or len(maps) != 1 or len(cfg.provides) != 1:
            raise ConfigError(
                f"{cfg.where}: wavefront provides one planner and requires output:: (local planner) and input:: "
                '(localized) position2d and a map, e.g. requires = ["output::r0:position2d:1", '
                '"input::r0:position2d:2", "r0:map:0"]'
            )
        self.out_addr, self.in_addr, self.map_addr = out[0].without_key(), inp[0].without_key(), maps[0].without_key()
        p = self.settings = parse_params(WavefrontParams, cfg, log=self.log)
        self.safety_dist, self.distance_epsilon = p.safety_dist, p.distance_epsilon
        self.angle_epsilon = math.radians(p.angle_epsilon)
        self.replan_dist_thresh, self.replan_min_time = p.replan_dist_thresh, p.replan_min_time
        self.robot_radius = p.robot_radius
        self.max_radius, self.dist_penalty = p.max_radius, p.dist_penalty
        self.exec = None
        self._probe = None  # a clone of the planner for rpc/plan (shares the configuration space)
        self.map_info = None
        self.loc = None  # localized pose (map)
        self.odom = None  # odometry pose of the local planner's base
        self.goal_id = 0
        self._open = 0  # the goal being driven or stopped, not yet ended by a done/aborted event
        self.handover = Handover()
        self._describe_tries = 0
        self._describe_again: float | None = None
        self._status = "idle"
        self._message = ""

    def setup(self) -> None:
        from ..kernels import prepare

        prepare("nav", label="nav")  # the search's kernels, before the planner is announced
        self.request(self.map_addr, "get", timeout=30.0)
        if self.robot_radius is None:
            self.request(self.out_addr, "describe")

    def ready(self) -> bool:
        return self.exec is not None  # the map is in and the configuration space built

    def on_reply(self, addr, op, result, error) -> None:
        if error is not None:
            if op == "describe":  # the radius falls back to the default
                self.robot_radius = self.robot_radius or 0.25
                self._build()
                return
            self.warn(f"retry:{op}", f"{self.cfg.where}: {addr} rpc/{op} failed ({error}); retrying")
            self.request(addr, op, timeout=30.0)
            return
        if op == "get":
            m = MapData.from_dict(result)
            from ..nav.grid import NavGrid

            self._grid = NavGrid.shared(m)  # one per map in the server
            self.map_info = (m.width, m.height, m.resolution)
            self._build()
        elif op == "describe":
            g = result.get("geometry", {}) or {}
            size = g.get("size")
            r = g.get("robot_radius")
            if size is None and "base" in g and self._describe_tries < RADIUS_TRIES:
                # a local planner that has not heard its base's size yet: ask again shortly
                self._describe_tries += 1
                self._describe_again = time.monotonic() + 0.25
                return
            if isinstance(r, int | float) and r > 0:
                self.robot_radius = float(r)
            elif isinstance(size, list) and len(size) >= 2:
                self.robot_radius = 0.5 * math.hypot(float(size[0]), float(size[1]))
            else:
                self.robot_radius = 0.25
            self._build()

    def _build(self) -> None:
        if self.exec is not None or self.robot_radius is None or getattr(self, "_grid", None) is None:
            return
        from ..nav.executive import Executive
        from ..nav.wavefront import Wavefront

        t0 = time.perf_counter()
        # One configuration space per map and robot size in the server (NavGrid.shared), each
        # planner a clone with its own search state: 100 robots of one size share one.
        key = ("wavefront", self.robot_radius, self.safety_dist, self.max_radius, self.dist_penalty)
        planner = self._grid.derived(
            key,
            lambda: Wavefront(
                self._grid,
                robot_radius=self.robot_radius,
                safety_dist=self.safety_dist,
                max_radius=self.max_radius,
                dist_penalty=self.dist_penalty,
            ),
        ).clone()
        self.exec = Executive(
            planner,
            distance_epsilon=self.distance_epsilon,
            angle_epsilon=self.angle_epsilon,
            replan_dist_thresh=self.replan_dist_thresh,
            replan_min_time=self.replan_min_time,
        )
        # Compile the search now (numba, cached on disk after the first run), not on the first goal.
        iy, ix = np.nonzero(planner.allowed)
        if len(ix):
            a = self._grid.cell_to_world(ix[0], iy[0])
            try:
                planner.plan((float(a[0]), float(a[1])), (float(a[0]), float(a[1])))
            except Exception:
                pass
            planner.reset()
        _READY.log(
            self.log,
            logging.INFO,
            "%s: configuration space ready (radius %.2f m + safety %.2f m) in %.0f ms",
            self.cfg.where,
            self.robot_radius,
            self.safety_dist,
            (time.perf_counter() - t0) * 1e3,
        )

    # ------------------------------------------------------------------ inputs
    def on_input(self, addr, channel, msg) -> None:
        if channel != "data":
            return
        a = addr.without_key()
        if a not in (self.in_addr, self.out_addr):
            return
        try:
            d = Position2dData.from_dict(msg)
        except MessageError:
            return
        if a == self.in_addr:
            self.loc = d.pose
        else:
            self.odom = d.pose

    # ------------------------------------------------------------------ the loop
    def update(self, now: float) -> None:
        if self._describe_again is not None and now >= self._describe_again:
            self._describe_again = None
            self.request(self.out_addr, "describe")
        ex = self.exec
        if ex is not None and ex.status == "driving" and self.loc is not None:
            target, status = ex.update(self.loc, now)
            if status == "driving" and target is not None:
                self._hand_over(tuple(float(v) for v in target), now)
            elif status in ("done", "aborted"):
                self._finish(status, str(ex.error) if ex.error else "")
        self._publish(now)

    def _hand_over(self, target_map, now: float) -> None:
        """Send the target to the local planner in its odometry frame."""
        if self.odom is None:
            return
        t_odom = self.handover.due(self.loc, self.odom, target_map, now)
        if t_odom is not None:
            self.send(self.out_addr, {"goal": list(t_odom)})

    def _finish(self, status: str, message: str) -> None:
        self.send(self.out_addr, VelocityCmd(0.0, 0.0))  # cancels the local goal and stops the base
        self.handover.reset()
        self._message = message
        self._end(self.goal_id, status, message)

    def _end(self, goal_id: int, status: str, message: str) -> None:
        """The one event that ends a goal: every goal id handed out gets exactly one."""
        if goal_id != self._open:
            return
        self._open = 0
        for a in self.cfg.provides:
            self.event(a, {"event": status, "goal_id": goal_id, "message": message})
        self.warn("goal", f"{self.cfg.where}: goal {goal_id} {status}{': ' + message if message else ''}", logging.INFO)

    def _publish(self, now: float) -> None:
        ex = self.exec
        status = ex.status if ex is not None else "idle"
        if status == "idle" and self._status == "invalid":
            status = "invalid"
        pose = self.loc or (0.0, 0.0, 0.0)
        goal = tuple(ex.goal) if ex is not None and ex.goal is not None else ()
        wp = ()
        n = idx = 0
        if ex is not None and ex.plan is not None:
            n = len(ex.plan.waypoints)
            idx = ex.waypoint_index
            if status == "driving":
                t = ex.target()
                wp = tuple(float(v) for v in t) if t is not None else ()
        msg = PlannerData(now, status, pose, goal, wp, idx, n, self._message)
        for a in self.cfg.provides:
            self.publish(a, msg)

    # ------------------------------------------------------------------ operations
    def ops(self, addr):
        return ["set_goal", "stop", "resume", "waypoints", "plan"]

    def on_rpc(self, addr, op, args):
        from ..nav.wavefront import PlanError

        ex = self.exec
        if op in ("set_goal", "resume") and (ex is None or self.loc is None):
            why = "no map yet" if ex is None else f"no localized pose yet from {self.in_addr}"
            raise RpcError(ErrorCode.UNAVAILABLE, f"{addr}: {why}; try again in a moment")
        if op == "set_goal":
            goal = get_vec(args, "goal", 3)
            now = time.monotonic()
            try:
                plan = ex.set_goal(self.loc, goal, now)
            except PlanError as e:
                # A rejected request changes nothing: a goal being driven goes on (and still ends with
                # its own done/aborted event). Otherwise the planner reports the goal invalid.
                if ex.status != "driving":
                    self._status = "invalid"
                    self._message = str(e)
                    ex.status = "idle"
                    ex.plan = None
                raise RpcError(ErrorCode.NOT_FOUND, f"invalid goal: {e}") from None
            self.goal_id += 1
            if self._open:  # the goal it replaces ends here, so nobody waits for it for ever
                self._end(self._open, "aborted", f"superseded by goal {self.goal_id}")
            self._open = self.goal_id
            self._status = "driving"
            self._message = ""
            self.handover.reset()
            self.update(now)
            return {"goal_id": self.goal_id, "waypoints": len(plan.waypoints), "length": float(plan.length)}
        if op == "stop":
            if ex is not None:
                ex.stop()
            self.send(self.out_addr, VelocityCmd(0.0, 0.0))
            self.handover.reset()
            return {"status": ex.status if ex is not None else "idle"}
        if op == "resume":
            st = ex.resume(self.loc, time.monotonic())
            if st == "aborted":
                self._finish("aborted", str(ex.error))
                raise RpcError(ErrorCode.UNAVAILABLE, f"cannot resume: {ex.error}")
            self.handover.reset()
            return {"status": st, "goal_id": self.goal_id}
        if op == "plan":
            return self._probe_plan(addr, args)
        if op == "waypoints":
            if ex is None or ex.plan is None:
                return {"waypoints": []}
            wp = ex.plan.waypoints
            return {"waypoints": [[float(x), float(y), 0.0] for x, y in wp], "length": float(ex.plan.length)}
        return super().on_rpc(addr, op, args)

    def _probe_plan(self, addr, args) -> dict:
        """``plan``: a path without driving it (its own search state; the executive's is untouched)."""
        from ..nav.wavefront import PlanError

        if self.exec is None:
            raise RpcError(ErrorCode.UNAVAILABLE, f"{addr}: no map yet; try again in a moment")
        goal = get_vec(args, "goal", 2)
        if args.get("start") is None:
            if self.loc is None:
                why = f"no 'start' and no localized pose yet from {self.in_addr}"
                raise RpcError(ErrorCode.UNAVAILABLE, f"{addr}: {why}")
            start = (float(self.loc[0]), float(self.loc[1]))
        else:
            start = get_vec(args, "start", 2)
        if self._probe is None:
            self._probe = self.exec.planner.clone()
        try:
            plan = self._probe.plan(start, goal)
        except PlanError as e:
            raise RpcError(ErrorCode.NOT_FOUND, f"no plan: {e}") from None
        wp = [[float(x), float(y)] for x, y in plan.waypoints]
        return {"length": float(plan.length), "waypoints": wp}

    def shutdown(self) -> None:
        try:
            self.send(self.out_addr, VelocityCmd(0.0, 0.0))
        except Exception:
            pass

    def geometry(self, addr):
        g = {
            "input": str(self.in_addr),
            "output": str(self.out_addr),
            "map": str(self.map_addr),
            "safety_dist": self.safety_dist,
            "distance_epsilon": self.distance_epsilon,
            "angle_epsilon": self.angle_epsilon,
            "frame": "map",
        }
        if self.robot_radius is not None:
            g["robot_radius"] = self.robot_radius
        return g
