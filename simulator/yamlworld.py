"""Loader for the YAML world format: an easier front end than Stage's ``.world`` syntax.

Produces the same :class:`~simulator.spec.WorldSpec` as :mod:`simulator.stageworld` (the Stage
world file format of thesis appendix A.1, A.5, A.6), with robots, devices and objects taken from
the presets of :mod:`simulator.presets`. Units are SI, except yaw and field-of-view angles, which
are degrees as in Stage files::

    world: {interval_sim: 0.1, speedup: 1.0, seed: 1}   # s per step; speedup: a number or "max"
    floorplan: {bitmap: testroom.png, resolution: 0.05, origin: [-5.0, -4.0]}
    #      or: {bitmap: testroom.png, size: [10.0, 8.0], pose: [0.0, 0.0]}   (Stage placement)
    robots:
      - name: r0
        type: pioneer2dx            # pioneer2dx | pioneer3at (default pioneer2dx)
        pose: [-3.0, 0.0, 90]       # x m, y m, yaw degrees
        color: red
        sonar: true                 # keep the preset's sonar ring (default true)
        devices:
          - {type: laser, model: urg04lx, pose: [0.13, 0, 0]}   # or fov/samples/range/noise
          - {type: sonar, model: pioneer2dx_sonar}              # or sensors: [{pose, fov, range}]
          - {type: blobfinder, colors: [green], fov: 90, range: 3, image: [80, 60]}
          - {type: gripper}
          - {type: bumper, model: pioneer}      # or segments: [{pose: [x, y, yaw], length: 0.1}]
          - {type: fiducial, range: [0, 8], range_id: 5, fov: 180, key: 0}
        fiducial_return: 1          # id fiducial finders read (0: not seen); fiducial_key: 0
    objects:
      - {name: blob0, type: blob, pose: [1.0, 2.0, 0], color: green}   # blob | box

Robots may also override ``size``, ``mass``, ``max_speed [m/s, deg/s]``, ``max_accel``,
``odom_error``, ``odom_noise``, the ``*_return`` flags and ``fiducial_return``/``fiducial_key``;
objects ``size``, ``mass``, the flags, ``fiducial_return`` and ``fiducial_key``.
The bitmap path is relative to the YAML file. Unknown keys are skipped with a warning (with a
"did you mean"); wrong types, missing required keys (robot and object ``name``, object ``type``,
floorplan ``bitmap``) and duplicate model names raise :class:`~simulator.errors.WorldFileError`
naming file:line and a fix.
"""

from __future__ import annotations

import difflib
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from .errors import WorldFileError, as_world_file_errors
from .presets import DEVICE_PRESETS, OBJECT_PRESETS, ROBOT_PRESETS, pioneer_bumper
from .spec import (
    BlobfinderSpec,
    BumperSegmentSpec,
    BumperSpec,
    FiducialSpec,
    FloorplanSpec,
    GripperSpec,
    ModelSpec,
    RangerSensorSpec,
    RangerSpec,
    WorldSpec,
    parse_color,
)

__all__ = ["load_yaml_world"]

log = logging.getLogger(__name__)

Pose = tuple[float, float, float]

_TOP_KEYS = ("world", "floorplan", "robots", "objects")
_WORLD_KEYS = ("interval_sim", "speedup", "seed", "name")
_FLOORPLAN_KEYS = ("bitmap", "resolution", "origin", "size", "pose", "threshold", "name")
_FLAG_KEYS = ("obstacle_return", "laser_return", "blob_return", "gripper_return")
_FIDUCIAL_KEYS = ("fiducial_return", "fiducial_key")
_ROBOT_KEYS = (
    "name", "type", "pose", "color", "sonar", "devices", "size", "mass", "max_speed", "max_accel",
    "odom_error", "odom_noise", "drive", *_FLAG_KEYS, *_FIDUCIAL_KEYS,
)  # fmt: skip
_OBJECT_KEYS = ("name", "type", "pose", "color", "size", "mass", *_FLAG_KEYS, *_FIDUCIAL_KEYS)
_DEVICE_KEYS: dict[str, tuple[str, ...]] = {
    "laser": ("type", "name", "model", "pose", "fov", "samples", "range", "noise", "interval"),
    "sonar": ("type", "name", "model", "pose", "sensors", "interval"),
    "blobfinder": ("type", "name", "pose", "colors", "fov", "range", "image", "interval"),
    "gripper": ("type", "name", "pose", "size", "paddle_time", "lift_time", "interval"),
    "bumper": ("type", "name", "model", "pose", "segments", "interval"),
    "fiducial": ("type", "name", "pose", "range", "range_id", "fov", "key", "noise", "interval"),
}
_SEGMENT_KEYS = ("pose", "length")
_SENSOR_KEYS = ("pose", "fov", "samples", "range", "noise")
_DEVICE_MODELS = {
    "laser": ("urg04lx", "utm30lx"),
    "sonar": ("pioneer2dx_sonar", "pioneer3at_sonar"),
}
_DEFAULT_RESOLUTION = 0.05
_Device = RangerSpec | BlobfinderSpec | GripperSpec | BumperSpec | FiducialSpec


# ---------------------------------------------------------------------------------- YAML with lines
class _Map(dict):
    """A YAML mapping that remembers the line of itself and of each key (1-based)."""

    line: int = 0
    key_lines: dict[Any, int]

    def line_of(self, key: str) -> int:
        return self.key_lines.get(key, self.line)


class _Seq(list):
    """A YAML sequence that remembers the line of itself and of each item (1-based)."""

    line: int = 0
    item_lines: list[int]

    def line_at(self, i: int) -> int:
        return self.item_lines[i] if i < len(self.item_lines) else self.line


class _LineLoader(yaml.SafeLoader):
    """``yaml.safe_load`` semantics, but mappings and sequences carry their line numbers."""

    duplicates: list[tuple[str, int]]


def _construct_map(loader: _LineLoader, node: yaml.MappingNode):  # type: ignore[no-untyped-def]
    data = _Map()
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


def _construct_seq(loader: _LineLoader, node: yaml.SequenceNode):  # type: ignore[no-untyped-def]
    data = _Seq()
    data.line = node.start_mark.line + 1
    data.item_lines = [n.start_mark.line + 1 for n in node.value]
    yield data
    data.extend(loader.construct_sequence(node))


_LineLoader.add_constructor("tag:yaml.org,2002:map", _construct_map)
_LineLoader.add_constructor("tag:yaml.org,2002:seq", _construct_seq)


# ---------------------------------------------------------------------------------- validation
def _is_num(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _short(v: object) -> str:
    r = repr(v)
    return r if len(r) <= 50 else r[:47] + "..."


class _YamlWorld:
    def __init__(self, display: str):
        self.file = display
        self.dir = Path(display).parent
        self.warnings: list[str] = []

    # ------------------------------------------------------------------ messages
    def error(self, line: int, message: str) -> WorldFileError:
        return WorldFileError(message, self.file, line)

    def warn(self, line: int, message: str) -> None:
        text = f"{self.file}:{line}: {message}"
        self.warnings.append(text)
        log.warning("%s", text)

    def check_keys(self, m: _Map, known: Sequence[str], where: str) -> None:
        for key in m:
            if key in known:
                continue
            if not isinstance(key, str):
                raise self.error(m.line_of(key), f"{where}: key {key!r} must be a name such as '{known[0]}'")
            close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
            hint = f"did you mean '{close[0]}'? " if close else ""
            self.warn(m.line_of(key), f"unknown key '{key}' in {where} ignored; {hint}known: {', '.join(known)}")

    def mapping(self, v: object, line: int, where: str, example: str) -> _Map:
        if not isinstance(v, _Map):
            raise self.error(line, f"{where} must be a mapping, got {_short(v)}; e.g. {example}")
        return v

    def sequence(self, m: _Map, key: str, where: str, example: str) -> _Seq:
        v = m.get(key)
        if v is None:
            return _Seq()
        if not isinstance(v, _Seq):
            raise self.error(m.line_of(key), f"{where}.{key} must be a list, got {_short(v)}; e.g. {example}")
        return v

    # ------------------------------------------------------------------ scalars
    def num(
        self,
        m: _Map,
        key: str,
        where: str,
        default: float,
        *,
        lo: float | None = None,
        positive: bool = False,
        unit: str = "",
    ) -> float:
        if key not in m:
            return default
        v = m[key]
        ok = _is_num(v) and (lo is None or v >= lo) and (not positive or v > 0)
        if not ok:
            need = "a positive number" if positive else (f"a number >= {lo:g}" if lo is not None else "a number")
            ex = default if _is_num(default) and default > 0 else 1.0
            raise self.error(m.line_of(key), f"{where}.{key} must be {need}{unit}, got {_short(v)}; e.g. {key}: {ex:g}")
        return float(v)

    def integer(self, m: _Map, key: str, where: str, default: int) -> int:
        if key not in m:
            return default
        v = m[key]
        if not isinstance(v, int) or isinstance(v, bool):
            raise self.error(m.line_of(key), f"{where}.{key} must be an integer, got {_short(v)}; e.g. {key}: 1")
        return v

    def flag(self, m: _Map, key: str, where: str, default: bool) -> bool:
        if key not in m:
            return default
        v = m[key]
        if isinstance(v, bool):
            return v
        if isinstance(v, int) and v in (0, 1):
            return bool(v)
        raise self.error(m.line_of(key), f"{where}.{key} must be true or false, got {_short(v)}")

    def text(self, m: _Map, key: str, where: str, default: str | None = None, *, required: bool = False) -> str:
        if key not in m:
            if required:
                raise self.error(m.line, f"{where} needs '{key}'; add e.g. {key}: {default or 'r0'}")
            return default or ""
        v = m[key]
        if not isinstance(v, str) or not v.strip():
            raise self.error(m.line_of(key), f"{where}.{key} must be a non-empty string, got {_short(v)}")
        return v.strip()

    def numbers(self, m: _Map, key: str, where: str, counts: tuple[int, ...], example: str) -> list[float]:
        v = m[key]
        if not isinstance(v, list) or len(v) not in counts or not all(_is_num(x) for x in v):
            n = " or ".join(str(c) for c in counts)
            raise self.error(
                m.line_of(key),
                f"{where}.{key} must be a list of {n} numbers, got {_short(v)}; e.g. {example}",
            )
        return [float(x) for x in v]

    def pose(self, m: _Map, key: str, where: str, default: Pose = (0.0, 0.0, 0.0)) -> Pose:
        if key not in m:
            return default
        v = self.numbers(m, key, where, (2, 3), f"{key}: [1.0, 2.0, 90]   # x m, y m, yaw degrees")
        return (v[0], v[1], math.radians(v[2]) if len(v) == 3 else 0.0)

    def size(self, m: _Map, key: str, where: str, default: Sequence[float]) -> tuple[float, float, float]:
        if key not in m:
            return (float(default[0]), float(default[1]), float(default[2]))
        example = f"{key}: [0.44, 0.38, 0.22]"
        v = self.numbers(m, key, where, (2, 3), example)
        if v[0] <= 0 or v[1] <= 0 or (len(v) == 3 and v[2] < 0):
            raise self.error(m.line_of(key), f"{where}.{key} must be positive sizes in metres; e.g. {example}")
        return (v[0], v[1], v[2] if len(v) == 3 else float(default[2]))

    def color(self, m: _Map, key: str, where: str, default: tuple[int, int, int]) -> tuple[int, int, int]:
        if key not in m:
            return default
        v = m[key]
        try:
            if isinstance(v, str) or (isinstance(v, list) and all(_is_num(x) for x in v)):
                return parse_color(v)
            raise ValueError(f"unknown colour {_short(v)}")
        except ValueError as e:
            raise self.error(
                m.line_of(key), f"{where}.{key}: {e}; use a name such as 'green', '#00ff00' or [r, g, b]"
            ) from None

    def choice(self, m: _Map, key: str, where: str, options: Sequence[str], default: str | None = None) -> str:
        if key not in m:
            if default is None:
                raise self.error(m.line, f"{where} needs '{key}': one of {', '.join(options)}")
            return default
        v = m[key]
        if isinstance(v, str) and v in options:
            return v
        close = difflib.get_close_matches(str(v), list(options), n=1, cutoff=0.6) if isinstance(v, str) else []
        hint = f"did you mean '{close[0]}'? " if close else ""
        raise self.error(
            m.line_of(key), f"{where}.{key} {_short(v)} is not known; {hint}use one of {', '.join(options)}"
        )

    # ------------------------------------------------------------------ sections
    def build(self, doc: object, seed: int | None) -> WorldSpec:
        if doc is None:
            raise self.error(1, "the world file is empty; add at least 'robots:' (see simulator/yamlworld.py)")
        top = self.mapping(doc, 1, "the world file", "world: {interval_sim: 0.1}  robots: [...]")
        self.check_keys(top, _TOP_KEYS, "the world file")
        spec = WorldSpec(source=self.file)
        if top.get("world") is not None:
            self.world(self.mapping(top["world"], top.line_of("world"), "world", "{interval_sim: 0.1}"), spec)
        if top.get("floorplan") is not None:
            fp = self.mapping(top["floorplan"], top.line_of("floorplan"), "floorplan", "{bitmap: map.png}")
            spec.floorplan = self.floorplan(fp)
        seen: dict[str, int] = {}
        for section, make in (("robots", self.robot), ("objects", self.obj)):
            items = self.sequence(top, section, "the world file", f"{section}: [{{name: x0, type: ...}}]")
            for i, item in enumerate(items):
                where = f"{section}[{i}]"
                m = self.mapping(item, items.line_at(i), where, "{name: r0, type: pioneer2dx}")
                model = make(m, where)
                if model.name in seen:
                    raise self.error(
                        m.line_of("name"),
                        f"{where}: two models are named '{model.name}' (the first on line "
                        f"{seen[model.name]}); give each a unique name",
                    )
                seen[model.name] = m.line_of("name")
                model.source = f"{self.file}:{m.line}"
                spec.models.append(model)
        if seed is not None:
            spec.seed = int(seed)
        spec.warnings = list(self.warnings)
        return spec

    def world(self, m: _Map, spec: WorldSpec) -> None:
        self.check_keys(m, _WORLD_KEYS, "world")
        spec.interval_sim = self.num(m, "interval_sim", "world", spec.interval_sim, positive=True, unit=" (s)")
        if "speedup" in m:
            v = m["speedup"]
            if isinstance(v, str) and v.strip().lower() in ("max", "inf", "fast"):
                spec.speedup = math.inf
            elif isinstance(v, int | float) and not isinstance(v, bool) and v > 0:
                spec.speedup = float(v)
            else:
                raise self.error(
                    m.line_of("speedup"),
                    f"world.speedup must be a positive real-time factor or 'max', got {_short(v)}; "
                    "e.g. speedup: 1.0 or speedup: max",
                )
        spec.seed = self.integer(m, "seed", "world", spec.seed)
        if "name" in m:
            self.text(m, "name", "world")

    def floorplan(self, m: _Map) -> FloorplanSpec:
        where = "floorplan"
        self.check_keys(m, _FLOORPLAN_KEYS, where)
        rel = self.text(m, "bitmap", where, "map.png", required=True)
        line = m.line_of("bitmap")
        path = self.dir / rel
        try:
            exists = path.is_file()
        except (OSError, ValueError):
            exists = False
        if not exists:
            raise self.error(
                line,
                f"floorplan.bitmap '{rel}' not found (looked for {path}); the path is relative to this file",
            )
        w, h = _image_size(path, rel, self.file, line)
        name = self.text(m, "name", where, "floorplan")
        threshold = self.num(m, "threshold", where, 0.5, positive=True)
        if threshold >= 1:
            raise self.error(m.line_of("threshold"), "floorplan.threshold must be between 0 and 1; e.g. 0.5")
        cx = cy = 0.0
        if "pose" in m:
            v = self.numbers(m, "pose", where, (2, 3), "pose: [0.0, 0.0]   # centre of the map, m")
            cx, cy = v[0], v[1]
        if "size" in m:
            if "resolution" in m or "origin" in m:
                raise self.error(
                    m.line_of("size"),
                    "floorplan: give either size (+ pose, Stage placement) or resolution (+ origin, "
                    "mapfile placement), not both",
                )
            sx, sy, _ = self.size(m, "size", where, (1.0, 1.0, 0.0))
            return FloorplanSpec(
                bitmap=path.absolute(),
                resolution=sx / w,
                origin=(cx - sx / 2.0, cy - sy / 2.0),
                size=(sx, sy),
                name=name,
                threshold=threshold,
            )
        res = self.num(m, "resolution", where, _DEFAULT_RESOLUTION, positive=True, unit=" (m/pixel)")
        if "origin" in m:
            if "pose" in m:
                raise self.error(
                    m.line_of("pose"),
                    "floorplan: give either origin (bottom-left corner) or pose (centre), not both",
                )
            v = self.numbers(m, "origin", where, (2,), "origin: [-5.0, -4.0]   # bottom-left corner, m")
            origin = (v[0], v[1])
        else:
            origin = (cx - w * res / 2.0, cy - h * res / 2.0)
        return FloorplanSpec(
            bitmap=path.absolute(), resolution=res, origin=origin, size=None, name=name, threshold=threshold
        )

    def _common(self, m: _Map, where: str, spec: ModelSpec) -> None:
        spec.size = self.size(m, "size", where, spec.size)
        spec.mass = self.num(m, "mass", where, spec.mass, lo=0.0, unit=" (kg)")
        for key in _FLAG_KEYS:
            setattr(spec, key, self.flag(m, key, where, getattr(spec, key)))
        for key in _FIDUCIAL_KEYS:
            setattr(spec, key, self.integer(m, key, where, getattr(spec, key)))

    def robot(self, m: _Map, where: str) -> ModelSpec:
        name = self.text(m, "name", where, "r0", required=True)
        where = f"{where} ({name})"
        self.check_keys(m, _ROBOT_KEYS, where)
        kind = self.choice(m, "type", where, sorted(ROBOT_PRESETS), "pioneer2dx")
        pose = self.pose(m, "pose", where)
        spec = ROBOT_PRESETS[kind](name, pose)
        spec.color = self.color(m, "color", where, spec.color)
        if not self.flag(m, "sonar", where, True):
            spec.rangers = [r for r in spec.rangers if r.kind != "sonar"]
        self._common(m, where, spec)
        for key in ("max_speed", "max_accel"):
            if key in m:
                example = f"{key}: [1.0, 100]   # m/s (m/s^2), deg/s (deg/s^2)"
                v = self.numbers(m, key, where, (2,), example)
                if min(v) < 0:
                    raise self.error(m.line_of(key), f"{where}.{key} must not be negative; e.g. {example}")
                setattr(spec, key, (v[0], math.radians(v[1])))
        for key in ("odom_error", "odom_noise"):
            if key in m:
                example = f"{key}: [0.03, 0.03, 0.05]   # fractions of x, y, yaw motion"
                v = self.numbers(m, key, where, (3,), example)
                if min(v) < 0:
                    raise self.error(m.line_of(key), f"{where}.{key} must not be negative; e.g. {example}")
                setattr(spec, key, (v[0], v[1], v[2]))
        if "drive" in m:
            drive = self.text(m, "drive", where)
            if drive != "diff":
                self.warn(m.line_of("drive"), f"{where}: drive '{drive}' is not simulated; using 'diff'")
        devices = self.sequence(m, "devices", where, "devices: [{type: laser, model: urg04lx}]")
        for i, item in enumerate(devices):
            dwhere = f"{where}.devices[{i}]"
            d = self.mapping(item, devices.line_at(i), dwhere, "{type: laser, model: urg04lx}")
            dev = self.device(d, dwhere, spec.size)
            if isinstance(dev, RangerSpec):
                spec.rangers.append(dev)
            elif isinstance(dev, BlobfinderSpec):
                spec.blobfinders.append(dev)
            elif isinstance(dev, BumperSpec):
                spec.bumpers.append(dev)
            elif isinstance(dev, FiducialSpec):
                spec.fiducials.append(dev)
            else:
                spec.grippers.append(dev)
        return spec

    def obj(self, m: _Map, where: str) -> ModelSpec:
        name = self.text(m, "name", where, "blob0", required=True)
        where = f"{where} ({name})"
        self.check_keys(m, _OBJECT_KEYS, where)
        kind = self.choice(m, "type", where, sorted(OBJECT_PRESETS))
        spec = OBJECT_PRESETS[kind](name, self.pose(m, "pose", where))
        spec.color = self.color(m, "color", where, spec.color)
        self._common(m, where, spec)
        return spec

    # ------------------------------------------------------------------ devices
    def device(self, m: _Map, where: str, size: Sequence[float] = (0.44, 0.38, 0.22)) -> _Device:
        kind = self.choice(m, "type", where, list(_DEVICE_KEYS))
        self.check_keys(m, _DEVICE_KEYS[kind], f"{where} ({kind})")
        pose = self.pose(m, "pose", where)
        dev: _Device
        if kind == "bumper":
            dev = self.bumper(m, where, pose, size)
        elif kind == "fiducial":
            dev = self.fiducial(m, where, pose)
        elif kind in _DEVICE_MODELS:
            dev = self.ranger(m, where, kind, pose)
        elif kind == "blobfinder":
            b = BlobfinderSpec(pose=pose)
            if "colors" in m:
                colors = m["colors"]
                if not isinstance(colors, list):
                    colors = [colors]
                for c in colors:
                    try:
                        if not isinstance(c, str | list):
                            raise ValueError(f"unknown colour {_short(c)}")
                        b.colors.append(parse_color(c))
                    except (ValueError, TypeError) as e:
                        raise self.error(
                            m.line_of("colors"), f"{where}.colors: {e}; e.g. colors: [green, red]"
                        ) from None
            else:
                b.colors.append(parse_color("green"))
            b.fov = math.radians(self.fov(m, where, math.degrees(b.fov)))
            b.range_max = self.num(m, "range", where, b.range_max, positive=True, unit=" (m)")
            if "image" in m:
                v = self.numbers(m, "image", where, (2,), "image: [80, 60]")
                if not all(1 <= x < 1e6 and x == int(x) for x in v):
                    raise self.error(m.line_of("image"), f"{where}.image must be [width, height] in pixels")
                b.image = (int(v[0]), int(v[1]))
            dev = b
        else:
            g = GripperSpec()
            if "pose" in m:
                g.pose = pose
            if "size" in m:
                sx, sy, _ = self.size(m, "size", where, (*g.size, 0.0))
                g.size = (sx, sy)
            g.paddle_time = self.num(m, "paddle_time", where, g.paddle_time, lo=0.0, unit=" (s)")
            g.lift_time = self.num(m, "lift_time", where, g.lift_time, lo=0.0, unit=" (s)")
            dev = g
        dev.name = self.text(m, "name", where, dev.name)
        dev.interval = self.num(m, "interval", where, dev.interval, positive=True, unit=" (s)")
        return dev

    def bumper(self, m: _Map, where: str, pose: Pose, size: Sequence[float]) -> BumperSpec:
        if "model" in m:
            self.choice(m, "model", where, ("pioneer",))
            return pioneer_bumper(pose, (float(size[0]), float(size[1])))
        example = "segments: [{pose: [0.24, 0, 0], length: 0.1}]"
        if "segments" not in m:
            raise self.error(m.line, f"{where}: a bumper needs 'model: pioneer' or '{example}'")
        b = BumperSpec(pose=pose)
        items = self.sequence(m, "segments", where, example)
        for i, item in enumerate(items):
            swhere = f"{where}.segments[{i}]"
            s_map = self.mapping(item, items.line_at(i), swhere, "{pose: [0.24, 0, 0], length: 0.1}")
            self.check_keys(s_map, _SEGMENT_KEYS, swhere)
            b.segments.append(
                BumperSegmentSpec(
                    pose=self.pose(s_map, "pose", swhere),
                    length=self.num(s_map, "length", swhere, 0.1, positive=True, unit=" (m)"),
                )
            )
        if not b.segments:
            raise self.error(m.line_of("segments"), f"{where}.segments is empty; list at least one segment")
        return b

    def fiducial(self, m: _Map, where: str, pose: Pose) -> FiducialSpec:
        f = FiducialSpec(pose=pose)
        f.range_min, f.range_max = self.range_(m, where, (f.range_min, f.range_max))
        f.range_max_id = self.num(m, "range_id", where, f.range_max_id, lo=0.0, unit=" (m)")
        f.fov = math.radians(self.fov(m, where, math.degrees(f.fov)))
        f.key = self.integer(m, "key", where, f.key)
        if "noise" in m:
            example = "noise: [0.02, 1.0]   # range m, bearing degrees (standard deviations)"
            v = self.numbers(m, "noise", where, (2,), example)
            if min(v) < 0:
                raise self.error(m.line_of("noise"), f"{where}.noise must not be negative; e.g. {example}")
            f.range_noise, f.bearing_noise = v[0], math.radians(v[1])
        return f

    def fov(self, m: _Map, where: str, default_deg: float) -> float:
        v = self.num(m, "fov", where, default_deg, positive=True, unit=" (degrees)")
        if v > 360:
            raise self.error(m.line_of("fov"), f"{where}.fov must be at most 360 degrees; e.g. fov: 240")
        return v

    def range_(self, m: _Map, where: str, default: tuple[float, float]) -> tuple[float, float]:
        if "range" not in m:
            return default
        v = m["range"]
        if _is_num(v):
            lo, hi = default[0], float(v)
        else:
            lo, hi = self.numbers(m, "range", where, (2,), "range: [0.02, 5.6]   # min, max in m")
        if not (hi > 0 and 0 <= lo <= hi):
            raise self.error(m.line_of("range"), f"{where}.range must be [min, max] with 0 <= min <= max, max > 0")
        return (lo, hi)

    def ranger(self, m: _Map, where: str, kind: str, pose: Pose) -> RangerSpec:
        if "model" in m:
            model = self.choice(m, "model", where, _DEVICE_MODELS[kind])
            r = DEVICE_PRESETS[model](pose=pose)
            assert isinstance(r, RangerSpec)
        elif kind == "laser":
            r = RangerSpec(name="laser", kind="laser", sensors=[RangerSensorSpec()], pose=pose)
        elif "sensors" in m:
            r = RangerSpec(name="sonar", kind="sonar", sensors=[], pose=pose)
        else:
            raise self.error(
                m.line,
                f"{where}: a sonar needs 'model' ({', '.join(_DEVICE_MODELS['sonar'])}) or "
                "'sensors: [{pose: [x, y, yaw], fov: 15, range: [0, 5]}]'",
            )
        if kind == "laser":
            s = r.sensors[0]
            s.fov = math.radians(self.fov(m, where, math.degrees(s.fov)))
            s.samples = self.integer(m, "samples", where, s.samples)
            if s.samples < 2:
                raise self.error(m.line_of("samples"), f"{where}.samples must be at least 2 for a laser")
            s.range_min, s.range_max = self.range_(m, where, (s.range_min, s.range_max))
            s.noise = self.num(m, "noise", where, s.noise, lo=0.0, unit=" (m)")
        elif "sensors" in m:
            sensors = self.sequence(m, "sensors", where, "sensors: [{pose: [0.1, 0, 0], fov: 15}]")
            r.sensors = []
            for i, item in enumerate(sensors):
                swhere = f"{where}.sensors[{i}]"
                s_map = self.mapping(item, sensors.line_at(i), swhere, "{pose: [0.1, 0, 0], fov: 15}")
                self.check_keys(s_map, _SENSOR_KEYS, swhere)
                samples = self.integer(s_map, "samples", swhere, 1)
                if samples < 1:
                    raise self.error(s_map.line_of("samples"), f"{swhere}.samples must be at least 1")
                rmin, rmax = self.range_(s_map, swhere, (0.0, 5.0))
                r.sensors.append(
                    RangerSensorSpec(
                        pose=self.pose(s_map, "pose", swhere),
                        range_min=rmin,
                        range_max=rmax,
                        fov=math.radians(self.fov(s_map, swhere, 15.0)),
                        samples=samples,
                        noise=self.num(s_map, "noise", swhere, 0.0, lo=0.0, unit=" (m)"),
                    )
                )
            if not r.sensors:
                raise self.error(m.line_of("sensors"), f"{where}.sensors is empty; list at least one sensor")
        return r


def _image_size(path: Path, rel: str, file: str, line: int) -> tuple[int, int]:
    from PIL import Image

    try:
        with Image.open(path) as im:
            w, h = im.size
    except Exception as e:  # Pillow raises many types for bad files; all mean "not an image"
        raise WorldFileError(
            f"floorplan.bitmap '{rel}' is not an image Pillow can read ({type(e).__name__}); use a PNG",
            file,
            line,
        ) from None
    if w <= 0 or h <= 0:
        raise WorldFileError(f"floorplan.bitmap '{rel}' is empty ({w} x {h} pixels)", file, line)
    return int(w), int(h)


def load_yaml_world(path: str | os.PathLike[str], *, seed: int | None = None) -> WorldSpec:
    """Read a YAML world file into a WorldSpec (``seed`` overrides ``world.seed``).

    Raises :class:`WorldFileError` naming file:line and a fix for a malformed file; warnings
    (unknown keys, duplicate keys) are in ``WorldSpec.warnings``.
    """
    display = os.fspath(path)
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
    loader = _LineLoader(text)
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
    world = _YamlWorld(display)
    for key, line in loader.duplicates:
        world.warn(line, f"duplicate key '{key}': the last one wins")
    with as_world_file_errors(display, "YAML nested too deeply"):
        return world.build(doc, seed)
