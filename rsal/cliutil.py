"""Helpers the ``rsal`` sub-commands share: an argparse type for positive numbers, a stop flag
raised by SIGINT/SIGTERM (so a command stops cleanly instead of dying in the middle), and the short
form of a long list of names (:func:`brief`: a thousand robots in one line, not a thousand lines)."""

from __future__ import annotations

import argparse
import logging
import math
import re
import signal
import threading
from collections.abc import Iterable

__all__ = ["CROWD", "FirstFew", "brief", "positive", "stop_on_signals"]

#: above this many robots or agents, progress output gives one line for all, not one line each
CROWD = 10


class FirstFew:
    """Log lines of one kind -- one per robot or driver -- at their level for the first ``n``
    (:data:`CROWD`), then at debug level, with one line that says so: a crowd of a thousand robots
    gives a few examples and the totals, not a thousand lines (``-vv`` shows them all)."""

    def __init__(self, what: str, n: int = CROWD):
        self.what = what
        self.n = n
        self.count = 0
        self._lock = threading.Lock()

    def log(self, logger: logging.Logger, level: int, msg: str, *args) -> None:
        with self._lock:
            self.count += 1
            count = self.count
        if count <= self.n:
            logger.log(level, msg, *args)
            return
        if count == self.n + 1 and not logger.isEnabledFor(logging.DEBUG):
            logger.log(level, "more %s; each at debug level (-vv)", self.what)
        logger.debug(msg, *args)


_NUMBERED = re.compile(r"(.*?)(0|[1-9][0-9]*)")


def brief(names: Iterable[str], limit: int = 12) -> str:
    """``names`` in one short line: runs of a prefix with consecutive numbers as ``r0..r999``, the
    rest as they are, in the given order; beyond ``limit`` parts the first ones and the total
    (``a, b, ... (40 in all)``)."""
    parts: list[str] = []
    run: tuple[str, int, int] | None = None  # prefix, first, last
    count = 0

    def close() -> None:
        if run is not None:
            p, a, b = run
            parts.append(f"{p}{a}" if a == b else (f"{p}{a}, {p}{b}" if b == a + 1 else f"{p}{a}..{p}{b}"))

    for name in names:
        count += 1
        m = _NUMBERED.fullmatch(name)
        if m is not None and run is not None and m.group(1) == run[0] and int(m.group(2)) == run[2] + 1:
            run = (run[0], run[1], run[2] + 1)
            continue
        close()
        if m is not None:
            run = (m.group(1), int(m.group(2)), int(m.group(2)))
        else:
            run = None
            parts.append(name)
    close()
    if len(parts) > limit:
        return ", ".join(parts[: limit - 1]) + f", ... ({count} in all)"
    return ", ".join(parts)


def positive(text: str) -> float:
    """argparse type: a finite number > 0 (seconds, Hz, a speed-up ...)."""
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive number")
    return v


def stop_on_signals() -> tuple[threading.Event, list[str]]:
    """Install SIGINT/SIGTERM handlers (main thread) that set the returned event and record the
    signal's name in the returned list."""
    stop = threading.Event()
    got: list[str] = []

    def on_signal(signum, frame) -> None:
        got.append(signal.Signals(signum).name)
        stop.set()

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, on_signal)
    return stop, got
