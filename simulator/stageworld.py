"""Loader for Stage ``.world`` files: the entry point of :mod:`simulator.stage`.

Reads a Stage 3/4 world file (and the files it includes) into a
:class:`~simulator.spec.WorldSpec` with Stage 4's meaning; the lexer/parser, macro expansion and
mapping live in the :mod:`simulator.stage` package, one module each. This module keeps the public
names other code imports: :func:`load_stage_world` and :data:`INCLUDE_DIR`.

Include files are looked up next to the including file, then in each directory of the
``STAGEPATH`` environment variable (colon-separated), then in :data:`INCLUDE_DIR`.
"""

from __future__ import annotations

import os
from pathlib import Path

from .spec import WorldSpec
from .stage import load

__all__ = ["INCLUDE_DIR", "load_stage_world"]

INCLUDE_DIR = Path(__file__).resolve().parent.parent / "maps" / "include"
"""The project's own include files (``pioneer.inc``, ``map.inc``, ...), searched last."""


def load_stage_world(path: str | os.PathLike[str], *, seed: int | None = None) -> WorldSpec:
    """Read a Stage ``.world`` (or ``.inc``) file and the files it includes into a WorldSpec.

    ``seed`` overrides the world's ``seed`` keyword. Raises :class:`WorldFileError` (naming
    file:line and a fix) for any malformed input; warnings are in ``WorldSpec.warnings``.
    """
    return load(path, include_dirs=[INCLUDE_DIR], seed=seed)
