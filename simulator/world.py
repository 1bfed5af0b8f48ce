"""The simulated world: bodies, differential drives, odometry, sensors and the simulation interface.

This plays Stage's role (thesis 2.2.1, appendix A.1, A.4-A.6). A :class:`World` is built from a
:class:`~simulator.spec.WorldSpec` and advanced in fixed steps of ``interval_sim`` seconds
(Stage's ``interval_sim``, 100 ms by default). Each step:

1. every robot's velocity approaches its commanded ``(v, w)`` within its acceleration and speed
   limits (Player's position2d velocity command);
2. pymunk moves the bodies: before each sub-step the motors of all robots are applied in one
   vectorised pass through pymunk's batch interface (:meth:`World._run_motors`); robots collide
   with the floorplan's walls (static boxes merged from the bitmap's occupied cells), with each
   other, and push objects that have ``obstacle_return``;
3. odometry integrates each robot's true motion in its own frame with a per-robot scale bias and
   white noise, so it drifts the way a wheel encoder does (Stage's ``odom_error``);
4. carried objects follow their gripper; grippers' paddles and lifts move and their beams update;
5. the rangers due this step (lasers and sonar cones of *all* robots) are cast in one batched,
   compiled pass (:mod:`simulator.raycast`) that also adds their noise; each sonar transducer then
   reads the minimum over its cone;
   blobfinders look for coloured bodies in their field of view with one occlusion ray each.

The simulation interface of Player (and the thesis's ``setPositionOf`` for mixed-reality proxies)
is :meth:`World.set_pose` / :meth:`World.get_pose` by model name, :meth:`World.add_model`,
:meth:`World.remove_model`, :meth:`World.pause`, :meth:`World.step` and :meth:`World.reset`.
Runs are deterministic for a given seed when stepped.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np
import pymunk
import pymunk.batch

from .controllers import StageControllers
from .errors import ModelError, OutOfWorld, SimulatorError
from .gridmap import GridMap
from .raycast import CircleIndex, cast_fans, segment_min
from .shapes import make_shapes
from .spec import BlobfinderSpec, GripperSpec, ModelSpec, RangerSpec, WorldSpec

__all__ = ["World", "RangerReading", "Blob", "GripperState", "SONAR_SUBRAYS"]

log = logging.getLogger(__name__)

SONAR_SUBRAYS = 5  # rays spread across a sonar cone; the transducer reads their minimum
_CIRCLE_CELL = 2.0  # m, hash-grid cell of the dynamic-body index
WORLD_MARGIN = 10.0  # m around the floorplan and the models' initial poses that set_pose accepts
_F = pymunk.batch.BodyFields
# Motor pass: per body [angle, vx, vy, w, fx, fy, torque] (pymunk's batch layout: fields in flag order).
_MOTOR_GET = _F.BODY_ID | _F.ANGLE | _F.VELOCITY | _F.ANGULAR_VELOCITY | _F.FORCE | _F.TORQUE
_MOTOR_SET = _F.VELOCITY | _F.ANGULAR_VELOCITY | _F.FORCE | _F.TORQUE
_POSE_GET = _F.BODY_ID | _F.POSITION | _F.ANGLE  # per body [x, y, angle]
# Per-robot state arrays, one row per robot.
_ROBOT_ARRAYS = ("_cmd", "_vel", "_limits", "_odom", "_bias", "_noise", "_prev", "_stall", "_drive", "_mass", "_moment")


def _wrap(a):
    """Angles to [-pi, pi)."""
    return (np.asarray(a) + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class RangerReading:
    """One scan of a ranger: ``ranges[i]`` is the range of beam/transducer ``i`` in metres."""

    ranges: np.ndarray  # float32
    time: float  # sim time of the scan, s
    spec: RangerSpec


@dataclass(frozen=True)
class Blob:
    """A coloured blob seen by a blobfinder (Player's ``player_blobfinder_blob``)."""

    name: str  # the model seen (simulation only; a real camera does not know it)
    color: tuple[int, int, int]
    x: int  # image centre column, pixels
    y: int  # image centre row, pixels
    left: int
    right: int
    top: int
    bottom: int
    area: int  # pixels
    range: float  # m
    bearing: float  # rad, positive to the left


@dataclass(frozen=True)
class GripperState:
    """Player's gripper state: paddles, lift, break beams, what is carried."""

    paddles: str  # "open" | "closed" | "opening" | "closing"
    lift: str  # "down" | "up" | "raising" | "lowering"
    inner_beam: bool  # an object is between the paddles, near their back
    outer_beam: bool  # an object is between the paddles, near their tips
    carrying: str | None  # name of the object held
    time: float


@dataclass
class _Gripper:
    spec: GripperSpec
    paddles: str = "open"
    lift: str = "down"
    paddle_progress: float = 0.0  # seconds of the current paddle motion done
    lift_progress: float = 0.0  # seconds of the current lift motion done (the lift moves independently)
    carrying: str | None = None
    inner_beam: bool = False
    outer_beam: bool = False
    stamp: float = 0.0


@dataclass
class _Blobfinder:
    spec: BlobfinderSpec
    blobs: list[Blob] = field(default_factory=list)
    stamp: float = 0.0


@dataclass
class _Model:
    spec: ModelSpec
    uid: int  # owner id in the ray caster
    body: pymunk.Body
    shapes: list[pymunk.Shape]
    radius: float  # bounding circle the rangers see
    row: int = -1  # index into the robot state arrays (robots only)
    rangers: list[RangerSpec] = field(default_factory=list)
    readings: list[RangerReading | None] = field(default_factory=list)
    blobfinders: list[_Blobfinder] = field(default_factory=list)
    grippers: list[_Gripper] = field(default_factory=list)
    carried_by: str | None = None  # name of the robot whose gripper holds this object
    in_space: bool = True

    @property
    def shape(self) -> pymunk.Shape:
        """The first collision polygon (a plain box model has only this one)."""
        return self.shapes[0]


class World:
    """A running simulation. Not thread-safe: call it from one thread (the device server's loop)."""

    def __init__(self, spec: WorldSpec, *, seed: int | None = None, substeps: int = 2):
        if spec.interval_sim <= 0 or not math.isfinite(spec.interval_sim):
            raise SimulatorError(f"interval_sim must be a positive number of seconds, not {spec.interval_sim!r}")
        self.spec = spec
        self.seed = spec.seed if seed is None else int(seed)
        self.substeps = max(1, int(substeps))
        self.grid: GridMap | None = None
        if spec.floorplan is not None:
            fp = spec.floorplan
            self.grid = GridMap.from_floorplan(fp, spec.resolution)
        self.bounds = self._bounds()
        self._build()

    def _bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)``: the floorplan and every model's initial pose, grown by
        :data:`WORLD_MARGIN`. Poses outside are refused, so no cost grows with a far coordinate."""
        xs = [m.pose[0] for m in self.spec.models]
        ys = [m.pose[1] for m in self.spec.models]
        if self.grid is not None:
            x0, x1, y0, y1 = self.grid.extent
            xs += [x0, x1]
            ys += [y0, y1]
        if not xs:
            xs = ys = [0.0]
        return (min(xs) - WORLD_MARGIN, max(xs) + WORLD_MARGIN, min(ys) - WORLD_MARGIN, max(ys) + WORLD_MARGIN)

    def in_bounds(self, x: float, y: float) -> bool:
        """Whether ``(x, y)`` lies inside :attr:`bounds` (where :meth:`set_pose` may put a model)."""
        x0, x1, y0, y1 = self.bounds
        return x0 <= x <= x1 and y0 <= y <= y1

    # ------------------------------------------------------------------ construction
    def _build(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.time = 0.0
        self.steps = 0
        self.paused = False
        self.space = pymunk.Space()
        self.space.damping = 0.2  # passive objects slow down (robots are driven every step)
        self.space.iterations = 10
        self.space.collision_slop = 0.002  # m: pymunk's default (0.1) is meant for pixels
        self._models: dict[str, _Model] = {}
        self._robots: list[_Model] = []
        self._next_uid = 0
        self._fans_dirty = True
        self._scan_out: np.ndarray | None = None
        self._reduce: tuple[np.ndarray, np.ndarray] | None = None  # (first ray, ray count) per reading
        self._add_walls()
        n0 = 0
        self._cmd = np.zeros((n0, 2))
        self._vel = np.zeros((n0, 2))
        self._limits = np.zeros((n0, 4))
        self._odom = np.zeros((n0, 3))
        self._bias = np.zeros((n0, 3))
        self._noise = np.zeros((n0, 3))
        self._prev = np.zeros((n0, 3))
        self._stall = np.zeros(n0, dtype=bool)
        self._drive = np.zeros((n0, 2))  # (v, w) the motors applied in the last step
        self._mass = np.zeros(n0)  # kg, and moment of inertia in kg m^2, of each robot body
        self._moment = np.zeros(n0)
        # Batch buffers, reused: pymunk allocates one per Buffer and never frees it.
        self._get_buf = pymunk.batch.Buffer()  # reads fill its own arrays
        self._set_buf = pymunk.batch.Buffer()  # writes are handed a numpy array each time
        self._bodies_dirty = True  # the space's bodies or the robot rows changed since the last map
        self._body_ids = np.zeros(0, dtype=np.uintp)  # space's bodies, in batch order
        self._body_rows = np.zeros(0, dtype=np.int64)  # robot row of each, -1 for objects
        self._body_seen = np.zeros(0, dtype=bool)  # has laser_return: rangers see it as a circle
        self._body_radius = np.zeros(0)  # m, that circle's radius
        self._body_uid = np.zeros(0, dtype=np.int64)  # owner id in the ray caster
        for m in self.spec.models:
            self._add(m)
        self.controllers = StageControllers(self.spec.models, self.seed)

    def _add_walls(self) -> None:
        if self.grid is None:
            return
        g = self.grid
        body = self.space.static_body
        shapes = []
        r = g.resolution
        x0, y0 = g.origin
        for ix0, iy0, ix1, iy1 in g.rectangles():
            box = pymunk.Poly(
                body,
                [
                    (x0 + ix0 * r, y0 + iy0 * r),
                    (x0 + ix1 * r, y0 + iy0 * r),
                    (x0 + ix1 * r, y0 + iy1 * r),
                    (x0 + ix0 * r, y0 + iy1 * r),
                ],
            )
            box.friction = 0.6
            shapes.append(box)
        self.space.add(*shapes)
        self._wall_count = len(shapes)

    def _add(self, spec: ModelSpec) -> _Model:
        if spec.name in self._models:
            raise ModelError(f"a model named {spec.name!r} already exists; choose another name")
        sx, sy = float(spec.size[0]), float(spec.size[1])
        if not (sx > 0 and sy > 0):
            raise ModelError(f"model {spec.name!r}: size {spec.size!r} must be positive")
        body = pymunk.Body(max(float(spec.mass), 1e-3), 1.0)
        x, y, a = spec.pose
        body.position = (float(x), float(y))
        body.angle = float(a)
        shapes, body.moment, radius = make_shapes(body, spec)  # Stage blocks scaled to size, at origin
        for shape in shapes:
            shape.friction = 0.6
            shape.sensor = not spec.obstacle_return
        self.space.add(body, *shapes)
        model = _Model(spec=spec, uid=self._next_uid, body=body, shapes=shapes, radius=radius)
        self._next_uid += 1
        self._models[spec.name] = model
        if spec.position:
            model.rangers = list(spec.rangers)
            model.readings = [None] * len(spec.rangers)
            model.blobfinders = [_Blobfinder(b) for b in spec.blobfinders]
            model.grippers = [_Gripper(g) for g in spec.grippers]
            model.row = len(self._robots)
            self._robots.append(model)
            e = np.asarray(spec.odom_error, dtype=float)
            bias = self.rng.uniform(-1.0, 1.0, 3) * e
            self._cmd = np.vstack([self._cmd, [0.0, 0.0]])
            self._vel = np.vstack([self._vel, [0.0, 0.0]])
            self._limits = np.vstack([self._limits, [*spec.max_speed, *spec.max_accel]])
            self._odom = np.vstack([self._odom, [0.0, 0.0, 0.0]])
            self._bias = np.vstack([self._bias, bias])
            self._noise = np.vstack([self._noise, np.asarray(spec.odom_noise, dtype=float)])
            self._prev = np.vstack([self._prev, [x, y, a]])
            self._stall = np.append(self._stall, False)
            self._drive = np.vstack([self._drive, [0.0, 0.0]])
            self._mass = np.append(self._mass, body.mass)
            self._moment = np.append(self._moment, body.moment)
        self._fans_dirty = self._bodies_dirty = True
        return model

    # ------------------------------------------------------------------ model access
    @property
    def robot_names(self) -> list[str]:
        return [m.spec.name for m in self._robots]

    @property
    def model_names(self) -> list[str]:
        return list(self._models)

    def _model(self, name: str) -> _Model:
        try:
            return self._models[name]
        except KeyError:
            raise ModelError(f"no model named {name!r}; models: {', '.join(self._models) or 'none'}") from None

    def _robot(self, name: str) -> _Model:
        m = self._model(name)
        if not m.spec.position:
            raise ModelError(f"model {name!r} is not a robot (it has no position model)")
        return m

    def model_spec(self, name: str) -> ModelSpec:
        return self._model(name).spec

    # ------------------------------------------------------------------ simulation interface
    def get_pose(self, name: str) -> tuple[float, float, float]:
        """Ground-truth pose ``(x, y, yaw)`` of any model."""
        b = self._model(name).body
        return (float(b.position.x), float(b.position.y), float(_wrap(b.angle)))

    def set_pose(self, name: str, x: float, y: float, yaw: float) -> None:
        """Move a model to a pose at once (the thesis's ``setPositionOf``). Odometry does not jump."""
        vals = (float(x), float(y), float(yaw))
        if not all(math.isfinite(v) for v in vals):
            raise ModelError(f"set_pose({name!r}): pose {vals!r} must be finite numbers")
        m = self._model(name)
        if not self.in_bounds(vals[0], vals[1]):
            x0, x1, y0, y1 = self.bounds
            raise OutOfWorld(
                f"set_pose({name!r}): ({vals[0]:g}, {vals[1]:g}) is outside the world; "
                f"x must be in [{x0:g}, {x1:g}] and y in [{y0:g}, {y1:g}] m"
            )
        if m.carried_by is not None:
            self._release(m)
        b = m.body
        b.position = vals[:2]
        b.angle = vals[2]
        b.velocity = (0.0, 0.0)
        b.angular_velocity = 0.0
        if m.in_space:
            self.space.reindex_shapes_for_body(b)
        if m.row >= 0:
            self._prev[m.row] = vals
            self._vel[m.row] = 0.0
        self._fans_dirty = True

    def add_model(self, spec: ModelSpec) -> None:
        """Add a robot or object while running."""
        self._add(replace(spec))

    def remove_model(self, name: str) -> None:
        """Remove a model; anything it carried is dropped where it is."""
        m = self._model(name)
        for g in m.grippers:
            if g.carrying:
                self._release(self._models[g.carrying])
        if m.carried_by is not None:
            self._release(m)
        if m.in_space:
            self.space.remove(*m.shapes, m.body)
        del self._models[name]
        if m.row >= 0:
            r = m.row
            keep = np.ones(len(self._robots), dtype=bool)
            keep[r] = False
            for attr in _ROBOT_ARRAYS:
                setattr(self, attr, getattr(self, attr)[keep])
            self._robots.pop(r)
            for i, rm in enumerate(self._robots):
                rm.row = i
        self._fans_dirty = self._bodies_dirty = True

    def pause(self, paused: bool = True) -> None:
        """While paused, :meth:`advance` does nothing; :meth:`step` still steps (Stage's step button)."""
        self.paused = bool(paused)

    def reset(self) -> None:
        """Back to the world file's initial state and the same seed."""
        self._build()

    # ------------------------------------------------------------------ robots
    def set_velocity(self, name: str, v: float, w: float) -> None:
        """Command a robot's forward speed (m/s) and turn rate (rad/s); clipped to its limits."""
        m = self._robot(name)
        if not (math.isfinite(v) and math.isfinite(w)):
            raise ModelError(f"set_velocity({name!r}): v={v!r}, w={w!r} must be finite")
        vmax, wmax = float(self._limits[m.row, 0]), float(self._limits[m.row, 1])
        self._cmd[m.row] = (min(max(float(v), -vmax), vmax), min(max(float(w), -wmax), wmax))

    def halt(self, name: str) -> None:
        """Stop a robot at once, past its acceleration limits (a brake: command timeout, emergency stop)."""
        m = self._robot(name)
        self._cmd[m.row] = (0.0, 0.0)
        self._vel[m.row] = (0.0, 0.0)

    def velocity(self, name: str) -> tuple[float, float]:
        """The robot's current ``(v, w)`` after acceleration limits and collisions."""
        return tuple(float(x) for x in self._vel[self._robot(name).row])  # type: ignore[return-value]

    def commanded_velocity(self, name: str) -> tuple[float, float]:
        return tuple(float(x) for x in self._cmd[self._robot(name).row])  # type: ignore[return-value]

    def odometry(self, name: str) -> tuple[float, float, float]:
        """Odometric pose: starts at (0, 0, 0) where the robot was created and drifts."""
        o = self._odom[self._robot(name).row]
        return (float(o[0]), float(o[1]), float(_wrap(o[2])))

    def set_odometry(self, name: str, x: float, y: float, yaw: float) -> None:
        """Reset the odometric pose (Player's position2d ``set_odom``)."""
        self._odom[self._robot(name).row] = (float(x), float(y), float(yaw))

    def stalled(self, name: str) -> bool:
        """True when the robot is commanded to move but is blocked (Player's ``stall``)."""
        return bool(self._stall[self._robot(name).row])

    def ranger(self, name: str, index: int = 0) -> RangerReading | None:
        """The latest scan of a robot's ranger ``index`` (None before the first one)."""
        m = self._robot(name)
        if not 0 <= index < len(m.rangers):
            raise ModelError(f"robot {name!r} has {len(m.rangers)} ranger(s); index {index} does not exist")
        return m.readings[index]

    def rangers(self, name: str) -> list[RangerSpec]:
        return list(self._robot(name).rangers)

    def blobfinder(self, name: str, index: int = 0) -> list[Blob]:
        m = self._robot(name)
        if not 0 <= index < len(m.blobfinders):
            raise ModelError(f"robot {name!r} has {len(m.blobfinders)} blobfinder(s); index {index} does not exist")
        return list(m.blobfinders[index].blobs)

    def gripper(self, name: str, index: int = 0) -> GripperState:
        g = self._gripper(name, index)
        return GripperState(g.paddles, g.lift, g.inner_beam, g.outer_beam, g.carrying, g.stamp)

    def gripper_command(self, name: str, command: str, index: int = 0) -> None:
        """``open``, ``close``, ``up``, ``down`` or ``stop`` (Player's gripper/actarray commands)."""
        g = self._gripper(name, index)
        cmd = str(command).lower()
        if cmd == "open":
            if g.paddles not in ("open", "opening"):
                g.paddles, g.paddle_progress = "opening", 0.0
        elif cmd == "close":
            if g.paddles not in ("closed", "closing"):
                g.paddles, g.paddle_progress = "closing", 0.0
        elif cmd == "up":
            if g.lift not in ("up", "raising"):
                g.lift, g.lift_progress = "raising", 0.0
        elif cmd == "down":
            if g.lift not in ("down", "lowering"):
                g.lift, g.lift_progress = "lowering", 0.0
        elif cmd == "stop":
            g.paddles = {"opening": "open", "closing": "open"}.get(g.paddles, g.paddles)
            g.lift = {"raising": "down", "lowering": "down"}.get(g.lift, g.lift)
        else:
            raise ModelError(f"unknown gripper command {command!r}; use open, close, up, down or stop")

    def _gripper(self, name: str, index: int) -> _Gripper:
        m = self._robot(name)
        if not 0 <= index < len(m.grippers):
            raise ModelError(f"robot {name!r} has {len(m.grippers)} gripper(s); index {index} does not exist")
        return m.grippers[index]

    # ------------------------------------------------------------------ stepping
    def advance(self) -> bool:
        """One step unless paused; returns whether it stepped."""
        if self.paused:
            return False
        self.step()
        return True

    def step(self, n: int = 1) -> None:
        """Advance ``n`` fixed steps of ``interval_sim`` seconds (even while paused)."""
        for _ in range(int(n)):
            self._step_once()
            if self.controllers:  # Stage ``ctrl`` controllers act on this step's readings
                self.controllers(self)

    def _step_once(self) -> None:
        dt = self.spec.interval_sim
        n = len(self._robots)
        if n:
            # 1. acceleration-limited velocity towards the command.
            dv = np.clip(self._cmd - self._vel, -self._limits[:, 2:4] * dt, self._limits[:, 2:4] * dt)
            self._vel += dv
        # 2. physics.
        h = dt / self.substeps
        for k in range(self.substeps):
            if n:
                self._run_motors(h, first=k == 0)
            self.space.step(h)
        self.time = (self.steps + 1) * dt
        self.steps += 1
        if n:
            pose = self._robot_poses()
            self._update_odometry(pose, dt)
            self._prev = pose
        # 4. grippers and carried objects.
        self._update_grippers(dt)
        # 5. sensors.
        self._update_rangers()
        self._update_blobfinders()

    # ------------------------------------------------------------------ motors
    def _space_bodies(self, fields, width: int) -> tuple[np.ndarray, np.ndarray]:
        """Every body in the space in one batched read: ``(rows, values)`` with ``rows[i]`` the
        robot row of body ``i`` (-1 for an object) and ``values[i]`` its ``width`` floats."""
        buf = self._get_buf
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, fields, buf)
        ids = np.frombuffer(buf.int_buf(), dtype=np.uintp)
        if self._bodies_dirty or not np.array_equal(ids, self._body_ids):
            # Bodies were added or removed (pymunk reorders its list on removal): map them again.
            model_of = {m.body.id: m for m in self._models.values()}
            ms = [model_of.get(int(i)) for i in ids]  # None: a body added to the space from outside
            self._body_rows = np.array([m.row if m else -1 for m in ms], dtype=np.int64)
            self._body_seen = np.array([bool(m and m.spec.laser_return) for m in ms], dtype=bool)
            self._body_radius = np.array([m.radius if m else 0.0 for m in ms], dtype=float)
            self._body_uid = np.array([m.uid if m else -1 for m in ms], dtype=np.int64)
            self._body_ids = ids.copy()
            self._bodies_dirty = False
        vals = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(ids.size, width)
        return self._body_rows, vals

    def _run_motors(self, h: float, first: bool) -> None:
        """Drive every robot body for one pymunk sub-step of ``h`` seconds, in one batched pass.

        The motor is a force and torque that make pymunk's velocity integration (damped previous
        velocity plus force over mass) land exactly on the commanded ``(v, w)``, so the velocity is
        set *before* contacts are solved: walls and other bodies still stop or deflect the robot,
        and the next position update moves it with the corrected velocity. The linear velocity is
        the chord of the step's arc along the heading at mid-step (exact integration of the
        unicycle model). On the first sub-step of a step, a robot whose drive changed gets the new
        velocity at once, so it moves from this step on; an unchanged drive leaves the contact
        corrections of the last step in place."""
        rows, b = self._space_bodies(_MOTOR_GET, 7)
        b = b.copy()  # becomes the write buffer: [angle, vx, vy, w, fx, fy, torque]
        r = rows >= 0
        rr = rows[r]
        v, w = self._vel[rr, 0], self._vel[rr, 1]
        half = 0.5 * h * w
        small = np.abs(half) <= 1e-12
        chord = v * np.where(small, 1.0, np.sin(half) / np.where(small, 1.0, half))
        ang = b[r, 0]
        cur = b[r, 1:4]
        if first:
            changed = (self._vel[rr] != self._drive[rr]).any(axis=1)
            if changed.any():
                a0 = ang[changed] + half[changed]
                cur[changed] = np.stack([chord[changed] * np.cos(a0), chord[changed] * np.sin(a0), w[changed]], 1)
            self._drive[rr] = self._vel[rr]
        # Heading after pymunk's position update (angle + w h), then half the step's turn on.
        a = ang + cur[:, 2] * h + half
        damp = self.space.damping**h
        mass = self._mass[rr]
        b[r, 1:4] = cur
        b[r, 4] = mass * (chord * np.cos(a) - cur[:, 0] * damp) / h
        b[r, 5] = mass * (chord * np.sin(a) - cur[:, 1] * damp) / h
        b[r, 6] = self._moment[rr] * (w - cur[:, 2] * damp) / h
        self._set_buf.set_float_buf(np.ascontiguousarray(b[:, 1:]).reshape(-1))
        pymunk.batch.set_space_bodies(self.space, _MOTOR_SET, self._set_buf)

    def _robot_poses(self) -> np.ndarray:
        """``(x, y, angle)`` of every robot, by row, in one batched read."""
        rows, b = self._space_bodies(_POSE_GET, 3)
        pose = np.empty((len(self._robots), 3))
        r = rows >= 0
        pose[rows[r]] = b[r]
        if r.sum() < len(self._robots):  # a robot held by a gripper is out of the space
            for m in self._robots:
                if not m.in_space:
                    pose[m.row] = (m.body.position.x, m.body.position.y, m.body.angle)
        return pose

    def _update_odometry(self, pose: np.ndarray, dt: float) -> None:
        d = pose - self._prev
        dth = _wrap(d[:, 2])
        # Displacement in the frame of the mid-step heading (where the chord of an arc points).
        mid_true = self._prev[:, 2] + 0.5 * dth
        c, s = np.cos(mid_true), np.sin(mid_true)
        dx = c * d[:, 0] + s * d[:, 1]
        dy = -s * d[:, 0] + c * d[:, 1]
        # Achieved velocity in the robot frame, and stall detection.
        achieved = np.stack([dx / dt, dth / dt], axis=1)
        expect = np.abs(self._vel[:, 0]) * dt
        self._stall = (expect > 1e-3) & (np.hypot(dx, dy) < 0.3 * expect)
        self._vel[:, 0] = np.where(self._stall, achieved[:, 0], self._vel[:, 0])
        nz = self.rng.standard_normal((len(dx), 3)) * self._noise
        ox = dx * (1.0 + self._bias[:, 0]) + nz[:, 0] * np.abs(dx)
        oy = dy * (1.0 + self._bias[:, 1]) + nz[:, 1] * np.abs(dx)
        ot = dth * (1.0 + self._bias[:, 2]) + nz[:, 2] * np.abs(dth)
        mid = self._odom[:, 2] + 0.5 * ot
        self._odom[:, 0] += np.cos(mid) * ox - np.sin(mid) * oy
        self._odom[:, 1] += np.sin(mid) * ox + np.cos(mid) * oy
        self._odom[:, 2] = _wrap(self._odom[:, 2] + ot)

    # ------------------------------------------------------------------ rangers
    def _rebuild_fans(self) -> None:
        """Flatten every robot's ranger sensors into fan tables (done when models change).

        Each sensor is one fan. A sensor with ``samples > 1`` (a laser, or part of one) gives one
        reading per beam; a single-sample sensor (a sonar transducer) is cast as a fan across its
        cone and gives one reading, the minimum of its rays. Sensors of both shapes may share a
        ranger; its readings follow the order of its sensors."""
        rob, lx, ly, lth, dth, nr, rmin, rmax, noise, every, cone = ([] for _ in range(11))
        # model, ranger index, its first fan, its first reading, its reading count
        rangers: list[tuple[_Model, int, int, int, int]] = []
        reading = 0
        dt = self.spec.interval_sim
        for m in self._robots:
            for ri, rs in enumerate(m.rangers):
                first_fan = len(rob)
                first_reading = reading
                k_every = max(1, int(round(rs.interval / dt)))
                px, py, pa = rs.pose
                cpa, spa = math.cos(pa), math.sin(pa)
                for s in rs.sensors:
                    sx, sy, sa = s.pose
                    # sensor pose in the robot frame = device mount ∘ sensor pose
                    x = px + cpa * sx - spa * sy
                    y = py + spa * sx + cpa * sy
                    a = pa + sa
                    if s.samples <= 1:
                        count = SONAR_SUBRAYS if s.fov > 0 else 1
                        step = s.fov / (count - 1) if count > 1 else 0.0
                        first = a - s.fov / 2 if count > 1 else a
                        reading += 1
                    else:
                        count = int(s.samples)
                        step = s.fov / (count - 1)
                        first = a - s.fov / 2
                        reading += count
                    rob.append(m.row)
                    lx.append(x)
                    ly.append(y)
                    lth.append(first)
                    dth.append(step)
                    nr.append(count)
                    rmin.append(s.range_min)
                    rmax.append(s.range_max)
                    noise.append(s.noise)
                    every.append(k_every)
                    cone.append(s.samples <= 1)
                rangers.append((m, ri, first_fan, first_reading, reading - first_reading))
        f = {
            "robot": np.asarray(rob, dtype=np.int64),
            "lx": np.asarray(lx, dtype=float),
            "ly": np.asarray(ly, dtype=float),
            "lth": np.asarray(lth, dtype=float),
            "dth": np.asarray(dth, dtype=float),
            "n": np.asarray(nr, dtype=np.int64),
            "rmin": np.asarray(rmin, dtype=float),
            "rmax": np.asarray(rmax, dtype=float),
            "noise": np.asarray(noise, dtype=float),
            "every": np.asarray(every, dtype=np.int64),
        }
        n = f["n"]
        f["uids"] = np.array([m.uid for m in self._robots], dtype=np.int64)
        # Readings from rays: a beam is one ray, a cone the minimum of its fan's rays.
        is_cone = np.asarray(cone, dtype=bool) & (n > 1)
        if is_cone.any():
            per_fan = np.where(is_cone, 1, n)  # readings per fan
            fan_of = np.repeat(np.arange(n.size), per_fan)
            ray0 = np.cumsum(n) - n
            local = np.arange(int(per_fan.sum())) - np.repeat(np.cumsum(per_fan) - per_fan, per_fan)
            counts = np.where(is_cone[fan_of], n[fan_of], 1)
            self._reduce = (ray0[fan_of] + local, counts)
        else:
            self._reduce = None  # every reading is one ray: readings are views of the scan
        self._fans = f
        self._ranger_slices = rangers
        self._scan_out = np.zeros(int(n.sum()), dtype=np.float32)
        self._fans_dirty = False

    def _circle_index(self) -> CircleIndex:
        """The bodies rangers see: models with ``laser_return`` in the space (not carried)."""
        _, xy = self._space_bodies(_F.BODY_ID | _F.POSITION, 2)
        seen = self._body_seen
        if not seen.any():
            return CircleIndex.empty()
        return CircleIndex(xy[seen, 0], xy[seen, 1], self._body_radius[seen], self._body_uid[seen], cell=_CIRCLE_CELL)

    def _update_rangers(self) -> None:
        if self._fans_dirty:
            self._rebuild_fans()
        f = self._fans
        if f["n"].size == 0:
            return
        due = ((self.steps - 1) % f["every"]) == 0  # every sensor scans on the first step
        if not due.any():
            return
        all_due = bool(due.all())
        idx = np.arange(due.size) if all_due else np.nonzero(due)[0]
        pose = self._prev[f["robot"][idx]]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        lx, ly = f["lx"][idx], f["ly"][idx]
        fans = {
            "x": pose[:, 0] + c * lx - s * ly,
            "y": pose[:, 1] + s * lx + c * ly,
            "th0": pose[:, 2] + f["lth"][idx],
            "dth": f["dth"][idx],
            "n": f["n"][idx],
            "rmax": f["rmax"][idx],
            "owner": f["uids"][f["robot"][idx]],
            "noise": f["noise"][idx],
            "rmin": f["rmin"][idx],
        }
        # Noise and clipping happen inside the compiled caster (deterministic per seed and step).
        ranges = cast_fans(self.grid, fans, self._circle_index(), seed=self.seed, step=self.steps).astype(np.float32)
        if all_due:
            out = ranges
        else:
            out = self._scan_out.copy()  # readings of sensors not due keep their old arrays
            out[np.repeat(due, f["n"])] = ranges
        out.flags.writeable = False
        self._scan_out = out
        vals = out if self._reduce is None else segment_min(out, *self._reduce)
        vals.flags.writeable = False  # readings are views into this tick's array
        t = self.time
        for m, ri, first_fan, r0, count in self._ranger_slices:
            if due[first_fan]:
                m.readings[ri] = RangerReading(vals[r0 : r0 + count], t, m.rangers[ri])

    # ------------------------------------------------------------------ blobfinders
    def _update_blobfinders(self) -> None:
        finders = [(m, b) for m in self._robots for b in m.blobfinders]
        if not finders:
            return
        dt = self.spec.interval_sim
        cands = [m for m in self._models.values() if m.spec.blob_return]
        if not cands:
            for _, b in finders:
                b.blobs, b.stamp = [], self.time
            return
        cxy = np.array([(m.body.position.x, m.body.position.y) for m in cands])
        crad = np.array([m.radius for m in cands])
        ccol = np.array([m.spec.color for m in cands], dtype=np.int64)
        circles = None
        for m, b in finders:
            if (self.steps - 1) % max(1, int(round(b.spec.interval / dt))):
                continue
            if circles is None:
                circles = self._circle_index()
            b.blobs = self._see_blobs(m, b.spec, cands, cxy, crad, ccol, circles)
            b.stamp = self.time

    def _see_blobs(self, m, spec, cands, cxy, crad, ccol, circles) -> list[Blob]:
        x, y, a = self._prev[m.row]
        px, py, pa = spec.pose
        ox = x + math.cos(a) * px - math.sin(a) * py
        oy = y + math.sin(a) * px + math.cos(a) * py
        oa = a + pa
        d = cxy - (ox, oy)
        rng_ = np.hypot(d[:, 0], d[:, 1])
        bearing = _wrap(np.arctan2(d[:, 1], d[:, 0]) - oa)
        half_w = np.arctan2(crad, np.maximum(rng_, 1e-6))
        self_mask = np.array([c is m for c in cands])
        if spec.colors:
            want = np.array(spec.colors, dtype=np.int64)
            colour_ok = (ccol[:, None, :] == want[None, :, :]).all(axis=2).any(axis=1)
        else:
            colour_ok = np.ones(len(cands), dtype=bool)
        ok = (
            colour_ok
            & ~self_mask
            & (rng_ <= spec.range_max)
            & (np.abs(bearing) - half_w <= spec.fov / 2)
            & (rng_ > 1e-6)
        )
        idx = np.nonzero(ok)[0]
        if idx.size == 0:
            return []
        # Occlusion: one ray to each candidate's centre; blocked if something is hit well before it.
        fans = {
            "x": np.full(idx.size, ox),
            "y": np.full(idx.size, oy),
            "th0": np.arctan2(d[idx, 1], d[idx, 0]),
            "dth": np.zeros(idx.size),
            "n": np.ones(idx.size, dtype=np.int64),
            "rmax": rng_[idx],
            "owner": np.full(idx.size, m.uid, dtype=np.int64),
        }
        hit = cast_fans(self.grid, fans, circles)
        w_px, h_px = spec.image
        fov = spec.fov
        vfov = fov * h_px / w_px
        cam_h = 0.3  # m, camera height above the floor
        blobs = []
        for j, t in zip(idx, hit, strict=True):
            visible_to = rng_[j] - crad[j] - 0.05
            if t < visible_to and not self._hit_is_target(cands[j], t, rng_[j], crad[j]):
                continue
            bx = w_px / 2 - bearing[j] / (fov / 2) * (w_px / 2)
            hw = half_w[j] / (fov / 2) * (w_px / 2)
            left, right = int(max(0, math.floor(bx - hw))), int(min(w_px - 1, math.ceil(bx + hw)))
            height = float(cands[j].spec.size[2]) or 2 * crad[j]
            top_ang = math.atan2(cam_h, rng_[j])  # angle below the horizon to the floor
            bot_ang = math.atan2(cam_h - height, rng_[j])
            ty = h_px / 2 + bot_ang / (vfov / 2) * (h_px / 2)
            by = h_px / 2 + top_ang / (vfov / 2) * (h_px / 2)
            top, bottom = int(max(0, math.floor(ty))), int(min(h_px - 1, math.ceil(by)))
            if right < left or bottom < top:
                continue
            blobs.append(
                Blob(
                    name=cands[j].spec.name,
                    color=tuple(int(v) for v in ccol[j]),  # type: ignore[arg-type]
                    x=int(round(min(max(bx, 0), w_px - 1))),
                    y=int(round((top + bottom) / 2)),
                    left=left,
                    right=right,
                    top=top,
                    bottom=bottom,
                    area=int((right - left + 1) * (bottom - top + 1)),
                    range=float(rng_[j]),
                    bearing=float(bearing[j]),
                )
            )
        blobs.sort(key=lambda b: b.range)
        return blobs

    @staticmethod
    def _hit_is_target(model: _Model, t: float, rng_: float, rad: float) -> bool:
        # A laser-visible target is itself hit at about range - radius.
        return bool(model.spec.laser_return) and t >= rng_ - rad - 0.05

    # ------------------------------------------------------------------ grippers
    def _gripper_frame(self, m: _Model, g: _Gripper) -> tuple[float, float, float]:
        x, y, a = m.body.position.x, m.body.position.y, m.body.angle
        gx, gy, _ = g.spec.pose
        return (x + math.cos(a) * gx - math.sin(a) * gy, y + math.sin(a) * gx + math.cos(a) * gy, a)

    def _update_grippers(self, dt: float) -> None:
        for m in self._robots:
            for g in m.grippers:
                self._step_gripper(m, g, dt)

    def _step_gripper(self, m: _Model, g: _Gripper, dt: float) -> None:
        spec = g.spec
        gx, gy, ga = self._gripper_frame(m, g)
        # Beams: objects with gripper_return whose centre is between the paddles.
        depth, width = spec.size
        inner = outer = False
        between: _Model | None = None
        ca, sa = math.cos(ga), math.sin(ga)
        for o in self._models.values():
            if o is m or not o.spec.gripper_return or (o.carried_by and o.carried_by != m.spec.name):
                continue
            dx, dy = o.body.position.x - gx, o.body.position.y - gy
            lx = ca * dx + sa * dy
            ly = -sa * dx + ca * dy
            if abs(ly) <= width / 2 and -depth / 2 - 0.1 <= lx <= depth / 2 + 0.1:
                if lx <= 0.0:
                    inner = True
                else:
                    outer = True
                if between is None:
                    between = o
        g.inner_beam, g.outer_beam = inner, outer
        if g.paddles in ("opening", "closing"):
            g.paddle_progress += dt
            if g.paddle_progress >= spec.paddle_time - 1e-9:
                if g.paddles == "closing":
                    g.paddles = "closed"
                    if between is not None and between.carried_by is None and g.carrying is None:
                        self._grab(m, g, between)
                else:
                    g.paddles = "open"
                    if g.carrying:
                        self._release(self._models[g.carrying])
        if g.lift in ("raising", "lowering"):
            g.lift_progress += dt
            if g.lift_progress >= spec.lift_time - 1e-9:
                g.lift = "up" if g.lift == "raising" else "down"
        if g.carrying:
            o = self._models.get(g.carrying)
            if o is None:
                g.carrying = None
            else:
                o.body.position = (gx, gy)
                o.body.angle = ga
                g.inner_beam = True
        g.stamp = self.time

    def _grab(self, m: _Model, g: _Gripper, o: _Model) -> None:
        g.carrying = o.spec.name
        o.carried_by = m.spec.name
        if o.in_space:
            self.space.remove(*o.shapes, o.body)
            o.in_space = False
            self._bodies_dirty = True

    def _release(self, o: _Model) -> None:
        holder = self._models.get(o.carried_by or "")
        if holder is not None:
            for g in holder.grippers:
                if g.carrying == o.spec.name:
                    g.carrying = None
        o.carried_by = None
        if not o.in_space:
            o.body.velocity = (0.0, 0.0)
            o.body.angular_velocity = 0.0
            self.space.add(o.body, *o.shapes)
            o.in_space = True
            self._bodies_dirty = True

    # ------------------------------------------------------------------ summary
    def describe(self) -> dict:
        """A plain summary: models, their kinds and devices (for logs and ``describe`` replies)."""
        return {
            "time": self.time,
            "interval_sim": self.spec.interval_sim,
            "robots": {
                m.spec.name: {
                    "rangers": [(r.name, r.kind, len(r.sensors)) for r in m.rangers],
                    "blobfinders": len(m.blobfinders),
                    "grippers": len(m.grippers),
                }
                for m in self._robots
            },
            "objects": [n for n, m in self._models.items() if not m.spec.position],
        }
