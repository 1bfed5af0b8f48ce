"""The control center's robot console: per robot, its pose on the map, the initial pose of its
localizer, a goal for its planner, stop, emergency stop and wall-following (thesis 3.4.2: a robot
that localization cannot place is put on the map by hand; 5.2.3: Playernav's goals and stop).

:class:`RobotConsole` is a part of :class:`agents.control.Control`: its poller thread keeps each
robot's pose (the ``localize:0`` estimate, else the simulator's ground truth), and
:meth:`RobotConsole.robot_action` answers ``POST /api/robots/<name>/<action>`` (``pose``, ``goal``,
``stop``, ``estop``, ``wallfollow``), every bad input refused with an
:class:`~agents.control.api.ApiError`.
"""

from __future__ import annotations

import math
from concurrent.futures import Future
from dataclasses import dataclass, field

from rsal.procs import Child

from .api import NAME, ApiError, _addr, _num, _one_line, _only

__all__ = ["RobotConsole", "RobotState"]


@dataclass
class RobotState:
    pose: list[float] | None = None  # x, y, yaw (rad) in the map frame
    pose_source: str = ""
    goal: dict | None = None
    note: str = ""
    wallfollow: Child | None = None
    pending: set[str] = field(default_factory=set)


class RobotConsole:
    """Robot poses and actions (a part of :class:`agents.control.Control`)."""

    def _poll_poses(self) -> None:
        with self._lock:
            devices = set(self.devices)
        robots = sorted({d.split(":")[0] for d in devices if d.split(":")[1] == "position2d"} - {"sim"})
        sim = "sim:simulation:0" in devices
        for r in robots:
            st = self._robot(r)
            loc = f"{r}:localize:0"
            if loc in devices:
                p = self.fabric.device(loc).position
                if p is not None:
                    st.pose, st.pose_source = [p.x, p.y, p.yaw], "localize"
                    continue
            if sim and "truth" not in st.pending:
                st.pending.add("truth")
                fut = self.fabric.rpc_async(_addr("sim:simulation:0"), "get_pose", {"name": r}, timeout=2.0)
                fut.add_done_callback(lambda f, st=st: self._on_truth(st, f))

    @staticmethod
    def _on_truth(st: RobotState, fut: Future) -> None:
        st.pending.discard("truth")
        try:
            pose = fut.result()["pose"]
        except Exception:
            return
        if st.pose_source != "localize":
            st.pose, st.pose_source = [float(v) for v in pose[:3]], "simulation"

    def _robot(self, name: str) -> RobotState:
        with self._lock:
            return self.robots.setdefault(name, RobotState())

    def _robot_list(self, nodes: dict[str, list[str]], robots_st: dict[str, RobotState]) -> list[dict]:
        """The robots of ``/api/state``: every node with a ``position2d:0`` but the simulator's."""
        robots = []
        for n, ifs in nodes.items():
            if "position2d:0" not in ifs or n == "sim":
                continue
            st = robots_st.get(n) or RobotState()
            wf = st.wallfollow
            robots.append(
                {
                    "name": n,
                    "localize": "localize:0" in ifs,
                    "planner": "planner:0" in ifs,
                    "pose": st.pose,
                    "pose_source": st.pose_source,
                    "goal": st.goal,
                    "note": st.note,
                    "wallfollow": wf.info() if wf is not None else None,
                }
            )
        return robots

    # ------------------------------------------------------------------ robot actions
    def _need_robot(self, name: str) -> None:
        if not isinstance(name, str) or not NAME.match(name):
            raise ApiError(f"robot {name!r} must be a node name like r0")
        with self._lock:
            ok = f"{name}:position2d:0" in self.devices
        if not ok:
            raise ApiError(f"robot {name!r} has no position2d:0 on the fabric; see the robots in /api/state", 404)

    def _need_device(self, robot: str, iface: str, hint: str) -> str:
        addr = f"{robot}:{iface}:0"
        with self._lock:
            ok = addr in self.devices
        if not ok:
            raise ApiError(f"robot {robot!r} has no {iface}:0 ({hint})")
        return addr

    def robot_action(self, name: str, action: str, body: dict) -> dict:
        from rsal.data import Position
        from rsal.msgs import RpcError

        self._need_robot(name)
        st = self._robot(name)
        if action == "pose":
            _only(body, "pose", ("x", "y", "yaw"))
            x, y, yaw = _num(body, "x"), _num(body, "y"), _num(body, "yaw", 0.0)
            addr = self._need_device(name, "localize", "start the simulator with --nav, or an amcl driver")
            try:
                self.fabric.device(addr).set_position(Position(x, y, math.radians(yaw)))
            except (RpcError, TimeoutError, ValueError) as e:
                raise ApiError(f"{addr}: set pose failed: {_one_line(e)}", 502) from None
            st.note = f"initial pose set to ({x:.2f}, {y:.2f}, {yaw:.0f} deg)"
            return {"ok": True, "robot": name, "note": st.note}
        if action == "goal":
            _only(body, "goal", ("x", "y", "yaw"))
            x, y, yaw = _num(body, "x"), _num(body, "y"), _num(body, "yaw", 0.0)
            addr = self._need_device(name, "planner", "start the simulator with --nav, or a wavefront driver")
            planner = self.fabric.device(addr)
            fut = planner.set_goal(Position(x, y, math.radians(yaw)), timeout=10.0)
            if fut.done() and fut.exception() is not None:
                raise ApiError(f"{addr}: goal ({x:.2f}, {y:.2f}) refused: {_one_line(fut.exception())}")
            goal = {"x": x, "y": y, "yaw": yaw, "status": "driving"}
            st.goal = goal

            def done(f: Future, goal=goal) -> None:
                e = f.exception()
                goal["status"] = "done" if e is None else f"ended: {_one_line(e)}"

            fut.add_done_callback(done)
            return {"ok": True, "robot": name, "goal": goal, "waypoints": planner.waypoint_count}
        if action == "stop":
            _only(body, "stop", ())
            done_what = []
            with self._lock:
                has_planner = f"{name}:planner:0" in self.devices
            wf = st.wallfollow
            if wf is not None and wf.poll() is None:
                self._stop_child(wf, "agent")
                done_what.append("wall-following stopped")
            if has_planner:
                try:
                    self.fabric.device(f"{name}:planner:0").stop()
                    done_what.append("planner stopped")
                except (RpcError, TimeoutError) as e:
                    done_what.append(f"planner stop failed: {_one_line(e)}")
            self.fabric.device(f"{name}:position2d:0").stop()
            done_what.append("zero velocity sent")
            if st.goal is not None and st.goal.get("status") == "driving":
                st.goal["status"] = "stopped"
            st.note = "; ".join(done_what)
            return {"ok": True, "robot": name, "note": st.note}
        if action == "wallfollow":
            _only(body, "wallfollow", ("on",))
            on = body.get("on", True)
            if not isinstance(on, bool):
                raise ApiError("wallfollow.on must be true or false")
            wf = st.wallfollow
            running = wf is not None and wf.poll() is None
            if on:
                if running:
                    raise ApiError(f"robot {name!r} is already wall-following (pid {wf.pid})")
                with self._lock:
                    taken = [a for a in self.agents if a == f"wallfollow-{name}"]
                if taken:
                    raise ApiError(f"agent {taken[0]!r} is already alive on the fabric; stop it first")
                args = ["agent", "WallfollowAgent", "--robot", name, "--id", f"wallfollow-{name}"]
                st.wallfollow = self._spawn("agent", f"wallfollow-{name}", args)
                st.note = f"wall-following started (pid {st.wallfollow.pid})"
            else:
                if not running:
                    raise ApiError(f"robot {name!r} is not wall-following from this page")
                self._stop_child(wf, "agent", background=True)
                st.note = "wall-following stopping"
            return {"ok": True, "robot": name, "note": st.note}
        if action == "estop":
            return self.estop(body, name)
        raise ApiError(f"unknown robot action {action!r}; use pose, goal, stop, estop or wallfollow", 404)

    def estop(self, body: dict, name: str | None = None) -> dict:
        """Latch (``{"release": true}``: release) the emergency stop of robot ``name``'s bases, or of
        every base on the fabric: the bases refuse every commander, running scenarios' agents included."""
        from rsal.estop import estop

        _only(body, "estop", ("release",))
        release = body.get("release", False)
        if not isinstance(release, bool):
            raise ApiError("estop.release must be true or false")
        res = estop(self.fabric.session, name, release=release)
        if not res.confirmed:
            who = f"no base of robot {name!r}" if name else "no robot"
            raise ApiError(f"{who} answered the emergency stop; is it on the fabric?", 502)
        return {"ok": not res.failed, "robots": res.robots, "note": res.summary(), "failed": res.failed}
