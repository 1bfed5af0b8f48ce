"""Load a world file of either supported format into a :class:`~simulator.spec.WorldSpec`.

Dispatches on the file suffix: ``.world`` and ``.inc`` are Stage world files (thesis appendix
A.1, A.5, A.6; :mod:`simulator.stageworld`), ``.yaml`` and ``.yml`` the project's YAML format
(:mod:`simulator.yamlworld`). Every problem is a :class:`~simulator.errors.WorldFileError`.
"""

from __future__ import annotations

import os
from pathlib import Path

from .errors import WorldFileError
from .spec import WorldSpec
from .stageworld import load_stage_world
from .yamlworld import load_yaml_world

__all__ = ["SUFFIXES", "load_world"]

SUFFIXES = {".world": "stage", ".inc": "stage", ".yaml": "yaml", ".yml": "yaml"}
"""Supported file suffixes and their format."""


def load_world(path: str | os.PathLike[str], *, seed: int | None = None) -> WorldSpec:
    """Load ``path`` as a Stage world (``.world``/``.inc``) or a YAML world (``.yaml``/``.yml``).

    ``seed`` overrides the seed the file sets. Raises :class:`WorldFileError` for a missing file,
    an unsupported suffix or malformed content (naming file:line and a fix).
    """
    display = os.fspath(path)
    p = Path(display)
    fmt = SUFFIXES.get(p.suffix.lower())
    if fmt is None:
        raise WorldFileError(
            f"unsupported world file type {p.suffix or '(no suffix)'!r}; use a Stage world "
            "(.world, .inc) or a YAML world (.yaml, .yml)",
            display,
        )
    try:
        exists = p.is_file()
    except (OSError, ValueError):
        exists = False
    if not exists:
        what = "is a directory, not a world file" if _is_dir(p) else "no such world file; check the path"
        raise WorldFileError(what, display)
    if fmt == "stage":
        return load_stage_world(display, seed=seed)
    return load_yaml_world(display, seed=seed)


def _is_dir(p: Path) -> bool:
    try:
        return p.is_dir()
    except (OSError, ValueError):
        return False
