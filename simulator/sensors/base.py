"""The sensor plug-in protocol of the simulator, and the runtime body every plug-in reads.

A *sensor* here is everything a robot carries besides its drive: Stage's ranger, blobfinder,
gripper, bumper and fiducial models (Stage 4 ``libstage/model_*.cc``; Player's interfaces of the
same names). Each kind is one class derived from :class:`Sensor` in its own module of
:mod:`simulator.sensors`, listed once in :data:`simulator.sensors.SENSOR_TYPES`; the
:class:`~simulator.world.World` builds one instance of each and never names a kind itself.

The life of a plug-in (all calls come from the world's one thread):

* ``__init__(world)``: nothing is known yet; the world adds its models next.
* :meth:`Sensor.add` / :meth:`Sensor.remove`: a robot joins or leaves; the default reads the
  robot's specs from the :class:`~simulator.spec.ModelSpec` list field named by
  :attr:`Sensor.spec_field` and keeps one state per device from :meth:`Sensor.make`.
* :meth:`Sensor.rebuild`: called lazily before the next update whenever models were added or
  removed (robot rows renumber): rebuild flat tables here.
* :meth:`Sensor.update` ``(dt)``: once per world step, after physics and odometry; a plug-in
  decides which of its devices are due (:meth:`Sensor.due`) and computes them, batched across
  all robots.
* read accessors (``reading(name, index)``, ...) and :meth:`Sensor.describe` for
  :meth:`World.describe`.
* :meth:`Sensor.player_devices` (a class method, no world needed): the Player devices
  ``(interface, index)`` a robot with a given spec serves from this kind -- one ``<kind>:<i>`` per
  device by default. The ``sim`` driver and ``rsal sim`` build a robot's device list from it
  (:func:`simulator.sensors.player_devices`), so a new kind adds its devices by itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pymunk

from ..errors import ModelError
from ..spec import ModelSpec

if TYPE_CHECKING:
    from ..world import World

__all__ = ["Model", "Sensor", "mount", "wrap"]


def wrap(a):
    """Angles to [-pi, pi). The simulator depends on nothing of ours (docs/concepts.md, "Layers"),
    so it keeps this one line instead of importing rsal.geometry.wrap; tests/rsal/test_geometry.py
    checks that the two agree."""
    return (np.asarray(a) + math.pi) % (2.0 * math.pi) - math.pi


def mount(pose, dev) -> tuple[float, float, float]:
    """World pose of a device mounted at ``dev = (x, y, yaw)`` on a body at ``pose``."""
    x, y, a = pose
    px, py, pa = dev
    c, s = math.cos(a), math.sin(a)
    return (x + c * px - s * py, y + s * px + c * py, a + pa)


@dataclass
class Model:
    """A model at run time: its spec and its pymunk body (owned by the world)."""

    spec: ModelSpec
    uid: int  # owner id in the ray caster
    body: pymunk.Body
    shapes: list[pymunk.Shape]  # collision polygons (Stage blocks; a plain box model has one)
    radius: float  # bounding circle the rangers see
    row: int = -1  # index into the world's robot state arrays (robots only)
    carried_by: str | None = None  # name of the robot whose gripper holds this object
    in_space: bool = True

    @property
    def shape(self) -> pymunk.Shape:
        """The first collision polygon (a plain box model has only this one)."""
        return self.shapes[0]


class Sensor:
    """Base of a sensor plug-in; subclasses set the class attributes and override :meth:`update`."""

    kind: ClassVar[str] = ""  # the device kind as errors name it, e.g. "ranger"
    spec_field: ClassVar[str] = ""  # ModelSpec list field holding this kind's specs, e.g. "rangers"
    describe_key: ClassVar[str] = ""  # key of this kind in World.describe()'s robot entries

    def __init__(self, world: World):
        self.world = world
        self.devices: dict[str, list[Any]] = {}  # robot name -> device states, in spec order
        self.dirty = True

    @classmethod
    def player_devices(cls, spec: ModelSpec) -> list[tuple[str, int]]:
        """The Player devices ``(interface, index)`` a robot with ``spec`` serves from this kind:
        ``(kind, i)`` for each of its specs by default (override for aliases, as rangers do)."""
        return [(cls.kind, i) for i in range(len(getattr(spec, cls.spec_field, None) or []))]

    # ------------------------------------------------------------------ models
    def make(self, model: Model, spec: Any) -> Any:
        """The run-time state of one device from its spec (the spec itself by default)."""
        return spec

    def add(self, model: Model) -> None:
        specs = getattr(model.spec, self.spec_field, None) or []
        if specs:
            self.devices[model.spec.name] = [self.make(model, s) for s in specs]
        self.dirty = True

    def remove(self, model: Model) -> None:
        self.devices.pop(model.spec.name, None)
        self.dirty = True

    def rebuild(self) -> None:
        """Models were added or removed since the last update: rebuild flat tables."""

    # ------------------------------------------------------------------ stepping
    def step(self, dt: float) -> None:
        if self.dirty:
            self.rebuild()
            self.dirty = False
        if self.devices:
            self.update(dt)

    def update(self, dt: float) -> None:
        raise NotImplementedError

    def due(self, interval: float) -> bool:
        """Whether a device updating every ``interval`` seconds runs in the step just taken
        (every device runs on the first step)."""
        every = max(1, int(round(interval / self.world.spec.interval_sim)))
        return (self.world.steps - 1) % every == 0

    # ------------------------------------------------------------------ access
    def device(self, name: str, index: int) -> Any:
        """Device ``index`` of robot ``name``, or a :class:`ModelError` that says what exists."""
        self.world._robot(name)
        devs = self.devices.get(name, [])
        if not 0 <= index < len(devs):
            raise ModelError(f"robot {name!r} has {len(devs)} {self.kind}(s); index {index} does not exist")
        return devs[index]

    def describe(self, name: str) -> Any:
        """This kind's entry in :meth:`World.describe` for robot ``name`` (default: the count)."""
        return len(self.devices.get(name, []))


class ReadingSensor(Sensor):
    """A sensor whose devices each keep their latest reading (``None`` until the first update):
    ``self.readings[name][index]``, kept in step with the models added and removed."""

    def __init__(self, world: World):
        super().__init__(world)
        self.readings: dict[str, list[Any]] = {}

    def add(self, model: Model) -> None:
        super().add(model)
        if model.spec.name in self.devices:
            self.readings[model.spec.name] = [None] * len(self.devices[model.spec.name])

    def remove(self, model: Model) -> None:
        super().remove(model)
        self.readings.pop(model.spec.name, None)

    def reading(self, name: str, index: int) -> Any:
        """The latest reading of ``name``'s device ``index`` (errors as :meth:`device`)."""
        self.device(name, index)
        return self.readings[name][index]
