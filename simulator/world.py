"""The simulated world: bodies, differential drives, odometry, the simulation interface, and the
loop over the sensor plug-ins of :mod:`simulator.sensors`.

This plays Stage's role (thesis 2.2.1, appendix A.1, A.4-A.6). A :class:`World` is built from a
:class:`~simulator.spec.WorldSpec` and advanced in fixed steps of ``interval_sim`` seconds
(Stage's ``interval_sim``, 100 ms by default). Each step:

1. every robot's velocity approaches its commanded ``(v, w)`` within its acceleration and speed
   limits (Player's position2d velocity command);
2. pymunk moves the bodies: before each sub-step the motors of all robots are applied in one
   vectorised pass through pymunk's batch interface (:meth:`simulator.bodies.Bodies.run_motors`);
   robots collide with the floorplan's walls (static boxes merged from the bitmap's occupied
   cells), with each other, and push objects that have ``obstacle_return``;
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
is in :mod:`simulator.drive`; the pymunk space, the model table and the batched body reads the
plug-ins share (poses, circles for the ray caster) in :mod:`simulator.bodies`. What is left here is
the world's core: building from a spec, stepping, and the simulation and robot interfaces.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

from .bodies import Bodies
from .controllers import StageControllers
from .drive import Drives
from .energy import Batteries, BatteryState
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
from .spec import ModelSpec, RangerSpec, WorldSpec

__all__ = [
    "World",
    "BatteryState",
    "RangerReading",
    "Blob",
    "BumperReading",
    "Fiducial",
    "GripperState",
    "SONAR_SUBRAYS",
]

log = logging.getLogger(__name__)

WORLD_MARGIN = 10.0  # m around the floorplan and the models' initial poses that set_pose accepts
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
        self._check_chargers()
        self._build()

    def _check_chargers(self) -> None:
        """A charger must stand on the floorplan (anywhere, without one)."""
        if self.grid is None:
            return
        x0, x1, y0, y1 = self.grid.extent
        for c in self.spec.chargers:
            x, y = c.pose[0], c.pose[1]
            if not (x0 <= x <= x1 and y0 <= y <= y1):
                at = f"{c.source}: " if c.source else ""
                raise ModelError(
                    f"{at}charger {c.name!r} at ({x:g}, {y:g}) is outside the map; put it within "
                    f"x [{x0:g}, {x1:g}] and y [{y0:g}, {y1:g}] m"
                )

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
        self.bodies = Bodies(self.grid)
        self.space = self.bodies.space
        self.sensors: dict[str, Sensor] = {cls.kind: cls(self) for cls in SENSOR_TYPES}
        self.drives = Drives()
        self.batteries = Batteries(self.spec.chargers)
        for m in self.spec.models:
            self._add(m)
        self.controllers = StageControllers(self.spec.models, self.seed)

    def _add(self, spec: ModelSpec) -> Model:
        model = self.bodies.add(spec)
        if spec.position:
            x, y, a = spec.pose
            e = np.asarray(spec.odom_error, dtype=float)
            bias = self.rng.uniform(-1.0, 1.0, 3) * e
            limits = (*spec.max_speed, *spec.max_accel)
            b = model.body
            self.drives.add((x, y, a), limits, bias, np.asarray(spec.odom_noise, dtype=float), b.mass, b.moment)
            self.batteries.add(spec.battery)
            for sensor in self.sensors.values():
                sensor.add(model)
        self._models_changed()
        return model

    def _models_changed(self) -> None:
        self.bodies.changed()
        for sensor in self.sensors.values():
            sensor.dirty = True

    # ------------------------------------------------------------------ model access
    @property
    def robot_names(self) -> list[str]:
        return [m.spec.name for m in self.bodies.robots]

    @property
    def model_names(self) -> list[str]:
        return list(self.bodies.models)

    @property
    def models(self) -> dict[str, Model]:
        """Every model by name (for sensor plug-ins; do not change the dict)."""
        return self.bodies.models

    @property
    def robots(self) -> list[Model]:
        """The robots, by row (for sensor plug-ins)."""
        return self.bodies.robots

    @property
    def poses(self) -> np.ndarray:
        """``(x, y, yaw)`` of every robot by row after the last step (or :meth:`set_pose`)."""
        return self.drives.prev

    def _model(self, name: str) -> Model:
        try:
            return self.bodies.models[name]
        except KeyError:
            raise ModelError(f"no model named {name!r}; models: {', '.join(self.bodies.models) or 'none'}") from None

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
        self.bodies.moved()

    def add_model(self, spec: ModelSpec) -> None:
        """Add a robot or object while running."""
        self._add(replace(spec))

    def remove_model(self, name: str) -> None:
        """Remove a model; anything it carried is dropped where it is."""
        m = self._model(name)
        for o in list(self.bodies.models.values()):
            if o.carried_by == name:
                self.release(o)
        if m.carried_by is not None:
            self.release(m)
        for sensor in self.sensors.values():
            sensor.remove(m)
        if m.row >= 0:
            self.drives.remove(m.row)
            self.batteries.remove(m.row)
        self.bodies.remove(m)
        self._models_changed()

    def hold(self, o: Model, holder: str) -> None:
        """``o`` is carried by robot ``holder``: out of the physics until :meth:`release`."""
        o.carried_by = holder
        if self.bodies.take_out(o):
            self._models_changed()

    def release(self, o: Model) -> None:
        """Put a carried model back into the physics where it is, at rest."""
        o.carried_by = None
        if self.bodies.put_back(o):
            self._models_changed()

    def contacts(self) -> dict:
        """Every contact of a robot with a wall or another robot since the world was built or reset,
        counted in every physics substep (:meth:`simulator.bodies.Bodies.contacts`)."""
        return self.bodies.contacts()

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

    # ------------------------------------------------------------------ energy
    def battery(self, name: str) -> BatteryState:
        """A robot's battery after the last step (:mod:`simulator.energy`)."""
        return self.batteries.state(self._robot(name).row)

    def battery_fraction(self, name: str) -> float:
        """A robot's charge as a fraction of its capacity (1.0 without a battery model): what
        :meth:`battery` reports as ``fraction``, without building the whole state."""
        return self.batteries.fraction(self._robot(name).row)

    def set_battery(self, name: str, fraction: float) -> None:
        """Set a robot's charge to ``fraction`` of its capacity (0..1)."""
        if not math.isfinite(fraction):
            raise ModelError(f"set_battery({name!r}): fraction {fraction!r} must be a number between 0 and 1")
        self.batteries.set_fraction(self._robot(name).row, fraction)

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
        return self.bodies.circles(flag)

    def space_poses(self) -> tuple[list[Model | None], np.ndarray]:
        """Every body in the space in one batched read: its model (None for a body added from
        outside the world) and its ``(x, y, angle)``; see :meth:`Bodies.space_poses`."""
        return self.bodies.space_poses()

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
        n = len(self.bodies.robots)
        if n:
            empty = self.batteries.empty  # an empty battery refuses to move (energy.py)
            if empty.any():
                self.drives.cmd[empty] = 0.0
                self.drives.vel[empty] = 0.0
            self.drives.accelerate(dt)  # 1. acceleration-limited velocity towards the command
        # 2. physics.
        h = dt / self.substeps
        for k in range(self.substeps):
            if n:
                self.bodies.run_motors(self.drives, h, first=k == 0)
            self.space.step(h)
        self.time = (self.steps + 1) * dt
        self.steps += 1
        if n:
            prev = self.drives.prev
            pose = self.bodies.robot_poses()
            self.drives.odometry(pose, dt, self.rng)  # 3.
            self.batteries.step(prev, pose, dt)  # 3b. energy: drain by the true motion, charge when docked
        self.bodies.moved()
        # 4. sensors (and the grippers' actuators), in the order of SENSOR_TYPES.
        for sensor in self.sensors.values():
            sensor.step(dt)

    # ------------------------------------------------------------------ summary
    def describe(self) -> dict:
        """A plain summary: models, their kinds and devices (for logs and ``describe`` replies)."""
        return {
            "time": self.time,
            "interval_sim": self.spec.interval_sim,
            "robots": {
                m.spec.name: {key: s.describe(m.spec.name) for key, s in self._describers()} for m in self.bodies.robots
            },
            "objects": [n for n, m in self.bodies.models.items() if not m.spec.position],
        }

    def _describers(self) -> list[tuple[str, Sensor]]:
        return [(s.describe_key, s) for s in self.sensors.values() if s.describe_key]
