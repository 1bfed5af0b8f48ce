"""Recording and playing back the fabric: ``rsal record`` and ``rsal play`` (what Player's
``writelog``/``readlog`` and ROS 2's ``rosbag2`` do), in MCAP files (https://mcap.dev).

:mod:`~rsal.record.format` (the MCAP layout: channels, metadata, times), :mod:`~rsal.record.recorder`
(:class:`Recorder`: subscriptions, one writer thread), :mod:`~rsal.record.reading` (:class:`Recording`:
indexed reads, and a sequential reader that survives a truncated file), :mod:`~rsal.record.player`
(:class:`Player`: devices re-created, samples re-published with their timing, a control
device), :mod:`~rsal.record.cli` (the two commands). ``docs/recording.md``
describes the commands and the file layout.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .cli import register
from .format import RecordingError

if TYPE_CHECKING:
    from .player import Player, PlayOptions, Recording, Sample
    from .recorder import Recorder, RecordOptions, RecordStats

# The player and the recorder are imported on first use (PEP 562): every ``rsal`` command registers
# ``record`` and ``play``, and the player's ROS 2 types would cost each process start a fifth of a
# second.
_LAZY = {
    "Player": ".player",
    "PlayOptions": ".player",
    "Recording": ".player",
    "Sample": ".player",
    "Recorder": ".recorder",
    "RecordOptions": ".recorder",
    "RecordStats": ".recorder",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Player",
    "PlayOptions",
    "Recorder",
    "RecordOptions",
    "RecordStats",
    "Recording",
    "RecordingError",
    "Sample",
    "register",
]
