"""Hardware rehearsal: the real ``p2os`` and ``hokuyo`` drivers serving a "real" robot before the
hardware arrives (``rsal rehearse WORLD ROBOT``, docs/hardware.md).

:mod:`.coupling` makes a robot of a simulated world the body of an emulated Pioneer and the world's
geometry the scene of an emulated Hokuyo laser (:mod:`mrs_bridge.emulators`), and steps the world
in real time; :mod:`.cli` is the command.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .coupling import COUPLINGS_KEY, RehearsalDriver, WorldLaser, WorldRobot


def __getattr__(name: str):
    """The coupling is imported on first use (PEP 562): every ``rsal`` command registers ``rehearse``
    (this package's :mod:`.cli`), and the coupling's drivers would cost each process start almost
    half a second."""
    if name in __all__:
        value = getattr(importlib.import_module(".coupling", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["COUPLINGS_KEY", "RehearsalDriver", "WorldLaser", "WorldRobot"]
