""" "Did you mean": the one nearest-name suggestion of the platform (ir-sim's unknown-key answer).

Every layer that reads names a user typed (driver configurations and their parameters in
:mod:`mrs_bridge.params`, scenario files in :mod:`agents.scenario`, algorithm parameters in
:mod:`mrs_bridge.nav.local`) answers an unknown one with the closest known name, found here with
:func:`difflib.get_close_matches` (Ratcliff/Obershelp similarity, Python's standard library).
It lives in :mod:`rsal`, the bottom layer, so every package above can import it without a cycle.
The simulator imports nothing of ours and keeps its own helper (docs/concepts.md, "Layers").
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

__all__ = ["did_you_mean"]


def did_you_mean(word: str, known: Iterable[str], *, cutoff: float = 0.6) -> str | None:
    """The known name closest to ``word``, or None if none is at least ``cutoff`` similar (0..1)."""
    close = difflib.get_close_matches(str(word), [str(k) for k in known], n=1, cutoff=cutoff)
    return close[0] if close else None
