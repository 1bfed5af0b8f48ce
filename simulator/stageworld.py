"""Loader for Stage ``.world`` files: a compatible subset of the Stage 3/4 world file syntax.

Implements the world and include file syntax the thesis uses (appendix A.1 ``devices.inc``, A.5
``urg.inc``, A.6 ``utm30lx.inc``) and turns it into a :class:`~simulator.spec.WorldSpec`. The code
is written for this project from the documented syntax; it shares no code with Stage.

Syntax
------
* ``# comment`` to the end of the line; ``"quoted strings"`` on one line; numbers; words made of
  letters, digits, ``_ . : -`` (an index suffix such as ``spose[3]`` belongs to the word);
  ``[ ... ]`` arrays of numbers and strings; ``TYPE ( ... )`` model bodies.
* ``include "file.inc"``: looked up next to the including file, then in each directory of the
  ``STAGEPATH`` environment variable (colon-separated), then in the project's ``maps/include/``.
* ``define NAME BASE ( body )``: a macro. Instantiating ``NAME ( body2 )`` gives a model of the
  base's built-in type with the define's properties, overridden and extended by ``body2``;
  defines chain, and the models declared inside a define body come with every instance.
* Built-in types: ``model``, ``position``, ``ranger``, ``sensor`` (a transducer group inside a
  ranger), ``laser`` (Stage 3: a ranger with one sensor), ``blobfinder``, ``gripper``; ``camera``,
  ``fiducial``, ``actuator``, ``bumper``, ``ptz`` are recognised and skipped with a warning;
  ``window`` (the GUI) and ``block`` (a model's polygon shape) are skipped silently.

Mapping to the spec
-------------------
* Top-level ``position`` models (or defines of it) are robots. Their ``ranger``/``laser`` children
  become :class:`RangerSpec` (``kind="laser"`` for one sensor with several samples, else
  ``"sonar"``), ``blobfinder`` and ``gripper`` children the other devices; plain ``model``
  children (a plate, a laptop) are decoration, though devices mounted on them are found.
* The first non-position top-level model with a ``bitmap`` is the floorplan: Stage stretches the
  bitmap to ``size`` and centres it on ``pose``, so resolution = size_x / width in pixels and
  origin = pose - size / 2. Without ``size``, our extension keys ``map_resolution`` (default 0.05
  m/pixel) and ``origin [x y]`` place it like Player's mapfile driver (default: centred on pose).
* Every other top-level model is a passive body (a blob, a box).
* Stage units become SI: poses ``[x y z a]`` (or ``[x y a]``) with ``a`` in degrees become
  ``(x, y, radians(a))``; ``fov`` is in degrees; ``interval_sim``/``interval_real`` and
  ``update_interval`` are in milliseconds. Unnamed models are named ``<type>:<n>`` as Stage does
  (``<type>`` is the built-in type, ``n`` counts the models of that type at their level).
* Extensions: ``odom_noise [x y a]`` on a position model, ``paddle_time``/``lift_time`` on a
  gripper, ``map_resolution``/``origin`` on a floorplan, ``seed`` at world level.

Errors and warnings
-------------------
Malformed input raises :class:`~simulator.errors.WorldFileError` with the file and line of the
offending token and a fix; no other exception escapes for any file content. Known Stage keywords
that are not simulated are accepted silently; an unknown keyword is skipped with one warning per
keyword and file (with a "did you mean"), collected in ``WorldSpec.warnings`` and logged.
"""

from __future__ import annotations

import difflib
import logging
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

from .errors import WorldFileError, as_world_file_errors
from .spec import (
    BlobfinderSpec,
    FloorplanSpec,
    GripperSpec,
    ModelSpec,
    RangerSensorSpec,
    RangerSpec,
    WorldSpec,
    parse_color,
)

__all__ = ["INCLUDE_DIR", "load_stage_world"]

log = logging.getLogger(__name__)

INCLUDE_DIR = Path(__file__).resolve().parent.parent / "maps" / "include"
"""The project's own include files (``pioneer.inc``, ``map.inc``, ...), searched last."""

Pose = tuple[float, float, float]

_MAX_NESTING = 64  # models inside models, and define expansions inside each other
_MAX_INCLUDE_DEPTH = 32
_MAX_MODELS = 100_000  # instances after macro expansion (guards against exponential defines)
_DEFAULT_MAP_RESOLUTION = 0.05  # m/pixel, Player's mapfile default

# ---------------------------------------------------------------------------------- keywords
_MODEL_TYPES = frozenset({"model", "position", "ranger", "sensor", "laser", "blobfinder", "gripper"})
_NOT_SIMULATED = frozenset({"camera", "fiducial", "actuator", "bumper", "ptz"})
_SKIPPED = frozenset({"window", "block"})  # GUI block and polygon shapes: ignored silently
BUILTIN_TYPES = _MODEL_TYPES | _NOT_SIMULATED | _SKIPPED

_MODEL_KEYS = frozenset(
    {
        "name", "pose", "size", "origin", "color", "color_rgba", "mass", "bitmap", "map_resolution",
        "obstacle_return", "laser_return", "ranger_return", "blob_return", "gripper_return",
        "fiducial_return", "fiducial_key", "boundary", "watts", "stack_children", "ctrl",
        "update_interval", "polygons", "polygon.points", "polygon.point", "polygon.filled",
        "velocity", "say", "friction", "alwayson", "joules", "joules_capacity", "kjoules",
        "give_watts", "take_watts", "line_count", "line.points", "line.point", "debug",
    }
)  # fmt: skip
_POSITION_KEYS = _MODEL_KEYS | {
    "drive", "velocity_bounds", "acceleration_bounds", "odom_error", "odom_noise", "localization",
    "localization_origin", "wheelbase", "velocity_enable",
}  # fmt: skip
_RANGER_KEYS = _MODEL_KEYS | {"scount", "spose", "ssize", "sview"}
_LASER_KEYS = _MODEL_KEYS | {
    "range_min", "range_max", "fov", "samples", "noise", "laser_sample_skip", "resolution",
}  # fmt: skip
_SENSOR_KEYS = frozenset(
    {"pose", "size", "range", "fov", "samples", "noise", "color", "color_rgba", "watts", "ranger_return"}
)
_BLOBFINDER_KEYS = _MODEL_KEYS | {
    "colors_count", "colors", "channel_count", "channels", "fov", "range", "range_max", "image", "pan", "ptz",
}  # fmt: skip
_GRIPPER_KEYS = _MODEL_KEYS | {
    "paddle_time", "lift_time", "paddle_size", "paddle_state", "lift_state", "autosnatch",
}  # fmt: skip
_WORLD_KEYS = frozenset(
    {
        "name", "resolution", "interval_sim", "interval_real", "speedup", "quit_time", "threads",
        "paused", "show_clock", "show_clock_interval", "seed", "size", "log",
    }
)  # fmt: skip
_KEYS_BY_TYPE = {
    "model": _MODEL_KEYS,
    "position": _POSITION_KEYS,
    "ranger": _RANGER_KEYS,
    "laser": _LASER_KEYS,
    "sensor": _SENSOR_KEYS,
    "blobfinder": _BLOBFINDER_KEYS,
    "gripper": _GRIPPER_KEYS,
}
_DEVICE_TYPES = frozenset({"ranger", "laser", "blobfinder", "gripper"})

# ---------------------------------------------------------------------------------- tokens
_NUM_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_WORD_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_.:\-]*(?:\[\d+\][A-Za-z0-9_.:\-]*)*", re.ASCII)
_BAD_NUM_RE = re.compile(r"[^\s\[\]()\"#]*")
_INDEX_RE = re.compile(r"\[\d+\]")
_NUM_FOLLOW = frozenset("_.:+-")


@dataclass(frozen=True, slots=True)
class _Tok:
    kind: str  # "word" | "num" | "str" | "[" | "]" | "(" | ")"
    text: str
    file: str
    line: int


def _show(t: _Tok) -> str:
    if t.kind == "str":
        return f'"{t.text}"'
    return t.text


def _tokenize(text: str, file: str) -> list[_Tok]:
    toks: list[_Tok] = []
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
            toks.append(_Tok(c, c, file, line))
            i += 1
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"' and text[j] != "\n":
                j += 1
            if j >= n or text[j] != '"':
                raise WorldFileError("string never closed: add the closing '\"' on the same line", file, line)
            toks.append(_Tok("str", text[i + 1 : j], file, line))
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
            toks.append(_Tok("num", m.group(), file, line))
            i = end
        elif (m := _WORD_RE.match(text, i)) is not None:
            toks.append(_Tok("word", m.group(), file, line))
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
class _Prop:
    key: str
    tok: _Tok  # the keyword
    values: list[_Tok]
    array: bool  # written as [ ... ]
    open: _Tok | None = None  # the "[" of an array

    @property
    def at(self) -> _Tok:
        """The token to blame for a bad value."""
        if self.values:
            return self.values[0]
        return self.open or self.tok


@dataclass(slots=True)
class _Body:
    props: list[_Prop]
    children: list[_Entity]


@dataclass(slots=True)
class _Entity:
    type_tok: _Tok
    body: _Body


@dataclass(slots=True)
class _Define:
    name_tok: _Tok
    base_tok: _Tok
    body: _Body


@dataclass(slots=True)
class _Include:
    tok: _Tok
    path_tok: _Tok


_Stmt = _Prop | _Entity | _Define | _Include


class _Parser:
    def __init__(self, toks: list[_Tok]):
        self.toks = toks
        self.i = 0

    def _peek(self, k: int = 0) -> _Tok | None:
        j = self.i + k
        return self.toks[j] if j < len(self.toks) else None

    def _next(self) -> _Tok | None:
        t = self._peek()
        if t is not None:
            self.i += 1
        return t

    def parse_file(self) -> list[_Stmt]:
        stmts: list[_Stmt] = []
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
    def _unexpected(tok: _Tok) -> None:
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
            msg = f"expected a keyword or a model type, got the {what} {_show(tok)}; is a keyword missing?"
        raise WorldFileError(msg, tok.file, tok.line)

    def _include(self) -> _Include:
        kw = self._next()
        assert kw is not None
        path = self._peek()
        if path is None or path.kind != "str" or not path.text.strip():
            raise WorldFileError('include needs a quoted file name: include "pioneer.inc"', kw.file, kw.line)
        self.i += 1
        return _Include(kw, path)

    def _define(self) -> _Define:
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
        return _Define(name, base, self._body(op, 1))

    def _item(self, depth: int) -> _Prop | _Entity:
        key = self._next()
        assert key is not None and key.kind == "word"
        nxt = self._peek()
        if nxt is not None and nxt.kind == "(":
            self.i += 1
            if "[" in key.text:
                raise WorldFileError(f"model type '{key.text}' cannot have an index", key.file, key.line)
            return _Entity(key, self._body(nxt, depth + 1))
        return self._prop(key)

    def _body(self, open_tok: _Tok, depth: int) -> _Body:
        if depth > _MAX_NESTING:
            raise WorldFileError(
                f"models nested more than {_MAX_NESTING} deep; is a ')' missing?",
                open_tok.file,
                open_tok.line,
            )
        props: list[_Prop] = []
        children: list[_Entity] = []
        while True:
            tok = self._peek()
            if tok is None:
                raise WorldFileError(
                    "'(' opened here is never closed; add the matching ')'", open_tok.file, open_tok.line
                )
            if tok.kind == ")":
                self.i += 1
                return _Body(props, children)
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
            if isinstance(item, _Entity):
                children.append(item)
            else:
                props.append(item)

    def _prop(self, key: _Tok) -> _Prop:
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
            return _Prop(key.text, key, [tok], False)
        values: list[_Tok] = []
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
                return _Prop(key.text, key, values, True, tok)
            values.append(t)


# ---------------------------------------------------------------------------------- values
def _bad(p: _Prop, need: str, example: str, tok: _Tok | None = None) -> WorldFileError:
    got = "[ " + " ".join(_show(t) for t in p.values) + " ]" if p.array else " ".join(_show(t) for t in p.values)
    t = tok or p.at
    if len(got) > 60:
        got = got[:57] + "..."
    return WorldFileError(f"'{p.key}' needs {need}, got {got}; write e.g. '{example}'", t.file, t.line)


def _tok_float(t: _Tok) -> float | None:
    if t.kind != "num":
        return None
    try:
        v = float(t.text)
    except ValueError:  # pragma: no cover - the tokenizer only lets valid numbers through
        return None
    return v if math.isfinite(v) else None


def _num(p: _Prop, need: str, example: str) -> float:
    if p.array or len(p.values) != 1 or (v := _tok_float(p.values[0])) is None:
        raise _bad(p, need, example)
    return v


def _int(p: _Prop, need: str, example: str) -> int:
    v = _num(p, need, example)
    if v != int(v) or abs(v) > 1e9:
        raise _bad(p, need, example)
    return int(v)


def _bool(p: _Prop, levels: bool = False) -> bool:
    """0 or 1 (or true/false); with ``levels``, any integer >= 0 (Stage 3's ``laser_return 2``
    meant "bright"), true when not 0."""
    if not p.array and len(p.values) == 1:
        t = p.values[0]
        v = _tok_float(t)
        if v is not None and (v in (0.0, 1.0) or (levels and v >= 0 and v == int(v))):
            return v != 0.0
        if t.kind in ("word", "str") and t.text.lower() in ("true", "false"):
            return t.text.lower() == "true"
    raise _bad(p, "0 or 1", f"{p.key} 1")


def _str(p: _Prop, need: str, example: str) -> str:
    if p.array or len(p.values) != 1 or p.values[0].kind not in ("str", "word"):
        raise _bad(p, need, example)
    return p.values[0].text


def _nums(p: _Prop, counts: tuple[int, ...], need: str, example: str) -> list[float]:
    if not p.array or len(p.values) not in counts:
        raise _bad(p, need, example)
    out: list[float] = []
    for t in p.values:
        v = _tok_float(t)
        if v is None:
            raise _bad(p, need, example, t)
        out.append(v)
    return out


def _strs(p: _Prop, need: str, example: str) -> list[str]:
    if not p.array:
        return [_str(p, need, example)]
    for t in p.values:
        if t.kind not in ("str", "word"):
            raise _bad(p, need, example, t)
    return [t.text for t in p.values]


def _pose(p: _Prop) -> Pose:
    v = _nums(p, (3, 4), "[x y z a] (metres and degrees)", f"{p.key} [ 1.0 2.0 0 90 ]")
    return (v[0], v[1], math.radians(v[-1]))


def _size(p: _Prop, default_z: float) -> tuple[float, float, float]:
    example = f"{p.key} [ 0.44 0.38 0.22 ]"
    v = _nums(p, (2, 3), "[x y z] in metres", example)
    if v[0] <= 0 or v[1] <= 0 or (len(v) == 3 and v[2] < 0):
        raise _bad(p, "positive sizes [x y z] in metres", example)
    return (v[0], v[1], v[2] if len(v) == 3 else default_z)


def _check(ok: bool, p: _Prop, need: str, example: str) -> None:
    if not ok:
        raise _bad(p, need, example)


def _compose(a: Pose, b: Pose) -> Pose:
    """A child model's pose ``b`` in its parent ``a``'s frame, in the world (yaw not wrapped, as Stage
    keeps it). The simulator depends on nothing of ours, so this is not rsal.geometry.compose;
    tests/rsal/test_geometry.py checks that the two agree."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def _base_key(key: str) -> str:
    return _INDEX_RE.sub("", key)


# ---------------------------------------------------------------------------------- expansion
@dataclass(eq=False, slots=True)
class _Macro:
    name: str
    base: _Macro | None
    builtin: str
    body: _Body
    tok: _Tok


@dataclass(eq=False, slots=True)
class _Inst:
    """A model after macro expansion: merged properties (latest assignment last) and children."""

    type_name: str
    base: str  # built-in type
    tok: _Tok  # where it was instantiated
    props: dict[str, _Prop]
    children: list[_Inst]

    def latest(self, *keys: str) -> _Prop | None:
        """Of several alternative keys, the one assigned last (instance over define over base)."""
        best: _Prop | None = None
        best_i = -1
        for i, (k, p) in enumerate(self.props.items()):
            if k in keys and i > best_i:
                best, best_i = p, i
        return best


def _where(t: _Tok) -> str:
    return f"{t.file}:{t.line}"


class _StageLoader:
    def __init__(self, display: str):
        self.display = display
        self.macros: dict[str, _Macro] = {}
        self.world_props: dict[str, _Prop] = {}
        self.top: list[_Inst] = []
        self.warnings: list[str] = []
        self._warned: set[object] = set()
        self._stack: list[tuple[Path, str]] = []  # files being read: resolved path, display name
        self._count = 0

    # ------------------------------------------------------------------ messages
    def warn(self, tok: _Tok, message: str, key: object = None) -> None:
        text = f"{_where(tok)}: {message}"
        k = key if key is not None else text
        if k in self._warned:
            return
        self._warned.add(k)
        self.warnings.append(text)
        log.warning("%s", text)

    def _check_keys(self, props: dict[str, _Prop], known: frozenset[str], what: str) -> None:
        for key, p in props.items():
            base = _base_key(key)
            if base in known or base.startswith("gui_"):
                continue
            close = difflib.get_close_matches(base, sorted(known), n=1, cutoff=0.6)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            self.warn(p.tok, f"unknown keyword '{key}' in {what} ignored{hint}", key=("key", p.tok.file, key))

    # ------------------------------------------------------------------ files
    def load_file(self, path: Path, display: str, via: _Tok | None) -> None:
        try:
            resolved = path.resolve()
        except (OSError, RuntimeError, ValueError):
            resolved = path.absolute()
        if via is not None:
            names = [d for r, d in self._stack]
            if any(r == resolved for r, _ in self._stack):
                chain = " -> ".join([*names, display])
                raise WorldFileError(f"include cycle {chain}; remove one of these includes", via.file, via.line)
            if len(self._stack) >= _MAX_INCLUDE_DEPTH:
                raise WorldFileError(
                    f"includes nested more than {_MAX_INCLUDE_DEPTH} deep; flatten them", via.file, via.line
                )
        text = _read_text(path, display, via)
        stmts = _Parser(_tokenize(text, display)).parse_file()
        self._stack.append((resolved, display))
        try:
            self._run(stmts, Path(display).parent)
        finally:
            self._stack.pop()

    def _run(self, stmts: list[_Stmt], directory: Path) -> None:
        for s in stmts:
            if isinstance(s, _Include):
                self._include(s, directory)
            elif isinstance(s, _Define):
                self._define(s)
            elif isinstance(s, _Prop):
                self.world_props.pop(s.key, None)
                self.world_props[s.key] = s
            else:
                self.top.append(self._expand(s.type_tok, s.body, [], 0))

    def _include(self, s: _Include, directory: Path) -> None:
        name = s.path_tok.text.strip()
        dirs = [directory]
        dirs += [Path(d) for d in os.environ.get("STAGEPATH", "").split(":") if d.strip()]
        dirs.append(INCLUDE_DIR)
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
        close = difflib.get_close_matches(name, self._known_types(), n=1, cutoff=0.6)
        return f"did you mean '{close[0]}'? " if close else ""

    def _define(self, s: _Define) -> None:
        name, base = s.name_tok.text, s.base_tok.text
        if name in BUILTIN_TYPES:
            raise WorldFileError(
                f"'{name}' is a built-in type and cannot be redefined; choose another name",
                s.name_tok.file,
                s.name_tok.line,
            )
        if base in self.macros:
            parent: _Macro | None = self.macros[base]
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
        self.macros[name] = _Macro(name, parent, builtin, s.body, s.name_tok)

    def _expand(self, type_tok: _Tok, body: _Body, active: list[_Macro], depth: int) -> _Inst:
        name = type_tok.text
        chain: list[_Macro] = []
        if name in self.macros:
            m: _Macro | None = self.macros[name]
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
        if self._count > _MAX_MODELS:
            raise WorldFileError(
                f"more than {_MAX_MODELS} models after expanding defines", type_tok.file, type_tok.line
            )
        if builtin in _SKIPPED:
            return _Inst(name, builtin, type_tok, {}, [])
        if depth > _MAX_NESTING:
            raise WorldFileError(f"models nested more than {_MAX_NESTING} deep", type_tok.file, type_tok.line)
        for m in chain:
            if m in active:
                raise WorldFileError(
                    f"'{m.name}' contains itself (defined at {_where(m.tok)}); a define cannot include "
                    "a model of its own type",
                    type_tok.file,
                    type_tok.line,
                )
        props: dict[str, _Prop] = {}
        children: list[_Inst] = []
        for m in reversed(chain):
            active.append(m)
            try:
                self._merge(m.body, props, children, active, depth)
            finally:
                active.pop()
        self._merge(body, props, children, active, depth)
        return _Inst(name, builtin, type_tok, props, children)

    def _merge(
        self, body: _Body, props: dict[str, _Prop], children: list[_Inst], active: list[_Macro], depth: int
    ) -> None:
        for p in body.props:
            props.pop(p.key, None)
            props[p.key] = p
        for c in body.children:
            children.append(self._expand(c.type_tok, c.body, active, depth + 1))

    # ------------------------------------------------------------------ the world
    def build(self, seed: int | None) -> WorldSpec:
        spec = WorldSpec(source=self.display)
        self._world(spec)
        counters: dict[str, int] = {}
        seen: dict[str, str] = {}
        for inst in self.top:
            base = inst.base
            if base in _SKIPPED:
                continue
            n = counters.get(base, 0)
            counters[base] = n + 1
            if base in _NOT_SIMULATED:
                self._not_simulated(inst)
                continue
            if base in _DEVICE_TYPES or base == "sensor":
                self.warn(
                    inst.tok,
                    f"'{inst.type_name}' ({base}) at the top level is skipped: devices must be declared "
                    "inside a position model",
                )
                continue
            name = self._name(inst, f"{base}:{n}")
            if base == "model" and "bitmap" in inst.props:
                if spec.floorplan is None:
                    spec.floorplan = self._floorplan(inst, name)
                else:
                    self.warn(
                        inst.tok,
                        f"second floorplan '{name}' skipped: only one bitmap model per world "
                        f"(the first is '{spec.floorplan.name}')",
                    )
                continue
            if name in seen:
                raise WorldFileError(
                    f"two models are named '{name}' (the first at {seen[name]}); give each a unique name",
                    inst.tok.file,
                    inst.tok.line,
                )
            seen[name] = _where(inst.tok)
            model = self._robot(inst, name) if base == "position" else self._passive(inst, name)
            spec.models.append(model)
        if seed is not None:
            spec.seed = int(seed)
        spec.warnings = list(self.warnings)
        return spec

    def _name(self, inst: _Inst, auto: str) -> str:
        p = inst.props.get("name")
        if p is None:
            return auto
        name = _str(p, "a quoted name", 'name "r0"').strip()
        _check(bool(name), p, "a non-empty name", 'name "r0"')
        return name

    def _not_simulated(self, inst: _Inst) -> None:
        self.warn(
            inst.tok,
            f"'{inst.type_name}' ({inst.base}) is not simulated; skipped",
            key=("nosim", inst.tok.file, inst.tok.line),
        )

    def _world(self, spec: WorldSpec) -> None:
        wp = self.world_props
        for key, p in wp.items():
            if _base_key(key) not in _WORLD_KEYS and not key.startswith("gui_"):
                close = difflib.get_close_matches(_base_key(key), sorted(_WORLD_KEYS), n=1, cutoff=0.6)
                hint = f"; did you mean '{close[0]}'?" if close else ""
                self.warn(p.tok, f"unknown world keyword '{key}' ignored{hint}", key=("key", p.tok.file, key))
        if (p := wp.get("interval_sim")) is not None:
            v = _num(p, "a positive number of milliseconds", "interval_sim 100")
            _check(v > 0, p, "a positive number of milliseconds", "interval_sim 100")
            spec.interval_sim = v / 1000.0
        if (p := wp.get("interval_real")) is not None:
            v = _num(p, "milliseconds >= 0 (0: as fast as possible)", "interval_real 100")
            _check(v >= 0, p, "milliseconds >= 0 (0: as fast as possible)", "interval_real 100")
            spec.speedup = math.inf if v == 0 else spec.interval_sim * 1000.0 / v
        if (p := wp.get("speedup")) is not None:
            v = _num(p, "a real-time factor (-1: as fast as possible)", "speedup 1.0")
            spec.speedup = math.inf if v <= 0 else v
        if (p := wp.get("seed")) is not None:
            spec.seed = _int(p, "an integer", "seed 42")
        for key, need, example in (
            ("resolution", "a positive number of metres", "resolution 0.02"),
            ("quit_time", "seconds >= 0", "quit_time 3600"),
            ("show_clock_interval", "a number of updates", "show_clock_interval 100"),
        ):
            if (p := wp.get(key)) is not None:
                _check(_num(p, need, example) >= 0, p, need, example)
        if (p := wp.get("threads")) is not None:
            _int(p, "an integer", "threads 1")
        for key in ("paused", "show_clock"):
            if (p := wp.get(key)) is not None:
                _bool(p)
        if (p := wp.get("name")) is not None:
            _str(p, "a quoted name", 'name "tams"')

    # ------------------------------------------------------------------ models
    def _common(self, inst: _Inst, m: ModelSpec) -> None:
        P = inst.props
        if (p := P.get("pose")) is not None:
            m.pose = _pose(p)
        if (p := P.get("size")) is not None:
            m.size = _size(p, m.size[2])
        if (p := inst.latest("color", "color_rgba")) is not None:
            if p.key == "color":
                cname = _str(p, "a colour name", 'color "red"')
                try:
                    m.color = parse_color(cname)
                except ValueError as e:
                    self.warn(p.at, f"{e}; keeping {m.color}", key=("color", p.tok.file, cname.lower()))
            else:
                rgba = _nums(p, (3, 4), "[r g b a] from 0 to 1", "color_rgba [ 0 1 0 1 ]")
                m.color = parse_color(rgba)
        if (p := P.get("mass")) is not None:
            v = _num(p, "kilograms >= 0", "mass 23.0")
            _check(v >= 0, p, "kilograms >= 0", "mass 23.0")
            m.mass = v
        if (p := inst.latest("laser_return", "ranger_return")) is not None:
            if p.key == "ranger_return":  # Stage 4: a float; rangers see the model when it is >= 0
                v = _num(p, "a number (>= 0: seen by rangers, < 0: invisible to them)", "ranger_return 1")
                m.laser_return = v >= 0.0
            else:  # Stage 3: 0 invisible, 1 visible, 2 bright
                m.laser_return = _bool(p, levels=True)
        for key in ("obstacle_return", "blob_return", "gripper_return"):
            if (p := P.get(key)) is not None:
                setattr(m, key, _bool(p))
        m.source = _where(inst.tok)

    def _passive(self, inst: _Inst, name: str) -> ModelSpec:
        self._check_keys(inst.props, _MODEL_KEYS, f"model '{name}'")
        m = ModelSpec(name=name, type_name=inst.type_name, position=False)
        self._common(inst, m)
        for c in inst.children:
            if c.base in _DEVICE_TYPES or c.base == "position":
                self.warn(
                    c.tok,
                    f"'{c.type_name}' on the passive model '{name}' is not simulated: mount devices "
                    "on a position model",
                    key=("passive-dev", c.tok.file, c.tok.line),
                )
        return m

    def _robot(self, inst: _Inst, name: str) -> ModelSpec:
        P = inst.props
        self._check_keys(P, _POSITION_KEYS, f"position '{name}'")
        m = ModelSpec(name=name, type_name=inst.type_name, position=True)
        self._common(inst, m)
        if (p := P.get("drive")) is not None:
            drive = _str(p, 'a drive name ("diff")', 'drive "diff"')
            if drive != "diff":
                self.warn(
                    p.at,
                    f"drive '{drive}' is not simulated; '{name}' uses a differential drive",
                    key=("drive", p.tok.file, p.tok.line),
                )
        for key in ("velocity_bounds", "acceleration_bounds"):
            if (p := P.get(key)) is not None:
                example = f"{key} [ -0.5 0.5 0 0 0 0 -90 90 ]"
                v = _nums(p, (8,), "[xmin xmax ymin ymax zmin zmax amin amax] (m and degrees)", example)
                lin = max(abs(v[0]), abs(v[1]))
                ang = math.radians(max(abs(v[6]), abs(v[7])))
                if key == "velocity_bounds":
                    m.max_speed = (lin, ang)
                else:
                    m.max_accel = (lin, ang)
        if (p := P.get("odom_error")) is not None:
            v = _nums(p, (3, 4), "[x y z a] error fractions >= 0", "odom_error [ 0.03 0.03 0.00 0.05 ]")
            _check(min(v) >= 0, p, "[x y z a] error fractions >= 0", "odom_error [ 0.03 0.03 0.00 0.05 ]")
            m.odom_error = (v[0], v[1], v[-1])
        if (p := P.get("odom_noise")) is not None:
            v = _nums(p, (3,), "[x y a] noise fractions >= 0", "odom_noise [ 0.01 0.01 0.02 ]")
            _check(min(v) >= 0, p, "[x y a] noise fractions >= 0", "odom_noise [ 0.01 0.01 0.02 ]")
            m.odom_noise = (v[0], v[1], v[2])
        self._devices(inst, m, (0.0, 0.0, 0.0), {})
        return m

    # ------------------------------------------------------------------ devices
    def _devices(self, parent: _Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> None:
        for c in parent.children:
            b = c.base
            if b in ("ranger", "laser"):
                r = self._ranger(c, robot, offset, counters)
                if r is not None:
                    robot.rangers.append(r)
            elif b == "blobfinder":
                robot.blobfinders.append(self._blobfinder(c, robot, offset, counters))
            elif b == "gripper":
                robot.grippers.append(self._gripper(c, robot, offset, counters))
            elif b == "model":
                # Decoration (a plate, a laptop): validated, not simulated; devices on it are found.
                self._check_keys(c.props, _MODEL_KEYS, f"model '{c.type_name}' on '{robot.name}'")
                self._common(c, ModelSpec(name=c.type_name))
                pose = _pose(c.props["pose"]) if "pose" in c.props else (0.0, 0.0, 0.0)
                self._devices(c, robot, _compose(offset, pose), counters)
            elif b in _NOT_SIMULATED:
                self._not_simulated(c)
            elif b == "position":
                self.warn(c.tok, f"position model '{c.type_name}' inside '{robot.name}' is not simulated; skipped")
            elif b == "sensor":
                self.warn(c.tok, f"sensor '{c.type_name}' outside a ranger is skipped; put it inside ranger( ... )")

    def _device_name(self, c: _Inst, counters: dict[str, int]) -> str:
        n = counters.get(c.base, 0)
        counters[c.base] = n + 1
        return self._name(c, f"{c.base}:{n}")

    def _mount(self, c: _Inst, offset: Pose) -> Pose:
        p = c.props.get("pose")
        return _compose(offset, _pose(p)) if p is not None else offset

    @staticmethod
    def _interval(c: _Inst, default: float) -> float:
        p = c.props.get("update_interval")
        if p is None:
            return default
        v = _num(p, "a positive number of milliseconds", "update_interval 100")
        _check(v > 0, p, "a positive number of milliseconds", "update_interval 100")
        return v / 1000.0

    def _ranger(self, c: _Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> RangerSpec | None:
        name = self._device_name(c, counters)
        what = f"{c.base} '{c.type_name}' of '{robot.name}'"
        P = c.props
        pose = self._mount(c, offset)
        interval = self._interval(c, RangerSpec().interval)
        sensors: list[RangerSensorSpec] = []
        if c.base == "laser":
            self._check_keys(P, _LASER_KEYS, what)
            rmin = _num(P["range_min"], "metres", "range_min 0.02") if "range_min" in P else 0.0
            rmax = _num(P["range_max"], "metres", "range_max 5.6") if "range_max" in P else 8.0
            if rmax <= 0 or not 0 <= rmin <= rmax:
                p = P.get("range_max") or P["range_min"]
                raise _bad(p, "0 <= range_min <= range_max, range_max > 0", "range_max 5.6")
            fov = self._fov(P.get("fov"), 180.0)
            samples = 180
            if (p := P.get("samples")) is not None:
                samples = _int(p, "an integer >= 1", "samples 682")
                _check(samples >= 1, p, "an integer >= 1", "samples 682")
            noise = self._noise(P.get("noise"))
            sensors.append(RangerSensorSpec((0.0, 0.0, 0.0), rmin, rmax, fov, samples, noise))
        else:
            self._check_keys(P, _RANGER_KEYS, what)
            for s in c.children:
                if s.base == "sensor":
                    sensors.append(self._sensor(s, what))
                elif s.base == "model":
                    self._check_keys(s.props, _MODEL_KEYS, f"model '{s.type_name}' on {what}")
                    self._common(s, ModelSpec(name=s.type_name))
                elif s.base in _NOT_SIMULATED:
                    self._not_simulated(s)
                elif s.base not in _SKIPPED:
                    self.warn(s.tok, f"'{s.type_name}' inside {what} is skipped; only sensor( ... ) belongs there")
            sensors += self._stage3_sensors(c, what)
        if not sensors:
            self.warn(c.tok, f"{what} has no sensors; skipped (add sensor( ... ) blocks)")
            return None
        kind = "laser" if len(sensors) == 1 and sensors[0].samples > 1 else "sonar"
        return RangerSpec(name=name, kind=kind, sensors=sensors, pose=pose, interval=interval)

    @staticmethod
    def _fov(p: _Prop | None, default_deg: float) -> float:
        if p is None:
            return math.radians(default_deg)
        v = _num(p, "an angle in degrees, 0 < fov <= 360", "fov 240")
        _check(0 < v <= 360, p, "an angle in degrees, 0 < fov <= 360", "fov 240")
        return math.radians(v)

    @staticmethod
    def _noise(p: _Prop | None) -> float:
        if p is None:
            return 0.0
        v = _num(p, "a standard deviation in metres >= 0", "noise 0.01")
        _check(v >= 0, p, "a standard deviation in metres >= 0", "noise 0.01")
        return v

    @staticmethod
    def _range(p: _Prop) -> tuple[float, float]:
        v = _nums(p, (2,), "[min max] in metres", "range [ 0.02 5.6 ]")
        _check(v[1] > 0 and 0 <= v[0] <= v[1], p, "[min max] with 0 <= min <= max, max > 0", "range [ 0.02 5.6 ]")
        return (v[0], v[1])

    def _sensor(self, s: _Inst, what: str) -> RangerSensorSpec:
        P = s.props
        self._check_keys(P, _SENSOR_KEYS, f"sensor of {what}")
        pose = _pose(P["pose"]) if "pose" in P else (0.0, 0.0, 0.0)
        rmin, rmax = self._range(P["range"]) if "range" in P else (0.0, 5.0)
        fov = self._fov(P.get("fov"), math.degrees(0.1))
        samples = 1
        if (p := P.get("samples")) is not None:
            samples = _int(p, "an integer >= 1", "samples 682")
            _check(samples >= 1, p, "an integer >= 1", "samples 682")
        if (p := P.get("size")) is not None:
            _size(p, 0.0)
        return RangerSensorSpec(pose, rmin, rmax, fov, samples, self._noise(P.get("noise")))

    def _stage3_sensors(self, c: _Inst, what: str) -> list[RangerSensorSpec]:
        P = c.props
        count = 0
        if (p := P.get("scount")) is not None:
            count = _int(p, "a number of transducers >= 0", "scount 8")
            _check(0 <= count <= 10_000, p, "a number of transducers >= 0", "scount 8")
        example = "sview [ 0 5.0 15 ]"
        view = [0.0, 5.0, 5.0]
        if (p := P.get("sview")) is not None:
            view = _nums(p, (3,), "[range_min range_max fov] (m, m, degrees)", example)
        out: list[RangerSensorSpec] = []
        for i in range(count):
            v = view
            if (p := P.get(f"sview[{i}]")) is not None:
                v = _nums(p, (3,), "[range_min range_max fov] (m, m, degrees)", example)
            vp = p if p is not None else P.get("sview")
            if vp is not None:
                _check(
                    v[1] > 0 and 0 <= v[0] <= v[1] and 0 < v[2] <= 360,
                    vp,
                    "0 <= min <= max, 0 < fov <= 360",
                    example,
                )
            sp = P.get(f"spose[{i}]")
            if sp is None:
                self.warn(c.tok, f"{what}: scount is {count} but spose[{i}] is missing; using [0 0 0]")
                pose: Pose = (0.0, 0.0, 0.0)
            else:
                pose = _pose(sp)
            out.append(RangerSensorSpec(pose, v[0], v[1], math.radians(v[2]), 1, 0.0))
        for key, p in P.items():
            if key.startswith("spose[") and _INDEX_RE.fullmatch(key[5:]) and int(key[6:-1]) >= count:
                self.warn(p.tok, f"'{key}' ignored: scount is {count}", key=("spose", p.tok.file, p.tok.line))
        return out

    def _blobfinder(self, c: _Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> BlobfinderSpec:
        name = self._device_name(c, counters)
        what = f"blobfinder '{c.type_name}' of '{robot.name}'"
        P = c.props
        self._check_keys(P, _BLOBFINDER_KEYS, what)
        b = BlobfinderSpec(name=name, pose=self._mount(c, offset), interval=self._interval(c, 0.1))
        cp = c.latest("colors", "channels")
        names: list[str] = []
        if cp is not None:
            names = _strs(cp, "a list of colour names", 'colors [ "green" "red" ]')
        kp = c.latest("colors_count", "channel_count")
        if kp is not None:
            count = _int(kp, "an integer >= 0", "colors_count 1")
            if count < 0 or count > len(names):
                raise WorldFileError(
                    f"'{kp.key}' is {count} but {len(names)} colours are listed; list that many "
                    "colours in colors [ ... ] or lower the count",
                    kp.at.file,
                    kp.at.line,
                )
            names = names[:count]
        for cname in names:
            try:
                b.colors.append(parse_color(cname))
            except ValueError as e:
                assert cp is not None
                self.warn(cp.at, f"{e}; that channel is skipped", key=("color", cp.tok.file, cname.lower()))
        if (p := c.latest("fov", "ptz")) is not None:
            if p.key == "ptz":
                v = _nums(p, (3,), "[pan tilt zoom] (degrees)", "ptz [ 0 0 60 ]")
                _check(0 < v[2] <= 360, p, "a zoom (fov) angle 0 < zoom <= 360 degrees", "ptz [ 0 0 60 ]")
                b.fov = math.radians(v[2])
            else:
                b.fov = self._fov(p, 60.0)
        if (p := c.latest("range", "range_max")) is not None:
            v = _num(p, "a positive range in metres", f"{p.key} 3.0")
            _check(v > 0, p, "a positive range in metres", f"{p.key} 3.0")
            b.range_max = v
        if (p := P.get("image")) is not None:
            v = _nums(p, (2,), "[width height] in pixels", "image [ 80 60 ]")
            _check(
                all(x >= 1 and x == int(x) and x < 1e6 for x in v),
                p,
                "[width height] in pixels",
                "image [ 80 60 ]",
            )
            b.image = (int(v[0]), int(v[1]))
        return b

    def _gripper(self, c: _Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> GripperSpec:
        name = self._device_name(c, counters)
        P = c.props
        self._check_keys(P, _GRIPPER_KEYS, f"gripper '{c.type_name}' of '{robot.name}'")
        g = GripperSpec(name=name, interval=self._interval(c, 0.1))
        g.pose = self._mount(c, offset) if "pose" in P else _compose(offset, g.pose)
        if (p := P.get("size")) is not None:
            sx, sy, _ = _size(p, 0.0)
            g.size = (sx, sy)
        for key in ("paddle_time", "lift_time"):
            if (p := P.get(key)) is not None:
                v = _num(p, "seconds >= 0", f"{key} 1.0")
                _check(v >= 0, p, "seconds >= 0", f"{key} 1.0")
                setattr(g, key, v)
        return g

    # ------------------------------------------------------------------ floorplan
    def _floorplan(self, inst: _Inst, name: str) -> FloorplanSpec:
        P = inst.props
        self._check_keys(P, _MODEL_KEYS, f"floorplan '{name}'")
        self._common(inst, ModelSpec(name=name))  # validates pose, size, colour, flags
        bp = P["bitmap"]
        rel = _str(bp, "a quoted image file name", 'bitmap "floor.png"').strip()
        _check(bool(rel), bp, "a quoted image file name", 'bitmap "floor.png"')
        path = Path(bp.tok.file).parent / rel
        try:
            exists = path.is_file()
        except (OSError, ValueError):
            exists = False
        if not exists:
            raise WorldFileError(
                f"bitmap file '{rel}' not found (looked for {path}); bitmap paths are relative to the "
                "file that sets them",
                bp.at.file,
                bp.at.line,
            )
        w, h = _image_size(path, rel, bp.at)
        px, py, pa = _pose(P["pose"]) if "pose" in P else (0.0, 0.0, 0.0)
        if pa != 0.0:
            self.warn(P["pose"].at, f"floorplan '{name}': rotation ignored, a bitmap is always axis-aligned")
        if (p := P.get("size")) is not None:
            sx, sy, _ = _size(p, 0.0)
            return FloorplanSpec(
                bitmap=path.absolute(),
                resolution=sx / w,
                origin=(px - sx / 2.0, py - sy / 2.0),
                size=(sx, sy),
                name=name,
            )
        res = _DEFAULT_MAP_RESOLUTION
        if (p := P.get("map_resolution")) is not None:
            res = _num(p, "metres per pixel > 0", "map_resolution 0.05")
            _check(res > 0, p, "metres per pixel > 0", "map_resolution 0.05")
        if (p := P.get("origin")) is not None:
            v = _nums(p, (2, 3, 4), "[x y] of the bottom-left corner in metres", "origin [ -31.475 -7.8 ]")
            origin = (v[0], v[1])
        else:
            origin = (px - w * res / 2.0, py - h * res / 2.0)
        return FloorplanSpec(bitmap=path.absolute(), resolution=res, origin=origin, size=None, name=name)


def _image_size(path: Path, rel: str, tok: _Tok) -> tuple[int, int]:
    from PIL import Image

    try:
        with Image.open(path) as im:
            w, h = im.size
    except Exception as e:  # Pillow raises many types for bad files; all mean "not an image"
        raise WorldFileError(
            f"bitmap '{rel}' is not an image Pillow can read ({type(e).__name__}); use a PNG",
            tok.file,
            tok.line,
        ) from None
    if w <= 0 or h <= 0:
        raise WorldFileError(f"bitmap '{rel}' is empty ({w} x {h} pixels)", tok.file, tok.line)
    return int(w), int(h)


def _read_text(path: Path, display: str, via: _Tok | None) -> str:
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


def load_stage_world(path: str | os.PathLike[str], *, seed: int | None = None) -> WorldSpec:
    """Read a Stage ``.world`` (or ``.inc``) file and the files it includes into a WorldSpec.

    ``seed`` overrides the world's ``seed`` keyword. Raises :class:`WorldFileError` (naming
    file:line and a fix) for any malformed input; warnings are in ``WorldSpec.warnings``.
    """
    display = os.fspath(path)
    loader = _StageLoader(display)
    with as_world_file_errors(display, "models or defines nested too deeply"):
        loader.load_file(Path(display), display, None)
        return loader.build(seed)
