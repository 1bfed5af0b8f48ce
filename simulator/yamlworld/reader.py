"""Reading a YAML world file: ``yaml.safe_load`` whose mappings and sequences remember their lines.

The first stage of :mod:`simulator.yamlworld`: the file's bytes become a YAML document (YAML 1.1 as
PyYAML's safe loader reads it) in which every mapping is a :class:`LineMap` and every sequence a
:class:`LineSeq`, so later stages can name the line of a key or item. Duplicate keys are collected
(the last one wins, as in YAML loaders generally) for the loader to warn about. Unreadable files,
syntax errors and tags beyond plain YAML raise :class:`~simulator.errors.WorldFileError` with file:line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ..errors import WorldFileError

__all__ = ["LineLoader", "LineMap", "LineSeq", "read"]


class LineMap(dict):
    """A YAML mapping that remembers the line of itself and of each key (1-based)."""

    line: int = 0
    key_lines: dict[Any, int]

    def line_of(self, key: str) -> int:
        return self.key_lines.get(key, self.line)


class LineSeq(list):
    """A YAML sequence that remembers the line of itself and of each item (1-based)."""

    line: int = 0
    item_lines: list[int]

    def line_at(self, i: int) -> int:
        return self.item_lines[i] if i < len(self.item_lines) else self.line


class LineLoader(yaml.SafeLoader):
    """``yaml.safe_load`` semantics, but mappings and sequences carry their line numbers."""

    duplicates: list[tuple[str, int]]


def _construct_map(loader: LineLoader, node: yaml.MappingNode):  # type: ignore[no-untyped-def]
    data = LineMap()
    data.line = node.start_mark.line + 1
    data.key_lines = {}
    yield data
    loader.flatten_mapping(node)
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(
                "while constructing a mapping",
                node.start_mark,
                "found an unhashable key",
                key_node.start_mark,
            ) from None
        line = key_node.start_mark.line + 1
        if key in data:
            loader.duplicates.append((str(key), line))
        data[key] = loader.construct_object(value_node)
        data.key_lines[key] = line


def _construct_seq(loader: LineLoader, node: yaml.SequenceNode):  # type: ignore[no-untyped-def]
    data = LineSeq()
    data.line = node.start_mark.line + 1
    data.item_lines = [n.start_mark.line + 1 for n in node.value]
    yield data
    data.extend(loader.construct_sequence(node))


LineLoader.add_constructor("tag:yaml.org,2002:map", _construct_map)
LineLoader.add_constructor("tag:yaml.org,2002:seq", _construct_seq)


def read(display: str) -> tuple[object, list[tuple[str, int]]]:
    """The document of the YAML file ``display`` (mappings and sequences with their lines) and its
    duplicate keys as ``(key, line)``; any unreadable or malformed file is a WorldFileError."""
    p = Path(display)
    try:
        text = p.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise WorldFileError("no such world file; check the path", display) from None
    except UnicodeDecodeError as e:
        raise WorldFileError(f"not UTF-8 text (byte {e.start}); save the file as UTF-8", display) from None
    except (OSError, ValueError) as e:
        reason = getattr(e, "strerror", None) or type(e).__name__
        raise WorldFileError(f"cannot read the world file: {reason}", display) from None
    loader = LineLoader(text)
    loader.duplicates = []
    try:
        doc = loader.get_single_data()
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        line = mark.line + 1 if mark is not None else 0
        problem = " ".join(str(e.problem or e.context or "syntax error").split())
        if isinstance(e, yaml.constructor.ConstructorError):
            msg = f"YAML value error: {problem}; use plain YAML values (no tags such as !!python/...)"
        else:
            msg = f"YAML syntax error: {problem}; check indentation, colons and brackets"
        raise WorldFileError(msg, display, line) from None
    except yaml.YAMLError as e:
        raise WorldFileError(f"YAML error: {' '.join(str(e).split())}", display) from None
    except RecursionError:
        raise WorldFileError("YAML nested too deeply", display) from None
    except (ValueError, TypeError, OverflowError) as e:  # e.g. an impossible date such as 2001-02-30
        raise WorldFileError(f"YAML value error: {e}", display) from None
    finally:
        loader.dispose()
    return doc, loader.duplicates
