"""Hardware rehearsal: the real ``p2os`` and ``hokuyo`` drivers serving a "real" robot before the
hardware arrives (``rsal rehearse WORLD ROBOT``, docs/hardware.md).

:mod:`.coupling` makes a robot of a simulated world the body of an emulated Pioneer and the world's
geometry the scene of an emulated Hokuyo laser (:mod:`mrs_bridge.emulators`), and steps the world
in real time; :mod:`.cli` is the command.
"""

from .coupling import COUPLINGS_KEY, RehearsalDriver, WorldLaser, WorldRobot

__all__ = ["COUPLINGS_KEY", "RehearsalDriver", "WorldLaser", "WorldRobot"]
