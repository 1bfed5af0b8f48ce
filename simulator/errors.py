"""Exceptions of the simulator.

::

    SimulatorError            anything the simulator refuses
    ├── WorldFileError        a world file (or a file it includes) is malformed: names file:line
    └── ModelError            an operation names a model that does not exist or cannot do it
        └── OutOfWorld        a pose outside the world's bounds

Every message is one line that names the place and says how to fix it; command-line tools print
``str(error)`` and exit 1, never a traceback. :func:`did_you_mean` is the simulator's one
"did you mean" for a misspelt name (keywords, keys, model types, presets).
"""

from __future__ import annotations

import difflib
import logging
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

__all__ = ["SimulatorError", "WorldFileError", "ModelError", "OutOfWorld", "as_world_file_errors", "did_you_mean"]

log = logging.getLogger(__name__)


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


class OutOfWorld(ModelError):
    """A pose outside the world's bounds (the floorplan and initial poses plus a margin)."""


@contextmanager
def as_world_file_errors(display: str, too_deep: str) -> Iterator[None]:
    """Every failure while building a world from ``display`` becomes one :class:`WorldFileError`:
    too deep nesting says ``too_deep``; anything unexpected (a loader bug) is still reported as a
    world file problem, with the details in the debug log, never as a traceback."""
    try:
        yield
    except WorldFileError:
        raise
    except RecursionError:
        raise WorldFileError(too_deep, display) from None
    except Exception as e:
        log.debug("internal error loading %s", display, exc_info=True)
        raise WorldFileError(
            f"internal error while loading ({type(e).__name__}: {e}); please report it", display
        ) from e


def did_you_mean(word: str, known: Iterable[str], *, cutoff: float = 0.6) -> str:
    """``"did you mean 'x'?"`` for the known name closest to ``word`` (difflib), else ``""``."""
    close = difflib.get_close_matches(str(word), list(known), n=1, cutoff=cutoff)
    return f"did you mean '{close[0]}'?" if close else ""
