"""The simulated world: bodies, differential drives, odometry, the simulation interface, and the
loop over the sensor plug-ins of :mod:`simulator.sensors`.

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
4. every sensor plug-in of :data:`simulator.sensors.SENSOR_TYPES` updates, in that order:
   grippers (and what they carry), rangers (lasers and sonar cones of *all* robots in one batched,
   compiled pass of :mod:`simulator.raycast`), blobfinders, bumpers, fiducial finders.

The world knows no sensor kind by name except to keep its historical read methods
(:meth:`World.ranger`, :meth:`World.blobfinder`, :meth:`World.gripper`, ...), which delegate.
The simulation interface of Player (and the thesis's ``setPositionOf`` for mixed-reality proxies)
is :meth:`World.set_pose` / :meth:`World.get_pose` by model name, :meth:`World.add_model`,
:meth:`World.remove_model`, :meth:`World.pause`, :meth:`World.step` and :meth:`World.reset`.
Runs are deterministic for a given seed when stepped. The drives' and odometry's vectorised maths
is in :mod:`simulator.drive`; what is left here (about 480 lines) is the body table shared by the
plug-ins (batched pymunk reads, circles for the ray caster) and the simulation interface.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np
import pymunk
import pymunk.batch

from .controllers import StageControllers
from .drive import Drives
from .errors import ModelError, OutOfWorld, SimulatorError
from .gridmap import GridMap
from .raycast import CircleIndex
from .sensors import SENSOR_TYPES, Sensor
from .sensors.base import Model, wrap
from .sensors.blobfinder import Blob
from .sensors.bumper import BumperReading
from .sensors.fiducial import Fiducial
from .sensors.gripper import GripperState
from .sensors.ranger import SONAR_SUBRAYS, RangerReading
from .shapes import make_shapes
from .spec import ModelSpec, RangerSpec, WorldSpec

__all__ = ["World", "RangerReading", "Blob", "BumperReading", "Fiducial", "GripperState", "SONAR_SUBRAYS"]

log = logging.getLogger(__name__)

_CIRCLE_CELL = 2.0  # m, hash-grid cell of the dynamic-body index
WORLD_MARGIN = 10.0  # m around the floorplan and the models' initial poses that set_pose accepts
_F = pymunk.batch.BodyFields
# Motor pass: per body [angle, vx, vy, w, fx, fy, torque] (pymunk's batch layout: fields in flag order).
_MOTOR_GET = _F.BODY_ID | _F.ANGLE | _F.VELOCITY | _F.ANGULAR_VELOCITY | _F.FORCE | _F.TORQUE
_MOTOR_SET = _F.VELOCITY | _F.ANGULAR_VELOCITY | _F.FORCE | _F.TORQUE
_POSE_GET = _F.BODY_ID | _F.POSITION | _F.ANGLE  # per body [x, y, angle]
_wrap = wrap


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
        self._models: dict[str, Model] = {}
        self._robots: list[Model] = []
        self._next_uid = 0
        self._circles: dict[str, CircleIndex] = {}  # per step: the bodies rays see, by flag
        self.sensors: dict[str, Sensor] = {cls.kind: cls(self) for cls in SENSOR_TYPES}
        self._add_walls()
        self.drives = Drives()
        # Batch buffers, reused: pymunk allocates one per Buffer and never frees it.
        self._get_buf = pymunk.batch.Buffer()  # reads fill its own arrays
        self._set_buf = pymunk.batch.Buffer()  # writes are handed a numpy array each time
        self._bodies_dirty = True  # the space's bodies or the robot rows changed since the last map
        self._body_ids = np.zeros(0, dtype=np.uintp)  # space's bodies, in batch order
        self._body_rows = np.zeros(0, dtype=np.int64)  # robot row of each, -1 for objects
        self._body_models: list[Model | None] = []  # model of each (None: added from outside)
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

    def _add(self, spec: ModelSpec) -> Model:
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
        model = Model(spec=spec, uid=self._next_uid, body=body, shapes=shapes, radius=radius)
        self._next_uid += 1
        self._models[spec.name] = model
        if spec.position:
            model.row = len(self._robots)
            self._robots.append(model)
            e = np.asarray(spec.odom_error, dtype=float)
            bias = self.rng.uniform(-1.0, 1.0, 3) * e
            limits = (*spec.max_speed, *spec.max_accel)
            self.drives.add((x, y, a), limits, bias, np.asarray(spec.odom_noise, dtype=float), body.mass, body.moment)
            for sensor in self.sensors.values():
                sensor.add(model)
        self._models_changed()
        return model

    def _models_changed(self) -> None:
        self._bodies_dirty = True
        self._circles = {}
        for sensor in self.sensors.values():
            sensor.dirty = True

    # ------------------------------------------------------------------ model access
    @property
    def robot_names(self) -> list[str]:
        return [m.spec.name for m in self._robots]

    @property
    def model_names(self) -> list[str]:
        return list(self._models)

    @property
    def models(self) -> dict[str, Model]:
        """Every model by name (for sensor plug-ins; do not change the dict)."""
        return self._models

    @property
    def robots(self) -> list[Model]:
        """The robots, by row (for sensor plug-ins)."""
        return self._robots

    @property
    def poses(self) -> np.ndarray:
        """``(x, y, yaw)`` of every robot by row after the last step (or :meth:`set_pose`)."""
        return self.drives.prev

    def _model(self, name: str) -> Model:
        try:
            return self._models[name]
        except KeyError:
            raise ModelError(f"no model named {name!r}; models: {', '.join(self._models) or 'none'}") from None

    def _robot(self, name: str) -> Model:
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
            self.release(m)
        b = m.body
        b.position = vals[:2]
        b.angle = vals[2]
        b.velocity = (0.0, 0.0)
        b.angular_velocity = 0.0
        if m.in_space:
            self.space.reindex_shapes_for_body(b)
        if m.row >= 0:
            self.drives.prev[m.row] = vals
            self.drives.vel[m.row] = 0.0
        self._circles = {}

    def add_model(self, spec: ModelSpec) -> None:
        """Add a robot or object while running."""
        self._add(replace(spec))

    def remove_model(self, name: str) -> None:
        """Remove a model; anything it carried is dropped where it is."""
        m = self._model(name)
        for o in list(self._models.values()):
            if o.carried_by == name:
                self.release(o)
        if m.carried_by is not None:
            self.release(m)
        for sensor in self.sensors.values():
            sensor.remove(m)
        if m.in_space:
            self.space.remove(*m.shapes, m.body)
        del self._models[name]
        if m.row >= 0:
            self.drives.remove(m.row)
            self._robots.pop(m.row)
            for i, rm in enumerate(self._robots):
                rm.row = i
        self._models_changed()

    def hold(self, o: Model, holder: str) -> None:
        """``o`` is carried by robot ``holder``: out of the physics until :meth:`release`."""
        o.carried_by = holder
        if o.in_space:
            self.space.remove(*o.shapes, o.body)
            o.in_space = False
            self._models_changed()

    def release(self, o: Model) -> None:
        """Put a carried model back into the physics where it is, at rest."""
        o.carried_by = None
        if not o.in_space:
            o.body.velocity = (0.0, 0.0)
            o.body.angular_velocity = 0.0
            self.space.add(o.body, *o.shapes)
            o.in_space = True
            self._models_changed()

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
        vmax, wmax = float(self.drives.limits[m.row, 0]), float(self.drives.limits[m.row, 1])
        self.drives.cmd[m.row] = (min(max(float(v), -vmax), vmax), min(max(float(w), -wmax), wmax))

    def halt(self, name: str) -> None:
        """Stop a robot at once, past its acceleration limits (a brake: command timeout, emergency stop)."""
        m = self._robot(name)
        self.drives.cmd[m.row] = (0.0, 0.0)
        self.drives.vel[m.row] = (0.0, 0.0)

    def velocity(self, name: str) -> tuple[float, float]:
        """The robot's current ``(v, w)`` after acceleration limits and collisions."""
        return tuple(float(x) for x in self.drives.vel[self._robot(name).row])  # type: ignore[return-value]

    def commanded_velocity(self, name: str) -> tuple[float, float]:
        return tuple(float(x) for x in self.drives.cmd[self._robot(name).row])  # type: ignore[return-value]

    def odometry(self, name: str) -> tuple[float, float, float]:
        """Odometric pose: starts at (0, 0, 0) where the robot was created and drifts."""
        o = self.drives.odom[self._robot(name).row]
        return (float(o[0]), float(o[1]), float(_wrap(o[2])))

    def set_odometry(self, name: str, x: float, y: float, yaw: float) -> None:
        """Reset the odometric pose (Player's position2d ``set_odom``)."""
        self.drives.odom[self._robot(name).row] = (float(x), float(y), float(yaw))

    def stalled(self, name: str) -> bool:
        """True when the robot is commanded to move but is blocked (Player's ``stall``)."""
        return bool(self.drives.stall[self._robot(name).row])

    # ------------------------------------------------------------------ sensors (delegating)
    def ranger(self, name: str, index: int = 0) -> RangerReading | None:
        """The latest scan of a robot's ranger ``index`` (None before the first one)."""
        return self.sensors["ranger"].reading(name, index)  # type: ignore[attr-defined]

    def rangers(self, name: str) -> list[RangerSpec]:
        self._robot(name)
        return self.sensors["ranger"].specs(name)  # type: ignore[attr-defined]

    def blobfinder(self, name: str, index: int = 0) -> list[Blob]:
        return self.sensors["blobfinder"].blobs(name, index)  # type: ignore[attr-defined]

    def gripper(self, name: str, index: int = 0) -> GripperState:
        return self.sensors["gripper"].state(name, index)  # type: ignore[attr-defined]

    def gripper_command(self, name: str, command: str, index: int = 0) -> None:
        """``open``, ``close``, ``up``, ``down`` or ``stop`` (Player's gripper/actarray commands)."""
        self.sensors["gripper"].command(name, command, index)  # type: ignore[attr-defined]

    def bumper(self, name: str, index: int = 0) -> BumperReading | None:
        """The latest reading of a robot's bumper ring ``index`` (None before the first one)."""
        return self.sensors["bumper"].reading(name, index)  # type: ignore[attr-defined]

    def fiducial(self, name: str, index: int = 0) -> list[Fiducial]:
        """What a robot's fiducial finder ``index`` saw in its last update, nearest first."""
        return self.sensors["fiducial"].seen(name, index)  # type: ignore[attr-defined]

    def circles(self, flag: str = "laser_return") -> CircleIndex:
        """The bodies in the space whose ``flag`` is set, as circles for the ray caster (built
        once per step and flag: rangers and blobfinders see ``laser_return``, bumpers
        ``obstacle_return``)."""
        c = self._circles.get(flag)
        if c is None:
            models, xy = self.space_poses()
            seen = (
                self._body_seen
                if flag == "laser_return"
                else np.array([bool(m and getattr(m.spec, flag)) for m in models], dtype=bool)
            )
            if not seen.any():
                c = CircleIndex.empty()
            else:
                c = CircleIndex(
                    xy[seen, 0], xy[seen, 1], self._body_radius[seen], self._body_uid[seen], cell=_CIRCLE_CELL
                )
            self._circles[flag] = c
        return c

    def space_poses(self) -> tuple[list[Model | None], np.ndarray]:
        """Every body in the space in one batched read: its model (None for a body added from
        outside the world) and its ``(x, y, angle)``. The list is the same object until bodies
        are added or removed, so plug-ins may cache what they derive from it by identity."""
        _, vals = self._space_bodies(_POSE_GET, 3)
        return self._body_models, vals

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
            self.drives.accelerate(dt)  # 1. acceleration-limited velocity towards the command
        # 2. physics.
        h = dt / self.substeps
        for k in range(self.substeps):
            if n:
                self._run_motors(h, first=k == 0)
            self.space.step(h)
        self.time = (self.steps + 1) * dt
        self.steps += 1
        if n:
            self.drives.odometry(self._robot_poses(), dt, self.rng)  # 3.
        self._circles = {}
        # 4. sensors (and the grippers' actuators), in the order of SENSOR_TYPES.
        for sensor in self.sensors.values():
            sensor.step(dt)

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
            self._body_models = ms
            self._body_rows = np.array([m.row if m else -1 for m in ms], dtype=np.int64)
            self._body_seen = np.array([bool(m and m.spec.laser_return) for m in ms], dtype=bool)
            self._body_radius = np.array([m.radius if m else 0.0 for m in ms], dtype=float)
            self._body_uid = np.array([m.uid if m else -1 for m in ms], dtype=np.int64)
            self._body_ids = ids.copy()
            self._bodies_dirty = False
        vals = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(ids.size, width)
        return self._body_rows, vals

    def _run_motors(self, h: float, first: bool) -> None:
        """Drive every robot body for one pymunk sub-step of ``h`` seconds, in one batched pass
        (the motor maths is :meth:`simulator.drive.Drives.motors`)."""
        rows, b = self._space_bodies(_MOTOR_GET, 7)
        self._set_buf.set_float_buf(self.drives.motors(b, rows, h, self.space.damping, first))
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

    # ------------------------------------------------------------------ summary
    def describe(self) -> dict:
        """A plain summary: models, their kinds and devices (for logs and ``describe`` replies)."""
        return {
            "time": self.time,
            "interval_sim": self.spec.interval_sim,
            "robots": {
                m.spec.name: {key: s.describe(m.spec.name) for key, s in self._describers()} for m in self._robots
            },
            "objects": [n for n, m in self._models.items() if not m.spec.position],
        }

    def _describers(self) -> list[tuple[str, Sensor]]:
        return [(s.describe_key, s) for s in self.sensors.values() if s.describe_key]
