"""The simulator's sensor plug-ins: one module per Stage/Player device kind.

Each module defines one :class:`~simulator.sensors.base.Sensor` subclass (the protocol is drawn
in :mod:`simulator.sensors.base`) and its reading types. :data:`SENSOR_TYPES` lists them in the
order the world updates them each step: grippers first (they move what they carry), then the
sensors that look at the world. Adding a kind = a spec in :mod:`simulator.spec`, a module here,
one line in :data:`SENSOR_TYPES` (see docs/simulator.md, "Adding a sensor"). The Player devices a
robot serves come from its sensors too (:func:`player_devices`).
"""

from __future__ import annotations

from dataclasses import fields

from ..spec import ModelSpec
from .base import Model, Sensor
from .blobfinder import Blob, Blobfinders
from .bumper import BumperReading, Bumpers
from .fiducial import Fiducial, Fiducials
from .gripper import Grippers, GripperState
from .ranger import SONAR_SUBRAYS, RangerReading, Rangers

__all__ = [
    "SENSOR_TYPES",
    "SONAR_SUBRAYS",
    "Blob",
    "Blobfinders",
    "BumperReading",
    "Bumpers",
    "Fiducial",
    "Fiducials",
    "GripperState",
    "Grippers",
    "Model",
    "RangerReading",
    "Rangers",
    "Sensor",
    "player_devices",
]

SENSOR_TYPES: tuple[type[Sensor], ...] = (Grippers, Rangers, Blobfinders, Bumpers, Fiducials)


def player_devices(spec: ModelSpec) -> list[tuple[str, int]]:
    """Every Player device ``(interface, index)`` the sensors of a robot with ``spec`` serve, kind
    by kind in the order :class:`~simulator.spec.ModelSpec` declares its device lists (rangers,
    blobfinders, grippers, bumpers, fiducials), each kind's own order within."""
    order = {f.name: i for i, f in enumerate(fields(ModelSpec))}
    out: list[tuple[str, int]] = []
    for cls in sorted(SENSOR_TYPES, key=lambda c: order.get(c.spec_field, len(order))):
        out += cls.player_devices(spec)
    return out
