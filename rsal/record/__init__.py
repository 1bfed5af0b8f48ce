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

from .cli import register
from .format import RecordingError
from .player import Player, PlayOptions, Recording, Sample
from .recorder import Recorder, RecordOptions, RecordStats

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
