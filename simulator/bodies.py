"""The bodies of a simulated world: the pymunk space, its walls, the model table and batched reads.

Stage keeps one model tree and a world of blocks (Stage 4 ``libstage/world.cc``, ``model.cc``,
read for meaning); here the physics is pymunk's. :class:`Bodies` owns what the
:class:`~simulator.world.World` and its sensor plug-ins share about bodies:

* the :class:`pymunk.Space` (damping, iterations, a slop in metres) with the floorplan's occupied
  cells merged into static boxes (:meth:`~simulator.gridmap.GridMap.rectangles`);
* the model table: every :class:`~simulator.sensors.base.Model` by name and the robots by row;
  model construction from a :class:`~simulator.spec.ModelSpec` (Stage blocks via
  :func:`simulator.shapes.make_shapes`), removal, and taking a carried model out of the physics;
* batched reads and writes of all bodies through ``pymunk.batch`` (one call per step, not one per
  body): poses, the motor pass of :meth:`simulator.drive.Drives.motors`, the robots' poses for
  odometry, and the circles the ray caster of :mod:`simulator.raycast` sees, built once per step
  and flag.
* the contact counter (:meth:`Bodies.contacts`): every time a robot starts touching a wall or
  another robot, in any physics substep, pymunk's ``begin`` callback counts it (Python runs once per
  new contact, not per step), so a verdict of "no contact" rests on every step, not on samples.
"""

from __future__ import annotations

import numpy as np
import pymunk
import pymunk.batch

from .drive import Drives
from .errors import ModelError
from .gridmap import GridMap
from .raycast import CircleIndex
from .sensors.base import Model
from .shapes import make_shapes
from .spec import ModelSpec

__all__ = ["Bodies"]

_CIRCLE_CELL = 2.0  # m, hash-grid cell of the dynamic-body index
_F = pymunk.batch.BodyFields
# Motor pass: per body [angle, vx, vy, w, fx, fy, torque] (pymunk's batch layout: fields in flag order).
_MOTOR_GET = _F.BODY_ID | _F.ANGLE | _F.VELOCITY | _F.ANGULAR_VELOCITY | _F.FORCE | _F.TORQUE
_MOTOR_SET = _F.VELOCITY | _F.ANGULAR_VELOCITY | _F.FORCE | _F.TORQUE
_POSE_GET = _F.BODY_ID | _F.POSITION | _F.ANGLE  # per body [x, y, angle]
# pymunk collision types: what a contact is between (Bodies.contacts)
_WALL, _ROBOT = 1, 2


class Bodies:
    """The space, walls and model table of one world (one thread, like the world)."""

    def __init__(self, grid: GridMap | None):
        self.space = pymunk.Space()
        self.space.damping = 0.2  # passive objects slow down (robots are driven every step)
        self.space.iterations = 10
        self.space.collision_slop = 0.002  # m: pymunk's default (0.1) is meant for pixels
        self.models: dict[str, Model] = {}
        self.robots: list[Model] = []
        self._next_uid = 0
        self._circles: dict[str, CircleIndex] = {}  # per step: the bodies rays see, by flag
        self.wall_count = self._add_walls(grid)
        self._owner: dict[pymunk.Body, str] = {}  # robot bodies -> robot name (contact counting)
        self.robot_contacts = 0  # a robot began touching another robot (each pair once per contact)
        self.wall_contacts = 0  # a robot began touching a wall
        self.touched: dict[str, list[int]] = {}  # robot -> [robot contacts, wall contacts]
        self.space.on_collision(_ROBOT, _ROBOT, begin=self._robot_robot)
        self.space.on_collision(_ROBOT, _WALL, begin=self._robot_wall)
        # Batch buffers, reused: pymunk allocates one per Buffer and never frees it.
        self._get_buf = pymunk.batch.Buffer()  # reads fill its own arrays
        self._set_buf = pymunk.batch.Buffer()  # writes are handed a numpy array each time
        self._dirty = True  # the space's bodies or the robot rows changed since the last map
        self._ids = np.zeros(0, dtype=np.uintp)  # space's bodies, in batch order
        self._rows = np.zeros(0, dtype=np.int64)  # robot row of each, -1 for objects
        self._models: list[Model | None] = []  # model of each (None: added from outside)
        self._seen = np.zeros(0, dtype=bool)  # has laser_return: rangers see it as a circle
        self._radius = np.zeros(0)  # m, that circle's radius
        self._uid = np.zeros(0, dtype=np.int64)  # owner id in the ray caster

    def _add_walls(self, grid: GridMap | None) -> int:
        if grid is None:
            return 0
        body = self.space.static_body
        shapes = []
        r = grid.resolution
        x0, y0 = grid.origin
        for ix0, iy0, ix1, iy1 in grid.rectangles():
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
            box.collision_type = _WALL
            shapes.append(box)
        self.space.add(*shapes)
        return len(shapes)

    # ------------------------------------------------------------------ the model table
    def add(self, spec: ModelSpec) -> Model:
        """A body with its shapes for ``spec`` in the space, in the table (a robot gets a row)."""
        if spec.name in self.models:
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
            if spec.position:
                shape.collision_type = _ROBOT
        self.space.add(body, *shapes)
        if spec.position:
            self._owner[body] = spec.name
        model = Model(spec=spec, uid=self._next_uid, body=body, shapes=shapes, radius=radius)
        self._next_uid += 1
        self.models[spec.name] = model
        if spec.position:
            model.row = len(self.robots)
            self.robots.append(model)
        self.changed()
        return model

    def remove(self, m: Model) -> None:
        """Take ``m`` out of the space and the table; the robots after it move up a row."""
        if m.in_space:
            self.space.remove(*m.shapes, m.body)
        self._owner.pop(m.body, None)
        del self.models[m.spec.name]
        if m.row >= 0:
            self.robots.pop(m.row)
            for i, rm in enumerate(self.robots):
                rm.row = i
        self.changed()

    # ------------------------------------------------------------------ contacts
    def _touch(self, arbiter: pymunk.Arbiter, kind: int) -> list[str]:
        a, b = arbiter.shapes
        if a.sensor or b.sensor:  # a model without obstacle_return touches nothing
            return []
        names = [n for n in (self._owner.get(a.body), self._owner.get(b.body)) if n is not None]
        for n in names:
            self.touched.setdefault(n, [0, 0])[kind] += 1
        return names

    def _robot_robot(self, arbiter: pymunk.Arbiter, space, data) -> None:
        if self._touch(arbiter, 0):
            self.robot_contacts += 1

    def _robot_wall(self, arbiter: pymunk.Arbiter, space, data) -> None:
        if self._touch(arbiter, 1):
            self.wall_contacts += 1

    def contacts(self) -> dict:
        """The contacts since the world was built: ``robot_robot`` (pairs of robots that began
        touching), ``robot_wall`` (a robot began touching a wall) and ``robots``: for each robot that
        touched anything, ``[robot contacts, wall contacts]``. A contact that lasts counts once."""
        return {
            "robot_robot": self.robot_contacts,
            "robot_wall": self.wall_contacts,
            "robots": {k: list(v) for k, v in sorted(self.touched.items())},
        }

    def take_out(self, m: Model) -> bool:
        """Take ``m`` out of the physics (carried by a gripper); whether it was in."""
        if not m.in_space:
            return False
        self.space.remove(*m.shapes, m.body)
        m.in_space = False
        self.changed()
        return True

    def put_back(self, m: Model) -> bool:
        """Put ``m`` back into the physics where it is, at rest; whether it was out."""
        if m.in_space:
            return False
        m.body.velocity = (0.0, 0.0)
        m.body.angular_velocity = 0.0
        self.space.add(m.body, *m.shapes)
        m.in_space = True
        self.changed()
        return True

    def changed(self) -> None:
        """Bodies were added or removed: map the batch order again on the next read."""
        self._dirty = True
        self._circles = {}

    def moved(self) -> None:
        """Bodies moved (a step, a teleport): the circles of the ray caster are stale."""
        self._circles = {}

    # ------------------------------------------------------------------ batched reads
    def read(self, fields, width: int) -> tuple[np.ndarray, np.ndarray]:
        """Every body in the space in one batched read: ``(rows, values)`` with ``rows[i]`` the
        robot row of body ``i`` (-1 for an object) and ``values[i]`` its ``width`` floats."""
        buf = self._get_buf
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, fields, buf)
        ids = np.frombuffer(buf.int_buf(), dtype=np.uintp)
        if self._dirty or not np.array_equal(ids, self._ids):
            # Bodies were added or removed (pymunk reorders its list on removal): map them again.
            model_of = {m.body.id: m for m in self.models.values()}
            ms = [model_of.get(int(i)) for i in ids]  # None: a body added to the space from outside
            self._models = ms
            self._rows = np.array([m.row if m else -1 for m in ms], dtype=np.int64)
            self._seen = np.array([bool(m and m.spec.laser_return) for m in ms], dtype=bool)
            self._radius = np.array([m.radius if m else 0.0 for m in ms], dtype=float)
            self._uid = np.array([m.uid if m else -1 for m in ms], dtype=np.int64)
            self._ids = ids.copy()
            self._dirty = False
        vals = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(ids.size, width)
        return self._rows, vals

    def space_poses(self) -> tuple[list[Model | None], np.ndarray]:
        """Every body in the space: its model (None for a body added from outside the world) and
        its ``(x, y, angle)``. The list is the same object until bodies are added or removed, so
        plug-ins may cache what they derive from it by identity."""
        _, vals = self.read(_POSE_GET, 3)
        return self._models, vals

    def circles(self, flag: str = "laser_return") -> CircleIndex:
        """The bodies in the space whose ``flag`` is set, as circles for the ray caster (built
        once per step and flag)."""
        c = self._circles.get(flag)
        if c is None:
            models, xy = self.space_poses()
            seen = (
                self._seen
                if flag == "laser_return"
                else np.array([bool(m and getattr(m.spec, flag)) for m in models], dtype=bool)
            )
            if not seen.any():
                c = CircleIndex.empty()
            else:
                c = CircleIndex(xy[seen, 0], xy[seen, 1], self._radius[seen], self._uid[seen], cell=_CIRCLE_CELL)
            self._circles[flag] = c
        return c

    def run_motors(self, drives: Drives, h: float, first: bool) -> None:
        """Drive every robot body for one pymunk sub-step of ``h`` seconds, in one batched pass
        (the motor maths is :meth:`simulator.drive.Drives.motors`)."""
        rows, b = self.read(_MOTOR_GET, 7)
        self._set_buf.set_float_buf(drives.motors(b, rows, h, self.space.damping, first))
        pymunk.batch.set_space_bodies(self.space, _MOTOR_SET, self._set_buf)

    def robot_poses(self) -> np.ndarray:
        """``(x, y, angle)`` of every robot, by row, in one batched read."""
        rows, b = self.read(_POSE_GET, 3)
        pose = np.empty((len(self.robots), 3))
        r = rows >= 0
        pose[rows[r]] = b[r]
        if r.sum() < len(self.robots):  # a robot held by a gripper is out of the space
            for m in self.robots:
                if not m.in_space:
                    pose[m.row] = (m.body.position.x, m.body.position.y, m.body.angle)
        return pose
