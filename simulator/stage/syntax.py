"""Lexer and parser of Stage world files: tokens with file:line, and a syntax tree.

The syntax is Stage's worldfile format (Stage manual, "World file syntax"; ``libstage/worldfile.cc``
read for its meaning, no code shared):

* ``# comment`` to the end of the line; ``"quoted strings"`` on one line; numbers; words made of
  letters, digits, ``_ . : -`` (an index suffix such as ``spose[3]`` belongs to the word);
  ``[ ... ]`` arrays of numbers and strings; ``TYPE ( ... )`` model bodies.
* Top-level statements: ``include "file.inc"``, ``define NAME BASE ( body )``, world properties
  ``key value``, and models ``TYPE ( body )``; bodies hold properties and nested models.

Every token keeps its file and line, so every later error names them. Malformed input raises
:class:`~simulator.errors.WorldFileError` with the place and a fix.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import WorldFileError

__all__ = ["Tok", "Prop", "Body", "Entity", "Define", "Include", "Stmt", "Parser", "tokenize", "show", "read_text",
           "INDEX_RE", "MAX_NESTING"]  # fmt: skip

MAX_NESTING = 64  # models inside models, and define expansions inside each other

_NUM_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_WORD_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_.:\-]*(?:\[\d+\][A-Za-z0-9_.:\-]*)*", re.ASCII)
_BAD_NUM_RE = re.compile(r"[^\s\[\]()\"#]*")
INDEX_RE = re.compile(r"\[\d+\]")
_NUM_FOLLOW = frozenset("_.:+-")


@dataclass(frozen=True, slots=True)
class Tok:
    kind: str  # "word" | "num" | "str" | "[" | "]" | "(" | ")"
    text: str
    file: str
    line: int


def show(t: Tok) -> str:
    if t.kind == "str":
        return f'"{t.text}"'
    return t.text


def tokenize(text: str, file: str) -> list[Tok]:
    toks: list[Tok] = []
    i, n, line = 0, len(text), 1
    while i < n:
        c = text[i]
        if c == "\n":
            line += 1
            i += 1
        elif c in " \t\r\f\v":
            i += 1
        elif c == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif c in "[]()":
            toks.append(Tok(c, c, file, line))
            i += 1
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"' and text[j] != "\n":
                j += 1
            if j >= n or text[j] != '"':
                raise WorldFileError("string never closed: add the closing '\"' on the same line", file, line)
            toks.append(Tok("str", text[i + 1 : j], file, line))
            i = j + 1
        elif (m := _NUM_RE.match(text, i)) is not None:
            end = m.end()
            if end < n and (text[end].isalnum() or text[end] in _NUM_FOLLOW):
                bad = _BAD_NUM_RE.match(text, i).group()  # type: ignore[union-attr]
                raise WorldFileError(
                    f"malformed number {bad!r}: write a plain number such as 0.25 or -1e-3 "
                    "(units are implied: metres, degrees, milliseconds)",
                    file,
                    line,
                )
            toks.append(Tok("num", m.group(), file, line))
            i = end
        elif (m := _WORD_RE.match(text, i)) is not None:
            toks.append(Tok("word", m.group(), file, line))
            i = m.end()
        else:
            raise WorldFileError(
                f'unexpected character {c!r}: Stage files hold keywords, numbers, "strings", '
                "[ arrays ], ( bodies ) and # comments",
                file,
                line,
            )
    return toks


# ---------------------------------------------------------------------------------- syntax tree
@dataclass(slots=True)
class Prop:
    key: str
    tok: Tok  # the keyword
    values: list[Tok]
    array: bool  # written as [ ... ]
    open: Tok | None = None  # the "[" of an array

    @property
    def at(self) -> Tok:
        """The token to blame for a bad value."""
        if self.values:
            return self.values[0]
        return self.open or self.tok


@dataclass(slots=True)
class Body:
    props: list[Prop]
    children: list[Entity]


@dataclass(slots=True)
class Entity:
    type_tok: Tok
    body: Body


@dataclass(slots=True)
class Define:
    name_tok: Tok
    base_tok: Tok
    body: Body


@dataclass(slots=True)
class Include:
    tok: Tok
    path_tok: Tok


Stmt = Prop | Entity | Define | Include


class Parser:
    def __init__(self, toks: list[Tok]):
        self.toks = toks
        self.i = 0

    def _peek(self, k: int = 0) -> Tok | None:
        j = self.i + k
        return self.toks[j] if j < len(self.toks) else None

    def _next(self) -> Tok | None:
        t = self._peek()
        if t is not None:
            self.i += 1
        return t

    def parse_file(self) -> list[Stmt]:
        stmts: list[Stmt] = []
        while (tok := self._peek()) is not None:
            if tok.kind != "word":
                self._unexpected(tok)
            if tok.text == "include":
                stmts.append(self._include())
            elif tok.text == "define":
                stmts.append(self._define())
            else:
                stmts.append(self._item(0))
        return stmts

    @staticmethod
    def _unexpected(tok: Tok) -> None:
        if tok.kind == ")":
            msg = "unmatched ')': no '(' is open here; remove it or add the missing '('"
        elif tok.kind == "]":
            msg = "unmatched ']': no '[' is open here; remove it or add the missing '['"
        elif tok.kind == "(":
            msg = "'(' without a model type before it; write e.g. 'model ( ... )'"
        elif tok.kind == "[":
            msg = "array without a keyword before it; write e.g. 'pose [ 1 2 0 90 ]'"
        else:
            what = "number" if tok.kind == "num" else "string"
            msg = f"expected a keyword or a model type, got the {what} {show(tok)}; is a keyword missing?"
        raise WorldFileError(msg, tok.file, tok.line)

    def _include(self) -> Include:
        kw = self._next()
        assert kw is not None
        path = self._peek()
        if path is None or path.kind != "str" or not path.text.strip():
            raise WorldFileError('include needs a quoted file name: include "pioneer.inc"', kw.file, kw.line)
        self.i += 1
        return Include(kw, path)

    def _define(self) -> Define:
        kw = self._next()
        assert kw is not None
        usage = "write: define NAME BASE ( properties and models )"
        name = self._next()
        if name is None or name.kind != "word" or name.text in ("include", "define") or "[" in name.text:
            t = name or kw
            raise WorldFileError(f"define needs a new type name; {usage}", t.file, t.line)
        base = self._next()
        if base is None or base.kind != "word" or "[" in base.text:
            t = base or name
            raise WorldFileError(
                f"define {name.text} needs a base type after its name (model, position, ...); {usage}",
                t.file,
                t.line,
            )
        op = self._next()
        if op is None or op.kind != "(":
            t = op or base
            raise WorldFileError(f"expected '(' after 'define {name.text} {base.text}'; {usage}", t.file, t.line)
        return Define(name, base, self._body(op, 1))

    def _item(self, depth: int) -> Prop | Entity:
        key = self._next()
        assert key is not None and key.kind == "word"
        nxt = self._peek()
        if nxt is not None and nxt.kind == "(":
            self.i += 1
            if "[" in key.text:
                raise WorldFileError(f"model type '{key.text}' cannot have an index", key.file, key.line)
            return Entity(key, self._body(nxt, depth + 1))
        return self._prop(key)

    def _body(self, open_tok: Tok, depth: int) -> Body:
        if depth > MAX_NESTING:
            raise WorldFileError(
                f"models nested more than {MAX_NESTING} deep; is a ')' missing?",
                open_tok.file,
                open_tok.line,
            )
        props: list[Prop] = []
        children: list[Entity] = []
        while True:
            tok = self._peek()
            if tok is None:
                raise WorldFileError(
                    "'(' opened here is never closed; add the matching ')'", open_tok.file, open_tok.line
                )
            if tok.kind == ")":
                self.i += 1
                return Body(props, children)
            if tok.kind != "word":
                self._unexpected(tok)
            if tok.text in ("include", "define"):
                raise WorldFileError(
                    f"'{tok.text}' is only allowed at the top level of a file, not inside '( ... )' "
                    f"(opened on line {open_tok.line}); move it out, or close the body first",
                    tok.file,
                    tok.line,
                )
            item = self._item(depth)
            if isinstance(item, Entity):
                children.append(item)
            else:
                props.append(item)

    def _prop(self, key: Tok) -> Prop:
        tok = self._peek()
        missing = (
            tok is None
            or tok.kind in (")", "]", "(")
            or (
                tok.kind == "word"
                and (tok.line != key.line or ((after := self._peek(1)) is not None and after.kind == "("))
            )
        )
        if missing:
            raise WorldFileError(
                f"keyword '{key.text}' has no value; write e.g. '{key.text} 1' or '{key.text} [ ... ]', "
                "or add '( ... )' if it is a model type",
                key.file,
                key.line,
            )
        assert tok is not None
        self.i += 1
        if tok.kind != "[":
            return Prop(key.text, key, [tok], False)
        values: list[Tok] = []
        while True:
            t = self._peek()
            if t is None or t.kind in ("[", "(", ")"):
                found = "the end of the file" if t is None else f"'{t.kind}' on line {t.line}"
                raise WorldFileError(
                    f"'[' of '{key.text}' is never closed (found {found}); add the matching ']'",
                    tok.file,
                    tok.line,
                )
            self.i += 1
            if t.kind == "]":
                return Prop(key.text, key, values, True, tok)
            values.append(t)


def read_text(path: Path, display: str, via: Tok | None) -> str:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        if via is not None:
            raise WorldFileError(f"include file {display} disappeared", via.file, via.line) from None
        raise WorldFileError("no such world file; check the path", display) from None
    except (OSError, ValueError) as e:
        reason = getattr(e, "strerror", None) or type(e).__name__
        if via is not None:
            raise WorldFileError(f"cannot read include file {display}: {reason}", via.file, via.line) from None
        raise WorldFileError(f"cannot read the world file: {reason}", display) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")
