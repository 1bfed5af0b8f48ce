"""Helpers the ``rsal`` sub-commands share: an argparse type for positive numbers and a stop flag
raised by SIGINT/SIGTERM (so a command stops cleanly instead of dying in the middle)."""

from __future__ import annotations

import argparse
import math
import signal
import threading

__all__ = ["positive", "stop_on_signals"]


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
