"""Driver parameters: a driver declares its configuration keys as a dataclass, parsed once.

Player drivers read their options one by one from the ``.cfg`` block (``cf->ReadInt(section,
"baud", 9600)``); ir-sim parses its YAML into dataclasses and answers an unknown key with "did you
mean". This module is the one implementation of that for every driver of :mod:`mrs_bridge`::

    @dataclass(frozen=True)
    class HokuyoParams:
        port: str = param(doc="the sensor's serial device", example="/dev/ttyACM0")   # required
        baud: int = param(115200, min=300, max=1_000_000)
        model: str = param("URG-04LX", choices=tuple(MODELS))
        timeout: float = param(1.0, gt=0, unit="seconds")

        def __post_init__(self):                     # checks across keys: raise ValueError(text)
            ...

    p = parse_params(HokuyoParams, cfg)              # cfg: the driver block (DriverConfig)

What :func:`parse_params` does, in this order, each failure one :class:`~mrs_bridge.config.ConfigError`
line ``"<file>: driver #n (name): <what>"`` naming the key and a fix:

- an unknown key: ``unknown parameter 'buad'; did you mean 'baud'?`` (difflib), else the known keys;
  keys in the class's ``IGNORED`` (Player options with no effect here) are logged and dropped;
- a missing key without a default: ``needs 'port', <doc> (e.g. port = "/dev/ttyS0")``;
- types from the annotations, coerced: ``int`` (no floats, no booleans), ``float`` (ints accepted,
  finite unless ``finite=False``), ``bool``, ``str``, ``Path`` (relative to the config file),
  ``tuple[float, ...]`` / ``tuple[float, float, float]`` / ``tuple[str, ...]`` from TOML lists,
  ``Literal[...]`` choices (and ``choices=`` for choices known at run time) with "did you mean" for
  strings, ``X | None`` (``None`` = not given), ``Any`` (passed as it is); a field named after a
  Python keyword with a trailing ``_`` (``global_``) reads the key without it (``global``);
- ranges from the field's metadata: ``min``/``max`` (inclusive), ``gt``/``lt`` (exclusive);
- the dataclass's own ``__post_init__`` for checks across keys: its ``ValueError`` text is prefixed
  with the block.

The text after ``key = value`` is ``must be <expect>``: generated from type, range and ``unit``
(``"an integer >= 1"``, ``"a number of seconds in [0.2, 30]"``), or the field's ``expect``.
:func:`did_you_mean` is the platform's one "did you mean" (config keys, driver names, algorithm
parameters, scenario files): it lives in :mod:`rsal.suggest` and is re-exported here.
"""

from __future__ import annotations

import dataclasses
import json
import keyword
import math
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, Union

from rsal.suggest import did_you_mean

from .config import ConfigError, DriverConfig

__all__ = ["param", "parse_params", "did_you_mean", "unknown_key", "describe_params"]

T = TypeVar("T")
_MISSING = dataclasses.MISSING


def unknown_key(key: str, known: Iterable[str], *, what: str = "parameter", cutoff: float = 0.6) -> str:
    """``unknown parameter 'x'; did you mean 'y'?`` or ``...; known: a, b, c``."""
    known = list(known)
    close = did_you_mean(key, known, cutoff=cutoff)
    hint = f"did you mean {close!r}?" if close else f"known: {', '.join(known)}"
    return f"unknown {what} {key!r}; {hint}"


def param(
    default: Any = _MISSING,
    *,
    min: float | None = None,  # noqa: A002 - the natural names in a declaration
    max: float | None = None,  # noqa: A002
    gt: float | None = None,
    lt: float | None = None,
    unit: str = "",
    doc: str = "",
    example: Any = None,
    choices: tuple | None = None,
    expect: str | None = None,
    missing: str | None = None,
    finite: bool = True,
) -> Any:
    """A dataclass field with the parsing metadata described in the module docstring. Without
    ``default`` the key is required (``doc`` and ``example`` make the "needs" message, or ``missing``
    replaces it). ``expect`` replaces the generated "must be ..." text for values out of range."""
    meta = {
        "min": min,
        "max": max,
        "gt": gt,
        "lt": lt,
        "unit": unit,
        "doc": doc,
        "example": example,
        "choices": choices,
        "expect": expect,
        "missing": missing,
        "finite": finite,
    }
    if isinstance(default, list | dict | set):
        raise TypeError("param(): use a tuple (immutable) as the default of a list parameter")
    return dataclasses.field(default=default, metadata={"param": meta})


def parse_params(
    cls: type[T],
    cfg: DriverConfig | Mapping[str, Any],
    where: str | None = None,
    *,
    rest: bool = False,
    log=None,
) -> T:
    """Build ``cls`` from a driver block's parameters (a :class:`DriverConfig` or a plain mapping);
    raises :class:`ConfigError` with one line naming ``where`` (default: the block), the key and a
    fix. With ``rest=True`` unknown keys are not errors: ``(params, {unknown: value})`` is returned
    for another parser (the ``amcl`` driver hands them to the filter's parameters)."""
    if isinstance(cfg, DriverConfig):
        raw, where, base = cfg.params, where or cfg.where, cfg.base_dir
    else:
        raw, where, base = cfg, where or f"<{cls.__name__}>", Path.cwd()
    hints = typing.get_type_hints(cls)
    fields = [f for f in dataclasses.fields(cls) if f.init]
    names = [_key(f) for f in fields]
    ignored = getattr(cls, "IGNORED", ())
    extra: dict[str, Any] = {}
    for k in raw:
        if k in names:
            continue
        if k in ignored:
            if log is not None:
                log.warning("%s: Player option %r has no effect here", where, k)
            continue
        if rest:
            extra[k] = raw[k]
            continue
        raise ConfigError(f"{where}: {unknown_key(k, names)}")
    kw: dict[str, Any] = {}
    for f in fields:
        meta, key = f.metadata.get("param", {}), _key(f)
        if key not in raw:
            if f.default is _MISSING and f.default_factory is _MISSING:
                raise ConfigError(f"{where}: {_missing(key, meta)}")
            continue
        kw[f.name] = _convert(key, raw[key], hints[f.name], meta, base, where)
    try:
        obj = cls(**kw)
    except ConfigError:
        raise
    except ValueError as e:
        raise ConfigError(f"{where}: {e}") from None
    return (obj, extra) if rest else obj  # type: ignore[return-value]


def describe_params(cls: type) -> list[dict[str, Any]]:
    """One row per parameter (name, type, default, range, unit, doc): for docs and ``--help``."""
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        meta = f.metadata.get("param", {})
        rows.append(
            {
                "name": _key(f),
                "type": _type_name(hints[f.name]),
                "default": None if f.default is _MISSING else f.default,
                "required": f.default is _MISSING and f.default_factory is _MISSING,
                "expect": _expect(hints[f.name], meta),
                "doc": meta.get("doc", ""),
            }
        )
    return rows


# ---------------------------------------------------------------------------- conversion
def _key(f: dataclasses.Field) -> str:
    """The configuration key of a field: its name, without the ``_`` of a Python keyword (``global_``)."""
    return f.name[:-1] if f.name.endswith("_") and keyword.iskeyword(f.name[:-1]) else f.name


def _missing(key: str, meta: Mapping[str, Any]) -> str:
    if meta.get("missing"):
        return meta["missing"]
    text = f"needs {key!r}"
    if meta.get("doc"):
        text += f", {meta['doc']}"
    if meta.get("example") is not None:
        text += f" (e.g. {key} = {_toml(meta['example'])})"
    return text


def _toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, tuple):
        v = list(v)
    return json.dumps(v)


def _optional(tp: Any) -> tuple[Any, bool]:
    """``(X, True)`` for ``X | None``, else ``(tp, False)``."""
    if typing.get_origin(tp) in (Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0], True
    return tp, False


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _num(x: float) -> str:
    return f"{x:g}"


def _range_text(meta: Mapping[str, Any]) -> str:
    lo, hi, gt, lt = meta.get("min"), meta.get("max"), meta.get("gt"), meta.get("lt")
    low = (f"[{_num(lo)}", lo) if lo is not None else ((f"({_num(gt)}", gt) if gt is not None else None)
    high = (f"{_num(hi)}]", hi) if hi is not None else ((f"{_num(lt)})", lt) if lt is not None else None)
    if low and high:
        return f" in {low[0]}, {high[0]}"
    if low:
        return f" >= {_num(lo)}" if lo is not None else f" > {_num(gt)}"
    if high:
        return f" <= {_num(hi)}" if hi is not None else f" < {_num(lt)}"
    return ""


def _kind(tp: Any, meta: Mapping[str, Any], *, finite_word: bool) -> str:
    unit = meta.get("unit", "")
    if tp is int:
        base = "an integer"
    else:
        base = "a finite number" if finite_word and meta.get("finite", True) else "a number"
    return base + (f" of {unit}" if unit else "") + _range_text(meta)


def _expect(tp: Any, meta: Mapping[str, Any]) -> str:
    if meta.get("expect"):
        return meta["expect"]
    tp, _ = _optional(tp)
    choices = meta.get("choices") or (typing.get_args(tp) if typing.get_origin(tp) is Literal else None)
    if choices:
        return "one of " + ", ".join(str(c) for c in choices)
    if tp in (int, float):
        return _kind(tp, meta, finite_word=False)
    if tp is bool:
        return "true or false"
    if tp in (str, Path):
        return "a string"
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        what = "strings" if args and args[0] is str else "numbers"
        n = "" if len(args) == 2 and args[1] is Ellipsis else f"{len(args)} "
        return f"a list of {n}{what}"
    return "a valid value"


def _convert(key: str, v: Any, tp: Any, meta: Mapping[str, Any], base: Path, where: str) -> Any:
    tp, optional = _optional(tp)

    def bad(expect: str | None = None) -> ConfigError:
        text = expect or _expect(tp, meta)
        hint = ""
        if isinstance(v, str) and choices:
            close = did_you_mean(v, [str(c) for c in choices])
            hint = f"; did you mean {close!r}?" if close else ""
        return ConfigError(f"{where}: {key} = {v!r} must be {text}{hint}")

    choices = meta.get("choices") or (typing.get_args(tp) if typing.get_origin(tp) is Literal else None)
    if v is None and optional:
        return None
    if choices:
        if isinstance(v, bool) or v not in choices or type(v) is not type(next(c for c in choices if c == v)):
            raise bad()
        return v
    if tp is Any:
        return v
    if tp is bool:
        if not isinstance(v, bool):
            raise bad()
        return v
    if tp in (int, float):
        if isinstance(v, bool) or not isinstance(v, int | float) or (tp is int and not isinstance(v, int)):
            raise bad(meta.get("expect") if tp is int else _kind(tp, meta, finite_word=True))
        if tp is float and meta.get("finite", True) and not math.isfinite(v):
            raise bad(_kind(tp, meta, finite_word=True))
        lo, hi, gt, lt = meta.get("min"), meta.get("max"), meta.get("gt"), meta.get("lt")
        if (
            (lo is not None and not v >= lo)
            or (hi is not None and not v <= hi)
            or (gt is not None and not v > gt)
            or (lt is not None and not v < lt)
        ):
            raise bad()
        return tp(v)
    if tp is str:
        if not isinstance(v, str) or not v:
            raise bad()
        return v
    if tp is Path:
        if not isinstance(v, str) or not v:
            raise bad()
        p = Path(v)
        return p if p.is_absolute() else base / p
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        of_str = bool(args) and args[0] is str
        if of_str and isinstance(v, str):
            v = [v]
        if not isinstance(v, list | tuple):
            raise bad()
        if not (len(args) == 2 and args[1] is Ellipsis) and len(v) != len(args):
            raise bad()
        if of_str:
            if not all(isinstance(s, str) and s for s in v):
                raise bad()
            return tuple(v)
        if not all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in v):
            raise bad()
        return tuple(float(x) for x in v)
    raise TypeError(f"parse_params: {key}: unsupported parameter type {tp!r}")
