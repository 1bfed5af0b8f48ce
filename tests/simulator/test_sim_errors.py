"""The simulator's one "did you mean" (simulator.errors.did_you_mean) and that the loaders use it."""

from __future__ import annotations

import ast
from pathlib import Path

from simulator.errors import did_you_mean

SIMULATOR = Path(__file__).resolve().parents[2] / "simulator"


def test_did_you_mean_names_the_closest_known_word():
    assert did_you_mean("colr", ["size", "color", "pose"]) == "did you mean 'color'?"
    assert did_you_mean("posiiton", {"position", "ranger"}) == "did you mean 'position'?"


def test_did_you_mean_is_empty_when_nothing_is_close():
    assert did_you_mean("xyzzy", ["color", "pose"]) == ""
    assert did_you_mean("color", []) == ""


def test_only_simulator_errors_imports_difflib():
    importers = []
    for path in sorted(SIMULATOR.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            if "difflib" in names:
                importers.append(path.relative_to(SIMULATOR).as_posix())
    assert importers == ["errors.py"]
