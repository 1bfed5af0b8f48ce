"""Local planners: the one interface of the VFH, ND and SND obstacle avoiders and what they share.

Player's ``vfh``, ``nd`` and ``snd`` drivers (thesis 3.4.1, appendix A.3) take a goal pose on their
``position2d`` interface and drive the underlying base there while avoiding what the laser (and
sonar) sees. Here each algorithm is a plain library object behind :class:`LocalPlanner`; a driver
binds it to the device server::

    planner = VFH({"max_speed": 0.4, "safety_dist_1ms": 0.4}, geometry=(0.44, 0.38))
    planner.set_goal((x, y, yaw))                    # in the base's odometry frame
    v, w = planner.step(pose, speed, points, dt)     # once per scan; points in the robot frame

Algorithms (one module each): :mod:`~mrs_bridge.nav.vfh` -- Borenstein & Koren 1991, "The Vector
Field Histogram", with Ulrich & Borenstein 1998, "VFH+"; :mod:`~mrs_bridge.nav.nd` -- Minguez &
Montano 2004, "Nearness Diagram (ND) Navigation"; :mod:`~mrs_bridge.nav.snd` -- Durham & Bullo
2008, "Smooth Nearness-Diagram Navigation".

What every planner shares, and therefore lives here (the parameter table in
:mod:`~mrs_bridge.nav.localparams`, the geometry of obstacle points in :mod:`~mrs_bridge.nav.obstacles`;
this module re-exports their names):

* **Parameters** by Player's names and in Player's configuration units (lengths m, speeds m/s,
  angles and turn rates in degrees and deg/s), so a Player ``.cfg`` block maps one to one. They are
  validated once: an unknown name is a ``ValueError`` naming the closest valid one, a bad value one
  naming the key and the expected range (:class:`~mrs_bridge.nav.localparams.Param`).
* **Goal handling**: drive until the position is within the position tolerance, then turn in place
  to the goal yaw until within the angle tolerance; then the status is ``done`` and the command
  zero. Near the goal the speed is capped so the robot can stop on it.
* **A motion guard** every command passes: the free length of the commanded arc for the robot's
  disc (``robot_radius``, half the base's diagonal) grown by the planner's safety distance is
  computed for all obstacle points at once, and the forward speed is cut to what can still stop
  in that length within one control period (:func:`free_path_length`). No command moves the robot
  towards an obstacle inside the safety distance. When the guard stops a forward command, the
  robot turns on the spot towards the free heading nearest the one the algorithm wanted and keeps
  to it for 1.5 s unless the algorithm comes round to it: it slides round what stopped it instead
  of dithering where the algorithm and the guard disagree.
* **A scan memory** (:class:`ScanMemory`): points of the last 3 s within 2 m, kept in the odometry
  frame, fill in the directions the sensors do not cover (behind a 240-degree laser), so turning on
  the spot does not forget an obstacle; the robot never backs up into space that has not been in
  view within those 3 s.
* **Limits**: ``|v|`` and ``|w|`` within the planner's maximum speed and turn rate; speeding up by
  at most the planner's acceleration per second (slowing down is never limited: a planner must
  be able to stop).
* **Stuck detection and escape**: no free direction for longer than the planner's blocked time,
  or no net progress in a window (closer to the goal, away from where the window began, or turned
  by an angle), puts the planner into status ``blocked`` and starts an escape: back up at the
  escape speed (where the guard and the memory allow) while turning towards the more open side for
  the escape time, then plan again -- and escape again, turning the other way, while still blocked.
* **A traffic rule**: of two ways round about equally good, take the right one (:data:`KEEP_RIGHT`);
  two robots meeting head-on then pass each other instead of mirroring each other's moves.
* **Polar helpers** over the obstacle points: sector minimum ranges (:func:`~mrs_bridge.nav.obstacles.polar_ranges`)
  and a swept-corridor test (:func:`~mrs_bridge.nav.obstacles.corridor_clear`), all vectorised with
  numpy over the points.

Units inside the objects are SI (metres, radians, seconds). Closed-loop runs on the simulator are
in :mod:`mrs_bridge.rigs.localsim`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from enum import StrEnum
from typing import Any, NamedTuple

import numpy as np

from rsal.geometry import wrap
from rsal.suggest import did_you_mean

from .localparams import Param, check_param
from .obstacles import ScanMemory, as_points, corridor_clear, free_path_length, polar_ranges

__all__ = [
    "KEEP_RIGHT",
    "Command",
    "LocalPlanner",
    "Param",
    "ScanMemory",
    "Status",
    "corridor_clear",
    "free_path_length",
    "polar_ranges",
]

log = logging.getLogger(__name__)

_TURN_GAIN = 1.5  # 1/s: in-place turn rate per radian of yaw error at the goal
KEEP_RIGHT = 0.1  # rad: a way round on the left must be this much nearer the goal to win (traffic rule)
_GUARD_FRACTIONS = np.array([1.0, 0.8, 0.6, 0.45, 0.3, 0.2, 0.1])  # speeds the guard tries, of the planned one
_OPEN_RANGE = 3.0  # m: ranges counted when judging which side is more open
_REAR_HALF_WIDTH = math.radians(45.0)  # backing up needs this cone behind seen within the memory's time
_SLIDE_DIRS = np.radians(np.arange(-120.0, 121.0, 10.0))  # headings tried when the guard stops the robot
_SLIDE_FREE = 0.5  # m of straight free path that makes a heading worth turning to
_SLIDE_COMMIT = 1.5  # s the robot keeps to a slide heading before the algorithm steers again
_SLIDE_AGREE = math.radians(20.0)  # ... unless the algorithm's own heading is this close to it


class Status(StrEnum):
    """A planner's state. Compares equal to its string value (``status == "done"``)."""

    IDLE = "idle"  # no goal (after construction or stop())
    DRIVING = "driving"  # on the way to the goal
    DONE = "done"  # goal position and yaw reached; the command is zero
    BLOCKED = "blocked"  # no free direction or no progress for too long; escaping


class Command(NamedTuple):
    """A velocity command for a differential drive: forward speed (m/s) and turn rate (rad/s)."""

    v: float
    w: float


STOP = Command(0.0, 0.0)


# ----------------------------------------------------------------------------------------------- helpers
def _floats(value, n: int, what: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be {n} numbers, not {value!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{what} must be {n} finite numbers, not {value!r}")
    return vals


# ----------------------------------------------------------------------------------------------- base class
class LocalPlanner:
    """A local planner: drives a differential-drive base to a goal pose around what it sees.

    ``params`` are Player's configuration options of the algorithm's driver (see the subclass's
    :attr:`PARAMS`); ``geometry`` is the base's ``(length, width)`` in metres from its position2d
    geometry, used for the robot's radius where the parameters do not give one (the radius is half
    the diagonal: the disc that holds the base in every heading).
    """

    name: str = "local"
    PARAMS: dict[str, Param] = {}

    # Set by each subclass's _configure (SI units).
    robot_radius: float
    v_max: float  # m/s
    w_max: float  # rad/s
    pos_tol: float  # m
    ang_tol: float  # rad
    turn_min: float  # rad/s, least turn rate when turning in place to the goal yaw
    accel: float | None  # m/s^2, limit on speeding up (None: none)
    brake: float  # m/s^2, deceleration the guard counts on
    escape_speed: float  # m/s, backwards
    escape_turnrate: float  # rad/s
    escape_time: float  # s
    blocked_after: float  # s without a free direction before status "blocked"
    stuck_time: float  # s: no progress in this time is stuck ...
    stuck_dist: float  # m: ... progress is moving this far ...
    stuck_angle: float  # rad: ... or turning this much
    rotate_stuck_time: float  # s turning in place without moving before stuck
    heading_wanted: float = 0.0  # rad, robot frame: the direction the algorithm chose last cycle

    def __init__(self, params: Mapping[str, Any] | None = None, *, geometry: Sequence[float] | None = None):
        self.params: dict[str, Any] = self._resolve(params)
        self.geometry: tuple[float, float] | None = None
        if geometry is not None:
            g = _floats(geometry, 2, f"{self.name}: geometry (length, width)")
            if not (g[0] > 0 and g[1] > 0):
                raise ValueError(f"{self.name}: geometry (length, width) must be positive metres, not {geometry!r}")
            self.geometry = (g[0], g[1])
        self._configure(self.params)
        self.goal: tuple[float, float, float] | None = None
        self.command = STOP
        self.status = Status.IDLE
        self.memory = ScanMemory()
        self._clock = 0.0  # s, summed dt (the memory's time base, never reset)
        self._pose = (0.0, 0.0, 0.0)
        self._reset()

    # ------------------------------------------------------------------ parameters
    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """The resolved default parameters (Player units)."""
        return cls._resolve_dict(cls, {})

    def _resolve(self, params: Mapping[str, Any] | None) -> dict[str, Any]:
        if params is None:
            params = {}
        if not isinstance(params, Mapping):
            raise ValueError(f"{self.name}: parameters must be a mapping of Player option names, not {params!r}")
        return self._resolve_dict(type(self), params)

    @staticmethod
    def _resolve_dict(cls, params: Mapping[str, Any]) -> dict[str, Any]:
        names = list(cls.PARAMS)
        for key in params:
            if key not in cls.PARAMS:
                close = did_you_mean(str(key), names, cutoff=0.0)
                hint = f"did you mean {close!r}? " if close else ""
                raise ValueError(f"{cls.name}: unknown parameter {key!r}; {hint}(valid: {', '.join(sorted(names))})")
        out: dict[str, Any] = {}
        for key, spec in cls.PARAMS.items():
            if key in params:
                out[key] = check_param(cls.name, key, params[key], spec)
            elif spec.same_as is not None:
                ref = out[spec.same_as]
                out[key] = ref if spec.factor == 1.0 else ref * spec.factor
            else:
                out[key] = spec.default
        return out

    def _configure(self, p: dict[str, Any]) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _radius(self, default: float) -> float:
        if self.geometry is not None:
            return 0.5 * math.hypot(*self.geometry)
        return default

    def safety(self, speed: float) -> float:
        """Safety distance (m) kept between the robot's disc and obstacles at ``speed`` m/s."""
        return 0.0

    # ------------------------------------------------------------------ interface
    def set_goal(self, goal: Sequence[float]) -> None:
        """Drive to ``(x, y, yaw)`` (m, m, rad) in the base's odometry frame."""
        self.goal = _floats(goal, 3, f"{self.name}: goal (x, y, yaw)")  # type: ignore[assignment]
        self.status = Status.DRIVING
        self._reset()

    def stop(self) -> None:
        """Forget the goal: status ``idle``, commands zero."""
        self.goal = None
        self.status = Status.IDLE
        self.command = STOP
        self._reset()

    def step(self, pose: Sequence[float], speed: Sequence[float], points, dt: float) -> Command:
        """One control cycle: the ``(v, w)`` command for the base.

        ``pose`` ``(x, y, yaw)`` in the odometry frame, ``speed`` the base's current ``(v, w)``,
        ``points`` the obstacle points ``(n, 2)`` in the robot frame (metres, x forward, y left;
        max-range readings already removed), ``dt`` seconds since the last step.
        """
        x, y, yaw = _floats(pose, 3, f"{self.name}: pose (x, y, yaw)")
        v_now, w_now = _floats(speed, 2, f"{self.name}: speed (v, w)")
        pts = as_points(points)
        dt = float(dt)
        if not (math.isfinite(dt) and dt >= 0.0):
            raise ValueError(f"{self.name}: dt must be a non-negative number of seconds, not {dt!r}")
        self._clock += dt
        self._pose = (x, y, yaw)
        remembered = self.memory.recall(self._clock, (x, y, yaw))
        self.memory.update(self._clock, (x, y, yaw), pts)
        if len(remembered):
            pts = np.concatenate((pts, remembered))
        if self.goal is None or self.status in (Status.IDLE, Status.DONE):
            self.command = STOP
            return STOP
        self._t += dt
        period = min(max(dt, 0.02), 0.5)  # the guard's reaction time
        gx, gy, gyaw = self.goal
        dx, dy = gx - x, gy - y
        dist = math.hypot(dx, dy)
        if dist <= self.pos_tol:
            self._arrived = True
        elif dist > 2.0 * self.pos_tol + 0.2:  # pushed away after arriving: drive back
            self._arrived = False
        if self._arrived:
            err = wrap(gyaw - yaw)
            if abs(err) <= self.ang_tol:
                self.status = Status.DONE
                self.command = STOP
                return STOP
            self.status = Status.DRIVING
            self._progress_reset(x, y, yaw)
            w = math.copysign(min(max(_TURN_GAIN * abs(err), self.turn_min), self.w_max), err)
            v = 0.0
        else:
            c, s = math.cos(yaw), math.sin(yaw)
            goal_r = (c * dx + s * dy, -s * dx + c * dy)
            v, w = self._drive(goal_r, dist, pts, v_now, w_now, (x, y, yaw), dt, period)
        self.command = self._limit(v, w, pts, v_now, dt, period)
        return self.command

    # ------------------------------------------------------------------ one cycle
    def _plan(
        self,
        goal: tuple[float, float],
        dist: float,
        pts: np.ndarray,
        speed: tuple[float, float],
        pose: tuple[float, float, float],
        dt: float,
    ) -> tuple[float, float, bool]:  # pragma: no cover - abstract
        """The algorithm: ``(v, w, free)`` towards the goal at ``goal`` (robot frame, ``dist`` m
        away); ``free`` False when no direction is free (``v, w`` then say how to wait)."""
        raise NotImplementedError

    def _drive(self, goal_r, dist, pts, v_now, w_now, pose, dt, period) -> tuple[float, float]:
        x, y, yaw = pose
        if self._escape_left > 0.0:
            self._escape_left -= dt
            self.status = Status.BLOCKED
            if self._escape_left <= 0.0:
                self._progress_reset(x, y, yaw)
            return self._escape_cmd
        v, w, free = self._plan(goal_r, dist, pts, (v_now, w_now), pose, dt)
        if free:
            self._no_way = 0.0
            self.status = Status.DRIVING
        else:
            self._no_way += dt
            if self._no_way >= self.blocked_after:
                self._no_way = 0.0
                self._blocked(pts, "no free direction", pose)
        if self._stuck(x, y, yaw, dist):
            self._blocked(pts, "no progress", pose)
        if self._escape_left > 0.0:
            return self._escape_cmd
        if self._slide_dir is not None and self._clock < self._slide_until:
            # Committed to sliding round what the guard stopped us at, unless the algorithm agrees.
            rel = float(wrap(self._slide_dir - yaw))
            if abs(wrap(self.heading_wanted - rel)) > _SLIDE_AGREE:
                w = float(np.clip(_TURN_GAIN * rel, -self.w_max, self.w_max))
                v = 0.5 * self.v_max * max(0.0, 1.0 - abs(rel) / _SLIDE_AGREE)
        # Approach: be able to stop on the goal (within half the tolerance).
        v = min(v, math.sqrt(2.0 * self.brake * max(dist - 0.5 * self.pos_tol, 0.0)), 1.5 * dist)
        return v, w

    def _limit(self, v: float, w: float, pts: np.ndarray, v_now: float, dt: float, period: float) -> Command:
        v = float(np.clip(v, -self.v_max, self.v_max))
        w = float(np.clip(w, -self.w_max, self.w_max))
        if self.accel is not None and abs(v) > abs(v_now):
            step = self.accel * max(dt, 1e-3)
            v = float(np.clip(v, v_now - step, v_now + step))
        if v != 0.0:
            wanted = v
            v = self._guard(v, w, pts, v_now, period)
            if v == 0.0 and wanted > 0.0:
                w = self._slide(pts, w)
        return Command(v, w)

    def _slide(self, pts: np.ndarray, w: float) -> float:
        """The guard stopped a forward command: turn on the spot towards the free direction
        nearest the one the planner wanted, so that the robot slides round what stopped it."""
        r = self.robot_radius + self.safety(0.0)
        c, s = np.cos(_SLIDE_DIRS)[:, None], np.sin(_SLIDE_DIRS)[:, None]
        along = pts[:, 0] * c + pts[:, 1] * s
        across = -pts[:, 0] * s + pts[:, 1] * c
        hit = (np.abs(across) < r) & (along > 0.0)
        reach = np.where(hit, along - np.sqrt(np.maximum(r * r - across * across, 0.0)), np.inf)
        length = reach.min(axis=1)
        free = length >= _SLIDE_FREE
        if not free.any():  # in a tight spot: any heading that frees a little more way than this one
            free = length >= max(float(length[len(_SLIDE_DIRS) // 2]) + 0.1, 0.15)
        if not free.any():
            return w
        cost = np.abs(_SLIDE_DIRS - self.heading_wanted)
        if self._slide_dir is not None and self._clock - self._slide_at < 1.0:
            # Keep sliding the way we started (in the odometry frame), so as not to dither.
            cost = cost + 0.5 * np.abs(wrap(_SLIDE_DIRS + self._pose[2] - self._slide_dir))
        phi = float(_SLIDE_DIRS[np.argmin(np.where(free, cost, np.inf))])
        self._slide_dir, self._slide_at = float(wrap(phi + self._pose[2])), self._clock
        self._slide_until = self._clock + _SLIDE_COMMIT
        if abs(phi) < 1e-9:
            return 0.0
        return math.copysign(min(max(_TURN_GAIN * abs(phi), self.turn_min), self.w_max), phi)

    def _guard(self, v: float, w: float, pts: np.ndarray, v_now: float, period: float) -> float:
        """Cut ``v`` so the robot can stop, within one control period plus braking, before its disc
        grown by the safety distance touches an obstacle point on the arc it drives."""
        sign = 1.0 if v > 0 else -1.0
        if sign < 0 and not self.memory.looked(self._clock, self._pose, math.pi, _REAR_HALF_WIDTH):
            return 0.0  # never back into space the sensors have not seen lately
        if len(pts) == 0:
            return v
        p = pts if sign > 0 else pts * np.array([-1.0, 1.0])  # reversing: mirror, drive forwards
        wf = w * sign
        speeds = abs(v) * _GUARD_FRACTIONS
        radius = self.robot_radius + self.safety(max(abs(v_now), abs(v)))
        a = self.brake
        horizon = abs(v) * period + v * v / (2.0 * a) + 0.05  # what stopping from |v| needs
        free = free_path_length(p, wf / speeds, radius, horizon)
        # The fastest speed that stops within `free`: travel one period, then brake.
        vstop = a * (np.sqrt(period * period + 2.0 * free / a) - period)
        ok = speeds <= vstop + 1e-9
        if not ok.any():
            return 0.0
        return sign * float(speeds[np.argmax(ok)])

    # ------------------------------------------------------------------ stuck and escape
    def _reset(self) -> None:
        self._t = 0.0
        self._arrived = False
        self._no_way = 0.0
        self._escape_left = 0.0
        self._escape_cmd = STOP
        self._escape_side = 0.0
        self._anchor: tuple[float, float, float, float, float] | None = None
        self._moved_at = 0.0
        self._slide_dir: float | None = None
        self._slide_at = -math.inf
        self._slide_until = -math.inf
        self._reset_algorithm()

    def _reset_algorithm(self) -> None:
        """Forget the algorithm's memory (a new goal or stop)."""

    def _progress_reset(self, x: float, y: float, yaw: float, dist: float = math.inf) -> None:
        self._anchor = (self._t, x, y, yaw, dist)
        self._moved_at = self._t

    def _stuck(self, x: float, y: float, yaw: float, dist: float) -> bool:
        """Progress is judged once per window of ``stuck_time``: by its end the robot must have got
        ``stuck_dist`` closer to the goal, or be ``stuck_dist`` from where the window began, or be
        turned ``stuck_angle`` from its heading then -- net, so dithering on the spot is no
        progress. Turning alone counts for at most ``rotate_stuck_time``."""
        a = self._anchor
        if a is None:
            self._progress_reset(x, y, yaw, dist)
            return False
        t0, x0, y0, yaw0, d0 = a
        if self._t - t0 < self.stuck_time:
            return False
        moved = math.hypot(x - x0, y - y0) >= self.stuck_dist or dist <= d0 - self.stuck_dist
        turned = abs(wrap(yaw - yaw0)) >= self.stuck_angle
        moved_at = self._t if moved else self._moved_at
        self._anchor = (self._t, x, y, yaw, dist)
        self._moved_at = moved_at
        if moved:
            return False
        return not turned or self._t - moved_at >= self.rotate_stuck_time

    def _blocked(self, pts: np.ndarray, why: str, pose: tuple[float, float, float]) -> None:
        repeat = self.status == Status.BLOCKED
        self.status = Status.BLOCKED
        self._progress_reset(*pose)
        if self.escape_time <= 0.0 or (self.escape_speed <= 0.0 and self.escape_turnrate <= 0.0):
            return
        side = self._open_side(pts)
        if repeat and self._escape_side != 0.0:
            side = -self._escape_side  # the last escape did not help: try the other way
        self._escape_side = side
        self._escape_left = self.escape_time
        # Backing up with w > 0 swings the front to the left.
        self._escape_cmd = Command(-self.escape_speed, side * self.escape_turnrate)
        log.debug(
            "%s: blocked (%s); escaping %s for %.1f s",
            self.name,
            why,
            "left" if side > 0 else "right",
            self.escape_time,
        )

    @staticmethod
    def _open_side(pts: np.ndarray) -> float:
        """+1 if the left half of the view is more open than the right, else -1."""
        r = polar_ranges(pts, 36, empty=_OPEN_RANGE)
        r = np.minimum(r, _OPEN_RANGE)
        left = float(r[1:13].sum())  # 10 .. 120 deg
        right = float(r[24:36].sum())  # -120 .. -10 deg
        return 1.0 if left >= right else -1.0
