"""A Stage-like 2.5D multi-robot simulator (thesis 2.2.1, 3.4.2, appendix A.1, A.4-A.6).

A library with no dependency on the rest of the project: bitmap floorplans, pymunk bodies for
robots and objects, differential-drive position models with drifting odometry, laser and sonar
rangers, blobfinders and grippers computed for all robots in one vectorised pass per tick,
batteries that drain with motion and charge at chargers (:mod:`simulator.energy`), a
fixed-step clock, and loaders for Stage ``.world`` files and a YAML world format.
"""

from .errors import ModelError, OutOfWorld, SimulatorError, WorldFileError
from .loader import load_world
from .spec import (
    BatterySpec,
    BlobfinderSpec,
    ChargerSpec,
    FloorplanSpec,
    GripperSpec,
    ModelSpec,
    RangerSensorSpec,
    RangerSpec,
    WorldSpec,
)

__all__ = [
    "BatterySpec",
    "BlobfinderSpec",
    "ChargerSpec",
    "FloorplanSpec",
    "GripperSpec",
    "ModelError",
    "OutOfWorld",
    "ModelSpec",
    "RangerSensorSpec",
    "RangerSpec",
    "SimulatorError",
    "WorldFileError",
    "WorldSpec",
    "load_world",
]
