"""Client-side device proxies (thesis 3.6.2.3 "Device"): the names agents import.

Each proxy lives with its interface in :mod:`rsal.interfaces` (``Position2d`` in
``rsal/interfaces/position2d.py``, ...), the base :class:`Device` in ``rsal/interfaces/base.py``;
this module re-exports the names it had, and :func:`proxy_class` reads the interface registry
(a new interface's proxy needs no line here: import it from its module).
"""

from __future__ import annotations

from .interfaces import proxy_class
from .interfaces.actarray import ActArray
from .interfaces.base import Device
from .interfaces.blobfinder import Blobfinder
from .interfaces.dio import Dio
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
    "proxy_class",
]
