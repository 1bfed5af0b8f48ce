"""Loader of Stage ``.world`` files: Stage 3/4 world-file syntax with Stage 4's meaning.

Implements the world and include file syntax of Stage (the thesis uses it in appendix A.1
``devices.inc``, A.5 ``urg.inc``, A.6 ``utm30lx.inc``) and turns it into a
:class:`~simulator.spec.WorldSpec`. The code is written for this project from Stage's documentation
and source (read for meaning; it shares no code with Stage, which is GPL). Three stages, one module
each:

* :mod:`~simulator.stage.syntax`: lexer and parser, tokens and a syntax tree with file:line;
* :mod:`~simulator.stage.macros`: ``include``, ``define`` and inheritance, giving model instances;
* :mod:`~simulator.stage.mapping` (and :mod:`~simulator.stage.devices`): instances to specs, with
  the vocabulary in :mod:`~simulator.stage.keywords` and value converters in
  :mod:`~simulator.stage.values`.

Malformed input raises :class:`~simulator.errors.WorldFileError` with the file and line of the
offending token and a fix; no other exception escapes for any file content.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import as_world_file_errors
from ..spec import WorldSpec
from .macros import Expander
from .mapping import Mapper

__all__ = ["load"]


def load(path: str | os.PathLike[str], *, include_dirs: list[Path], seed: int | None = None) -> WorldSpec:
    """Read a Stage world file and its includes into a :class:`WorldSpec` (see the package doc)."""
    display = os.fspath(path)
    with as_world_file_errors(display, "models or defines nested too deeply"):
        ex = Expander(include_dirs)
        ex.load_file(Path(display), display, None)
        return Mapper(display, ex.world_props, ex.top).build(seed)
