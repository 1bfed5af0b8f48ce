"""Macro expansion of Stage world files: ``include``, ``define`` and inheritance.

Stage's semantics (Stage manual, "define" and "include"; ``libstage/worldfile.cc``, read for
meaning): ``include "file.inc"`` reads another file in place, looked up next to the including file,
then in each directory of ``STAGEPATH`` (colon-separated), then in the project's ``maps/include/``;
``define NAME BASE ( body )`` makes a new type. Instantiating ``NAME ( body2 )`` gives a model of
the base's built-in type with the define's properties, overridden and extended by ``body2``;
defines chain, and the models declared inside a define body come with every instance. The result
is a tree of :class:`Inst` (merged properties, latest assignment last, each with its file:line).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import WorldFileError, did_you_mean
from .keywords import BUILTIN_TYPES
from .syntax import MAX_NESTING, Body, Define, Include, Parser, Prop, Stmt, Tok, read_text, tokenize
from .values import where

__all__ = ["Expander", "Inst", "Macro", "MAX_INCLUDE_DEPTH", "MAX_MODELS"]

MAX_INCLUDE_DEPTH = 32
MAX_MODELS = 100_000  # instances after macro expansion (guards against exponential defines)


@dataclass(eq=False, slots=True)
class Macro:
    name: str
    base: Macro | None
    builtin: str
    body: Body
    tok: Tok


@dataclass(eq=False, slots=True)
class Inst:
    """A model after macro expansion: merged properties (latest assignment last) and children."""

    type_name: str
    base: str  # built-in type
    tok: Tok  # where it was instantiated
    props: dict[str, Prop]
    children: list[Inst]

    def latest(self, *keys: str) -> Prop | None:
        """Of several alternative keys, the one assigned last (instance over define over base)."""
        best: Prop | None = None
        best_i = -1
        for i, (k, p) in enumerate(self.props.items()):
            if k in keys and i > best_i:
                best, best_i = p, i
        return best


class Expander:
    """Reads a world file and its includes, keeps the defines, and expands every model into an
    :class:`Inst`. ``include_dirs`` are searched after the including file's directory and
    ``STAGEPATH``."""

    def __init__(self, include_dirs: list[Path]):
        self.include_dirs = list(include_dirs)
        self.macros: dict[str, Macro] = {}
        self.world_props: dict[str, Prop] = {}
        self.top: list[Inst] = []
        self._stack: list[tuple[Path, str]] = []  # files being read: resolved path, display name
        self._count = 0

    # ------------------------------------------------------------------ files
    def load_file(self, path: Path, display: str, via: Tok | None) -> None:
        try:
            resolved = path.resolve()
        except (OSError, RuntimeError, ValueError):
            resolved = path.absolute()
        if via is not None:
            names = [d for r, d in self._stack]
            if any(r == resolved for r, _ in self._stack):
                chain = " -> ".join([*names, display])
                raise WorldFileError(f"include cycle {chain}; remove one of these includes", via.file, via.line)
            if len(self._stack) >= MAX_INCLUDE_DEPTH:
                raise WorldFileError(
                    f"includes nested more than {MAX_INCLUDE_DEPTH} deep; flatten them", via.file, via.line
                )
        text = read_text(path, display, via)
        stmts = Parser(tokenize(text, display)).parse_file()
        self._stack.append((resolved, display))
        try:
            self._run(stmts, Path(display).parent)
        finally:
            self._stack.pop()

    def _run(self, stmts: list[Stmt], directory: Path) -> None:
        for s in stmts:
            if isinstance(s, Include):
                self._include(s, directory)
            elif isinstance(s, Define):
                self._define(s)
            elif isinstance(s, Prop):
                self.world_props.pop(s.key, None)
                self.world_props[s.key] = s
            else:
                self.top.append(self._expand(s.type_tok, s.body, [], 0))

    def _include(self, s: Include, directory: Path) -> None:
        name = s.path_tok.text.strip()
        dirs = [directory]
        dirs += [Path(d) for d in os.environ.get("STAGEPATH", "").split(":") if d.strip()]
        dirs += self.include_dirs
        for d in dirs:
            cand = d / name
            try:
                found = cand.is_file()
            except (OSError, ValueError):
                found = False
            if found:
                self.load_file(cand, str(cand), s.tok)
                return
        looked = ", ".join(str(d) for d in dirs)
        raise WorldFileError(
            f"cannot find include file '{name}' (looked in {looked}); fix the name or add its directory to STAGEPATH",
            s.tok.file,
            s.tok.line,
        )

    # ------------------------------------------------------------------ macros
    def _known_types(self) -> list[str]:
        return sorted(BUILTIN_TYPES | set(self.macros))

    def _suggest(self, name: str) -> str:
        hint = did_you_mean(name, self._known_types())
        return f"{hint} " if hint else ""

    def _define(self, s: Define) -> None:
        name, base = s.name_tok.text, s.base_tok.text
        if name in BUILTIN_TYPES:
            raise WorldFileError(
                f"'{name}' is a built-in type and cannot be redefined; choose another name",
                s.name_tok.file,
                s.name_tok.line,
            )
        if base in self.macros:
            parent: Macro | None = self.macros[base]
            builtin = parent.builtin  # type: ignore[union-attr]
        elif base in BUILTIN_TYPES:
            parent, builtin = None, base
        else:
            raise WorldFileError(
                f"define {name}: unknown base type '{base}'; {self._suggest(base)}"
                "use a built-in type (model, position, ranger, sensor, laser, blobfinder, gripper), "
                "an earlier define, or include the file that defines it first",
                s.base_tok.file,
                s.base_tok.line,
            )
        self.macros[name] = Macro(name, parent, builtin, s.body, s.name_tok)

    def _expand(self, type_tok: Tok, body: Body, active: list[Macro], depth: int) -> Inst:
        name = type_tok.text
        chain: list[Macro] = []
        if name in self.macros:
            m: Macro | None = self.macros[name]
            while m is not None:
                chain.append(m)
                m = m.base
            builtin = chain[-1].builtin
        elif name in BUILTIN_TYPES:
            builtin = name
        else:
            fix = 'include "map.inc" first' if name == "floorplan" else "include the file that defines it"
            raise WorldFileError(
                f"unknown model type '{name}'; {self._suggest(name)}"
                f"define it first (define {name} model ( ... )) or {fix}",
                type_tok.file,
                type_tok.line,
            )
        self._count += 1
        if self._count > MAX_MODELS:
            raise WorldFileError(f"more than {MAX_MODELS} models after expanding defines", type_tok.file, type_tok.line)
        if builtin == "window":  # the GUI window: nothing to simulate
            return Inst(name, builtin, type_tok, {}, [])
        if depth > MAX_NESTING:
            raise WorldFileError(f"models nested more than {MAX_NESTING} deep", type_tok.file, type_tok.line)
        for m in chain:
            if m in active:
                raise WorldFileError(
                    f"'{m.name}' contains itself (defined at {where(m.tok)}); a define cannot include "
                    "a model of its own type",
                    type_tok.file,
                    type_tok.line,
                )
        props: dict[str, Prop] = {}
        children: list[Inst] = []
        for m in reversed(chain):
            active.append(m)
            try:
                self._merge(m.body, props, children, active, depth)
            finally:
                active.pop()
        self._merge(body, props, children, active, depth)
        return Inst(name, builtin, type_tok, props, children)

    def _merge(self, body: Body, props: dict[str, Prop], children: list[Inst], active: list[Macro], depth: int) -> None:
        for p in body.props:
            props.pop(p.key, None)
            props[p.key] = p
        for c in body.children:
            children.append(self._expand(c.type_tok, c.body, active, depth + 1))
