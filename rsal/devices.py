"""Client-side device proxies (thesis 3.6.2.3 "Device"): the names agents import.

Each proxy lives with its interface in :mod:`rsal.interfaces` (``Position2d`` in
``rsal/interfaces/position2d.py``, ...), the base :class:`Device` in ``rsal/interfaces/base.py``;
this module re-exports them, and :func:`proxy_class` reads the interface registry.
"""

from __future__ import annotations

from .interfaces import proxy_class
from .interfaces.actarray import ActArray
from .interfaces.base import Device
from .interfaces.blobfinder import Blobfinder
from .interfaces.bumper import Bumper
from .interfaces.dio import Dio
from .interfaces.fiducial import Fiducial
from .interfaces.gripper import Gripper
from .interfaces.localize import Localize
from .interfaces.map import MapDevice
from .interfaces.planner import Planner
from .interfaces.position2d import Position2d
from .interfaces.power import Power
from .interfaces.ranger import Laser, Ranger, Sonar
from .interfaces.simulation import Simulation

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
    "Dio",
    "ActArray",
    "Bumper",
    "Fiducial",
    "proxy_class",
]
