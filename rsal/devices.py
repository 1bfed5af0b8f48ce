"""Client-side device proxies (thesis 3.6.2.3 "Device"), one class per Player interface.

A proxy subscribes to its device's ``data`` (and ``event``) key and keeps the latest decoded
message: agents read values without waiting, as the thesis's device threads did, but fed by push
instead of polling. Listeners (``add_listener``) are called on the fabric's dispatcher thread with
each new message. Commands are fire-and-forget puts; long operations (gripper open/close) return
``concurrent.futures.Future`` objects that resolve when the device reports the new state.
A proxy whose device's liveliness token goes away is marked lost (``alive`` false, ``on_lost``
listeners called); it recovers by itself when the device comes back.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any

import numpy as np

from . import keys, msgs
from .data import BlobfinderBlob, Position
from .keys import DeviceAddr
from .msgs import MessageError, decode_map

if TYPE_CHECKING:
    from .client import Fabric

__all__ = [
    "Device",
    "Position2d",
    "Ranger",
    "Laser",
    "Sonar",
    "Blobfinder",
    "Gripper",
    "Power",
    "Simulation",
    "MapDevice",
    "Localize",
    "Planner",
    "proxy_class",
]

log = logging.getLogger(__name__)
_monotonic = time.monotonic


class Device:
    """Base proxy: latest data, listeners, liveness, rpc and cmd."""

    data_type: Any = None  # msgs class used to decode data (None: plain dict)

    def __init__(self, fabric: Fabric, addr: DeviceAddr):
        self.fabric = fabric
        self.addr = addr
        self.alive = True
        self.latest: Any = None
        self.received_at = 0.0  # time.monotonic() of the latest data
        self.count = 0
        self._listeners: list[Callable[[Any], None]] = []
        self._inline_listeners: list[Callable[[Any], None]] = []
        self._event_listeners: list[Callable[[dict], None]] = []
        self._lost_listeners: list[Callable[[Device], None]] = []
        self._cond = threading.Condition()
        self._waiting = 0  # threads in wait_for_data: only then does new data need a notify
        self._bad = 0
        # The data path runs once per sample: bind what it calls once, here.
        dt = self.data_type
        if type(self)._decode is not Device._decode:  # a subclass decodes the map its own way
            self._from_bytes = lambda data: self._decode(decode_map(data))
        else:
            self._from_bytes = dt.from_bytes if dt is not None else decode_map
        self._has_after_data = type(self)._after_data is not Device._after_data
        s = fabric.session
        self._sub = s.declare_subscriber(keys.data_key(addr), fabric.callback(self._on_data))
        self._esub = s.declare_subscriber(keys.event_key(addr), fabric.callback(self._on_event))
        self._describe: msgs.Describe | None = None

    # ------------------------------------------------------------------ identity
    @property
    def node(self) -> str:
        return self.addr.node

    @property
    def interface(self) -> str:
        return self.addr.interface

    @property
    def index(self) -> int:
        return self.addr.index

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.addr} {'alive' if self.alive else 'lost'}>"

    # ------------------------------------------------------------------ inbound (Zenoh threads)
    def _decode(self, m: dict) -> Any:
        return self.data_type.from_dict(m) if self.data_type is not None else m

    def _on_data(self, sample) -> None:
        try:
            msg = self._from_bytes(sample.payload.to_bytes())
        except MessageError as e:
            self._bad += 1
            if self._bad in (1, 10, 100) or self._bad % 1000 == 0:
                log.warning("%s: dropped malformed data (%d so far): %s", self.addr, self._bad, e)
            return
        # One Zenoh thread per subscription delivers in order, so these plain writes need no lock;
        # waiters count themselves in under the condition before they check, so none is missed.
        self.latest = msg
        self.received_at = _monotonic()
        self.count += 1
        if self._waiting:
            with self._cond:
                self._cond.notify_all()
        if self._has_after_data:
            self._after_data(msg)
        for fn in self._inline_listeners:
            try:
                fn(msg)
            except Exception:
                log.exception("%s: inline listener %r failed", self.addr, getattr(fn, "__qualname__", fn))
        if self._listeners:
            submit = self.fabric.dispatcher.submit
            for fn in self._listeners:
                submit(fn, msg)

    def _after_data(self, msg: Any) -> None:
        """Hook for subclasses (runs on a Zenoh thread: keep it short)."""

    def _on_event(self, sample) -> None:
        try:
            ev = msgs.decode_map(sample.payload.to_bytes())
        except MessageError:
            return
        self._handle_event(ev)
        for fn in self._event_listeners:
            self.fabric.dispatcher.submit(fn, ev)

    def _handle_event(self, ev: dict) -> None:
        pass

    def _set_alive(self, alive: bool) -> None:
        if alive == self.alive:
            return
        self.alive = alive
        if not alive:
            for fn in self._lost_listeners:
                self.fabric.dispatcher.submit(fn, self)

    # ------------------------------------------------------------------ public
    def add_listener(self, fn: Callable[[Any], None], *, inline: bool = False) -> None:
        """``fn(msg)`` for every new data message, in order, on the fabric's dispatcher thread.

        ``inline=True`` runs ``fn`` on the Zenoh thread that decoded the message instead: no thread
        hand-off (the fastest path, for high-rate streams), but ``fn`` must return quickly and must
        not block or call Zenoh (STYLE rule 2). An exception in it is logged and dropped.
        """
        (self._inline_listeners if inline else self._listeners).append(fn)

    def remove_listener(self, fn: Callable[[Any], None]) -> None:
        for lst in (self._listeners, self._inline_listeners):
            if fn in lst:
                lst.remove(fn)

    def add_event_listener(self, fn: Callable[[dict], None]) -> None:
        self._event_listeners.append(fn)

    def on_lost(self, fn: Callable[[Device], None]) -> None:
        """``fn(device)`` when the device's token disappears (needs a DeviceNode watching it)."""
        self._lost_listeners.append(fn)

    def wait_for_data(self, timeout: float = 5.0, *, newer_than: int | None = None) -> Any:
        """Block until a data message (newer than message number ``newer_than``) arrived."""
        deadline = time.monotonic() + timeout
        with self._cond:
            self._waiting += 1
            try:
                while self.latest is None or (newer_than is not None and self.count <= newer_than):
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise TimeoutError(f"{self.addr}: no data within {timeout:g} s; is the device alive (rsal ls)?")
                    self._cond.wait(left)
                return self.latest
            finally:
                self._waiting -= 1

    def age(self) -> float:
        """Seconds since the latest data (inf if none)."""
        return time.monotonic() - self.received_at if self.latest is not None else math.inf

    def rpc(self, op: str, timeout: float = 5.0, **args) -> dict:
        return self.fabric.rpc(self.addr, op, args, timeout=timeout)

    def rpc_async(self, op: str, timeout: float = 5.0, **args) -> Future:
        return self.fabric.rpc_async(self.addr, op, args, timeout=timeout)

    def describe(self, timeout: float = 5.0) -> msgs.Describe:
        if self._describe is None:
            self._describe = msgs.Describe.from_dict(self.rpc("describe", timeout=timeout))
        return self._describe

    def send(self, msg) -> None:
        self.fabric.send(self.addr, msg)

    def undeclare(self) -> None:
        """Stop receiving (the fabric does this for every proxy when it closes)."""
        for s in (self._sub, self._esub):
            try:
                s.undeclare()
            except Exception:
                pass
        self.fabric._forget(self.addr)


class Position2d(Device):
    """A mobile base (Player position2d): pose in its frame, velocity, stall; velocity commands."""

    data_type = msgs.Position2dData

    @property
    def position(self) -> Position | None:
        m = self.latest
        return Position(*m.pose) if m is not None else None

    @property
    def velocity(self) -> tuple[float, float]:
        m = self.latest
        return (m.vel[0], m.vel[2]) if m is not None else (0.0, 0.0)

    @property
    def stalled(self) -> bool:
        return bool(self.latest.stall) if self.latest is not None else False

    def set_velocity(self, v: float, w: float, *, hold: bool = True) -> None:
        """Forward speed m/s and turn rate rad/s (the server rejects values over the robot's limits).

        A base stops by itself when its velocity command is not refreshed within its ``cmd_timeout``
        (0.5 s by default). ``hold=True``: the fabric re-sends this command every 0.2 s until the
        next command or :meth:`stop`, for callers that set a velocity once. ``hold=False``: the
        caller refreshes it itself (a control cycle at 5 Hz or more), so a controller that hangs
        lets the robot stop."""
        cmd = msgs.VelocityCmd(float(v), float(w))
        if hold and (cmd.v != 0.0 or cmd.w != 0.0):
            self.fabric.hold(self.addr, cmd)
        else:
            self.fabric.release(self.addr)
            self.send(cmd)

    def stop(self) -> None:
        self.fabric.release(self.addr)
        self.send(msgs.VelocityCmd(0.0, 0.0))

    def goto(self, goal: Position) -> None:
        """Drive to ``goal`` in this device's frame: for a local planner's position2d (vfh, nd, snd),
        which reports ``{"event": "done"}`` on arrival; a plain base rejects it. A position goal is
        not a held velocity: the planner pursues it without refresh."""
        self.fabric.release(self.addr)
        self.send(msgs.GoalCmd(goal.as_tuple()))

    def set_motor_power(self, on: bool, timeout: float = 5.0) -> bool:
        """Switch the motors on or off (Player's ``MOTOR_POWER``, ``rpc/motor_power``); while off the
        base ignores velocity commands and stays stopped. Returns the state the base reports."""
        return bool(self.rpc("motor_power", timeout=timeout, on=bool(on))["on"])

    def estop(self, timeout: float = 5.0) -> dict:
        """Latch this base's emergency stop (``rpc/estop``): it stops and refuses velocity commands
        until :meth:`release_estop`."""
        self.fabric.release(self.addr)
        return self.rpc("estop", timeout=timeout)

    def release_estop(self, timeout: float = 5.0) -> dict:
        """Release the latched emergency stop (``rpc/release``)."""
        return self.rpc("release", timeout=timeout)

    @property
    def estopped(self) -> bool:
        """The base reports its emergency stop latched."""
        return bool(self.latest.estop) if self.latest is not None else False

    @property
    def timed_out(self) -> bool:
        """The base stopped itself because its velocity command was not refreshed in time."""
        return bool(self.latest.timed_out) if self.latest is not None else False

    def set_odometry(self, pose: Position) -> dict:
        return self.rpc("set_odom", pose=list(pose.as_tuple()))

    def limits(self) -> tuple[float, float]:
        g = self.describe().geometry
        v, w = g.get("max_speed", (0.5, 1.0))
        return float(v), float(w)


class Ranger(Device):
    """A range sensor (Player ranger): ``ranges`` in metres, beam angles when known."""

    data_type = msgs.RangerData

    @property
    def ranges(self) -> np.ndarray | None:
        return self.latest.ranges if self.latest is not None else None

    def angles(self) -> np.ndarray | None:
        """Beam angles in the sensor frame: from the scan for a laser, from describe for a sonar."""
        m = self.latest
        if m is None:
            return None
        if m.angle_step != 0.0:
            return m.angle_min + np.arange(m.ranges.shape[0]) * m.angle_step
        g = self.describe().geometry
        return np.array([s["pose"][2] for s in g.get("sensors", [])], dtype=float)

    def sensor_poses(self) -> np.ndarray:
        """(n, 3) poses of the beams' origins in the robot frame (x, y, yaw)."""
        g = self.describe().geometry
        mount = g.get("pose", [0.0, 0.0, 0.0])
        sensors = g.get("sensors", [])
        m = self.latest
        out = []
        cm, sm = math.cos(mount[2]), math.sin(mount[2])
        for s in sensors:
            x, y, a = s["pose"]
            out.append((mount[0] + cm * x - sm * y, mount[1] + sm * x + cm * y, mount[2] + a))
        if len(out) == 1 and m is not None and m.ranges.shape[0] > 1:
            x, y, a = out[0]
            angs = self.angles()
            return np.column_stack([np.full(angs.shape, x), np.full(angs.shape, y), angs + mount[2]])
        return np.array(out, dtype=float).reshape(-1, 3)


class Laser(Ranger):
    pass


class Sonar(Ranger):
    pass


class Blobfinder(Device):
    data_type = msgs.BlobfinderData

    @property
    def blobs(self) -> list[BlobfinderBlob]:
        m = self.latest
        if m is None:
            return []
        return [
            BlobfinderBlob(b.id, b.color, b.area, b.x, b.y, b.left, b.right, b.top, b.bottom, b.range, b.bearing)
            for b in m.blobs
        ]


class Gripper(Device):
    """A gripper: ``open()``/``close()``/``lift_up()``/``lift_down()`` return futures that resolve
    with the gripper state when the paddles or lift reach the requested position."""

    data_type = msgs.GripperData

    def __init__(self, fabric, addr):
        self._waiters: list[tuple[Callable[[msgs.GripperData], bool], Future, float]] = []
        self._wlock = threading.Lock()
        super().__init__(fabric, addr)

    @property
    def state(self) -> msgs.GripperData | None:
        return self.latest

    @property
    def carrying(self) -> bool:
        return bool(self.latest and self.latest.stored)

    @property
    def beams(self) -> int:
        return self.latest.beams if self.latest else 0

    def _after_data(self, msg) -> None:
        now = time.monotonic()
        with self._wlock:
            keep = []
            for cond, fut, deadline in self._waiters:
                if fut.done():
                    continue
                if cond(msg):
                    fut.set_result(msg)
                elif now > deadline:
                    fut.set_exception(TimeoutError(f"{self.addr}: gripper did not get there in time"))
                else:
                    keep.append((cond, fut, deadline))
            self._waiters = keep

    def _command(self, action: str, cond, timeout: float) -> Future:
        fut: Future = Future()
        with self._wlock:
            self._waiters.append((cond, fut, time.monotonic() + timeout))
        self.send(msgs.GripperCmd(action))
        return fut

    def open(self, timeout: float = 10.0) -> Future:
        return self._command("open", lambda m: m.paddles == "open", timeout)

    def close(self, timeout: float = 10.0) -> Future:
        return self._command("close", lambda m: m.paddles == "closed", timeout)

    def lift_up(self, timeout: float = 10.0) -> Future:
        return self._command("up", lambda m: m.lift == "up", timeout)

    def lift_down(self, timeout: float = 10.0) -> Future:
        return self._command("down", lambda m: m.lift == "down", timeout)

    def stop(self) -> None:
        self.send(msgs.GripperCmd("stop"))


class Power(Device):
    data_type = msgs.PowerData

    @property
    def percent(self) -> float | None:
        return self.latest.percent if self.latest else None


class Simulation(Device):
    """The simulation interface (thesis ``setPositionOf``): poses of models by name."""

    data_type = msgs.SimulationData

    def get_pose(self, name: str) -> Position:
        return Position(*self.rpc("get_pose", name=name)["pose"])

    def set_pose(self, name: str, pose: Position) -> None:
        self.rpc("set_pose", name=name, pose=list(pose.as_tuple()))

    def models(self) -> dict:
        return self.rpc("models")

    def pause(self, paused: bool = True) -> bool:
        return bool(self.rpc("pause", paused=paused)["paused"])

    def step(self, n: int = 1) -> dict:
        return self.rpc("step", n=n)

    def reset(self) -> dict:
        return self.rpc("reset")


class MapDevice(Device):
    """A grid map (Player map): :meth:`get_map` fetches the whole grid once."""

    def get_map(self, timeout: float = 5.0) -> msgs.MapData:
        return msgs.MapData.from_dict(self.rpc("get", timeout=timeout))


class Localize(Device):
    """A localizer (Player's localize; the ``amcl`` driver): the robot's pose on the map with its
    covariance (thesis eq. 3.3-3.4) and the hypotheses behind it."""

    data_type = msgs.LocalizeData

    def get_position(self) -> Position | None:
        """The best pose estimate, or None before the first update."""
        m = self.latest
        return Position(*m.pose) if m is not None else None

    position = property(get_position)

    def covariance(self) -> np.ndarray | None:
        m = self.latest
        return np.asarray(m.cov, dtype=float).reshape(3, 3) if m is not None else None

    def hypotheses(self) -> list[msgs.Hypothesis]:
        m = self.latest
        return list(m.hypotheses) if m is not None else []

    def set_position(self, pose: Position, cov=(0.25, 0.25, 0.0685), timeout: float = 5.0) -> dict:
        """Re-initialise the filter around ``pose``; ``cov`` is a 3x3 matrix or its diagonal
        (m², m², rad²; default 0.5 m and 15 deg standard deviations). The thesis's way to help a robot
        that cannot find itself (3.4.2)."""
        c = np.asarray(cov, dtype=float)
        if c.shape == (3,):
            c = np.diag(c)
        if c.shape != (3, 3):
            raise ValueError("cov must be a 3x3 matrix or its diagonal (3 values)")
        return self.rpc("set_pose", timeout=timeout, pose=list(pose.as_tuple()), cov=[float(x) for x in c.ravel()])

    def set_global(self, timeout: float = 5.0) -> dict:
        """Forget the pose: global localization over all free space."""
        return self.rpc("set_global", timeout=timeout)


class Planner(Device):
    """A global planner (Player's planner; the ``wavefront`` driver): goals in the map frame.

    :meth:`set_goal` returns a future that resolves to the final status, ``"done"``, or raises
    :class:`~rsal.msgs.RpcError` (``not_found`` for an invalid goal: outside the map, in an obstacle,
    unreachable; ``unavailable`` when aborted, e.g. a replan failed, or superseded by another goal).
    """

    data_type = msgs.PlannerData

    def __init__(self, fabric, addr):
        super().__init__(fabric, addr)
        self._goal_futures: list[tuple[int, Future]] = []
        self._done_listeners: list[Callable[[str], None]] = []
        self._glock = threading.Lock()

    @property
    def status(self) -> str:
        m = self.latest
        return m.status if m is not None else "idle"

    @property
    def waypoint_count(self) -> int:
        m = self.latest
        return m.waypoint_count if m is not None else 0

    @property
    def waypoint_index(self) -> int:
        m = self.latest
        return m.waypoint_index if m is not None else 0

    def current_waypoint(self) -> Position | None:
        m = self.latest
        return Position(*m.waypoint) if m is not None and m.waypoint else None

    def waypoints(self, timeout: float = 5.0) -> list[Position]:
        return [Position(*w) for w in self.rpc("waypoints", timeout=timeout)["waypoints"]]

    def set_goal(self, goal: Position, timeout: float = 5.0) -> Future:
        """Plan to ``goal`` and drive there. The future resolves to "done" or raises RpcError."""
        fut: Future = Future()
        try:
            r = self.rpc("set_goal", timeout=timeout, goal=list(goal.as_tuple()))
        except Exception as e:  # RpcError (invalid goal, timeout) ends the future at once
            fut.set_exception(e)
            return fut
        with self._glock:
            for _, f in self._goal_futures:  # a new goal supersedes the old ones
                if not f.done():
                    f.set_exception(msgs.RpcError(msgs.ErrorCode.UNAVAILABLE, "superseded by a new goal"))
            self._goal_futures = [(int(r.get("goal_id", 0)), fut)]
        return fut

    def stop(self, timeout: float = 5.0) -> dict:
        return self.rpc("stop", timeout=timeout)

    def resume(self, timeout: float = 5.0) -> dict:
        return self.rpc("resume", timeout=timeout)

    def add_is_done_listener(self, fn: Callable[[str], None]) -> None:
        """``fn(status)`` when a goal ends: "done", "aborted" or "invalid"."""
        self._done_listeners.append(fn)

    def _handle_event(self, ev: dict) -> None:
        kind = ev.get("event")
        if kind not in ("done", "aborted", "invalid"):
            return
        gid = ev.get("goal_id", 0)
        with self._glock:
            keep = []
            for g, f in self._goal_futures:
                if g != gid:
                    keep.append((g, f))
                elif not f.done():
                    if kind == "done":
                        f.set_result("done")
                    else:
                        code = msgs.ErrorCode.NOT_FOUND if kind == "invalid" else msgs.ErrorCode.UNAVAILABLE
                        f.set_exception(msgs.RpcError(code, str(ev.get("message", kind))))
            self._goal_futures = keep
        for fn in self._done_listeners:
            self.fabric.dispatcher.submit(fn, kind)


_PROXIES: dict[str, type[Device]] = {
    "position2d": Position2d,
    "ranger": Ranger,
    "laser": Laser,
    "sonar": Sonar,
    "blobfinder": Blobfinder,
    "gripper": Gripper,
    "power": Power,
    "simulation": Simulation,
    "map": MapDevice,
    "localize": Localize,
    "planner": Planner,
}


def proxy_class(interface: str) -> type[Device]:
    return _PROXIES.get(interface, Device)
