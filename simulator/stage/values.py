"""Typed values of Stage properties, and the warnings of one load.

Converters from a property's tokens to numbers, poses, sizes and strings in SI units (Stage writes
angles in degrees: ``pose [x y z a]`` becomes ``(x, y, radians(a))``), each raising a
:class:`~simulator.errors.WorldFileError` that names the file:line, what was expected and an
example. :class:`Reporter` collects the warnings of a load, once each.
"""

from __future__ import annotations

import logging
import math

from ..errors import WorldFileError, did_you_mean
from .syntax import INDEX_RE, Prop, Tok, show

__all__ = ["Pose", "Reporter", "bad", "base_key", "boolean", "check", "compose", "integer", "num", "nums",
           "parse_pose", "parse_size", "string", "strings", "tok_float", "where"]  # fmt: skip

log = logging.getLogger("simulator.stageworld")

Pose = tuple[float, float, float]


def where(t: Tok) -> str:
    return f"{t.file}:{t.line}"


def bad(p: Prop, need: str, example: str, tok: Tok | None = None) -> WorldFileError:
    got = "[ " + " ".join(show(t) for t in p.values) + " ]" if p.array else " ".join(show(t) for t in p.values)
    t = tok or p.at
    if len(got) > 60:
        got = got[:57] + "..."
    return WorldFileError(f"'{p.key}' needs {need}, got {got}; write e.g. '{example}'", t.file, t.line)


def tok_float(t: Tok) -> float | None:
    if t.kind != "num":
        return None
    try:
        v = float(t.text)
    except ValueError:  # pragma: no cover - the tokenizer only lets valid numbers through
        return None
    return v if math.isfinite(v) else None


def num(p: Prop, need: str, example: str) -> float:
    if p.array or len(p.values) != 1 or (v := tok_float(p.values[0])) is None:
        raise bad(p, need, example)
    return v


def integer(p: Prop, need: str, example: str) -> int:
    v = num(p, need, example)
    if v != int(v) or abs(v) > 1e9:
        raise bad(p, need, example)
    return int(v)


def boolean(p: Prop, levels: bool = False) -> bool:
    """0 or 1 (or true/false); with ``levels``, any integer >= 0 (Stage 3's ``laser_return 2``
    meant "bright"), true when not 0."""
    if not p.array and len(p.values) == 1:
        t = p.values[0]
        v = tok_float(t)
        if v is not None and (v in (0.0, 1.0) or (levels and v >= 0 and v == int(v))):
            return v != 0.0
        if t.kind in ("word", "str") and t.text.lower() in ("true", "false"):
            return t.text.lower() == "true"
    raise bad(p, "0 or 1", f"{p.key} 1")


def string(p: Prop, need: str, example: str) -> str:
    if p.array or len(p.values) != 1 or p.values[0].kind not in ("str", "word"):
        raise bad(p, need, example)
    return p.values[0].text


def nums(p: Prop, counts: tuple[int, ...], need: str, example: str) -> list[float]:
    if not p.array or len(p.values) not in counts:
        raise bad(p, need, example)
    out: list[float] = []
    for t in p.values:
        v = tok_float(t)
        if v is None:
            raise bad(p, need, example, t)
        out.append(v)
    return out


def strings(p: Prop, need: str, example: str) -> list[str]:
    if not p.array:
        return [string(p, need, example)]
    for t in p.values:
        if t.kind not in ("str", "word"):
            raise bad(p, need, example, t)
    return [t.text for t in p.values]


def parse_pose(p: Prop) -> Pose:
    v = nums(p, (3, 4), "[x y z a] (metres and degrees)", f"{p.key} [ 1.0 2.0 0 90 ]")
    return (v[0], v[1], math.radians(v[-1]))


def parse_size(p: Prop, default_z: float) -> tuple[float, float, float]:
    example = f"{p.key} [ 0.44 0.38 0.22 ]"
    v = nums(p, (2, 3), "[x y z] in metres", example)
    if v[0] <= 0 or v[1] <= 0 or (len(v) == 3 and v[2] < 0):
        raise bad(p, "positive sizes [x y z] in metres", example)
    return (v[0], v[1], v[2] if len(v) == 3 else default_z)


def check(ok: bool, p: Prop, need: str, example: str) -> None:
    if not ok:
        raise bad(p, need, example)


def compose(a: Pose, b: Pose) -> Pose:
    """``a ⊕ b`` as Stage nests model poses (the yaw is not wrapped). The simulator depends on
    nothing of ours, so it keeps this instead of rsal.geometry.compose; tests/rsal/test_geometry.py
    checks that the two agree."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def base_key(key: str) -> str:
    return INDEX_RE.sub("", key)


class Reporter:
    """The warnings of one load: each is logged once and kept in :attr:`warnings`."""

    def __init__(self) -> None:
        self.warnings: list[str] = []
        self._warned: set[object] = set()
        self._unsimulated: dict[tuple[str, str, int], tuple[str, str]] = {}  # (what, file, line) -> entry, needs
        self._present: set[str] = set()  # "fiducial" (a fiducial finder), "power" (a power pack)

    def not_simulated(self, tok: Tok, what: str) -> None:
        """Note that ``what`` (e.g. ``"'watts'"`` or ``"model type 'camera'"``) written at ``tok``
        is not simulated; :meth:`report_not_simulated` lists every such note in one warning."""
        if what == "model type 'fiducial'":
            self._present.add("fiducial")
        needs = ""
        if what.startswith("'"):
            key = what.strip("'")
            needs = _NEEDS.get(key, "")
            if key in ("joules", "kjoules", "joules_capacity"):
                self._present.add("power")
        self._unsimulated.setdefault((what, tok.file, tok.line), (f"{what} at {where(tok)}", needs))

    def mark_present(self, what: str) -> None:
        """A simulated model that keywords of :data:`_NEEDS` act through (``"fiducial"``) exists."""
        self._present.add(what)

    def report_not_simulated(self, display: str) -> None:
        """The one warning naming everything a load recognised but does not simulate."""
        entries = [e for e, needs in self._unsimulated.values() if not needs or needs in self._present]
        if entries:
            self.warn_text(f"{display}: not simulated (ignored): " + ", ".join(entries))

    def scope_not_simulated(self, props: dict[str, Prop], known: frozenset[str]) -> None:
        """Note every property of ``props`` whose keyword is in ``known`` (not simulated), unless
        its value is all zeros or ``localization "odom"``: Stage's "off", which is what we do."""
        for key, p in props.items():
            if base_key(key) in known and not _is_off(p):
                self.not_simulated(p.tok, f"'{key}'")

    def warn_text(self, text: str) -> None:
        if text in self._warned:
            return
        self._warned.add(text)
        self.warnings.append(text)
        log.warning("%s", text)

    def warn(self, tok: Tok, message: str, key: object = None) -> None:
        text = f"{where(tok)}: {message}"
        k = key if key is not None else text
        if k in self._warned:
            return
        self._warned.add(k)
        self.warnings.append(text)
        log.warning("%s", text)

    def check_keys(self, props: dict[str, Prop], known: frozenset[str], what: str) -> None:
        for key, p in props.items():
            base = base_key(key)
            if base in known or base.startswith("gui_"):
                continue
            hint = did_you_mean(base, sorted(known))
            hint = f"; {hint}" if hint else ""
            self.warn(p.tok, f"unknown keyword '{key}' in {what} ignored{hint}", key=("key", p.tok.file, key))


# Keywords that only act through another model (Stage): fiducial_return/fiducial_key are seen by
# fiducial finders, watts draw from a power pack (a model with joules). Without one they do nothing.
_NEEDS = {"fiducial_return": "fiducial", "fiducial_key": "fiducial", "watts": "power", "give_watts": "power",
          "take_watts": "power"}  # fmt: skip


def _is_off(p: Prop) -> bool:
    if p.key == "localization":
        return len(p.values) == 1 and p.values[0].text == "odom"
    return bool(p.values) and all(tok_float(t) == 0.0 for t in p.values)
