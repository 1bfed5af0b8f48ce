"""Exceptions of the simulator.

::

    SimulatorError            anything the simulator refuses
    ├── WorldFileError        a world file (or a file it includes) is malformed: names file:line
    └── ModelError            an operation names a model that does not exist or cannot do it

Every message is one line that names the place and says how to fix it; command-line tools print
``str(error)`` and exit 1, never a traceback.
"""

from __future__ import annotations

__all__ = ["SimulatorError", "WorldFileError", "ModelError"]


class SimulatorError(Exception):
    """Base class of the simulator's errors."""


class WorldFileError(SimulatorError):
    """A world file cannot be loaded. ``str()`` is ``"file:line: message"``."""

    def __init__(self, message: str, file: str = "", line: int = 0):
        self.file = str(file)
        self.line = int(line)
        self.message = message
        where = f"{self.file}:{self.line}: " if self.file and self.line else (f"{self.file}: " if self.file else "")
        super().__init__(f"{where}{message}")


class ModelError(SimulatorError):
    """An operation on a model that does not exist or does not support it."""
