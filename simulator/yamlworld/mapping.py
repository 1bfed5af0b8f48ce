"""The sections of a YAML world file (world, floorplan, robots, objects) as a WorldSpec.

The last stage of :mod:`simulator.yamlworld`: :class:`Mapper` turns the document into a
:class:`~simulator.spec.WorldSpec` (the same specs :mod:`simulator.stage` produces from a Stage
world), robots and objects from the presets of :mod:`simulator.presets` with the file's overrides,
their ``devices[]`` through :class:`~simulator.yamlworld.devices.DeviceSections`. The floorplan is
placed either as a Player ``mapfile`` (``resolution`` + bottom-left ``origin``) or as Stage places
a bitmap (``size`` + centre ``pose``).
"""

from __future__ import annotations

import math
from pathlib import Path

from ..gridmap import MAP_YAML_SUFFIXES, image_size, read_map_yaml
from ..presets import OBJECT_PRESETS, ROBOT_PRESETS
from ..spec import (
    BatterySpec,
    BlobfinderSpec,
    BumperSpec,
    ChargerSpec,
    FiducialSpec,
    FloorplanSpec,
    ModelSpec,
    RangerSpec,
    WorldSpec,
)
from .devices import DeviceSections
from .reader import LineMap
from .values import short

__all__ = ["DEFAULT_RESOLUTION", "Mapper"]

TOP_KEYS = ("world", "floorplan", "robots", "objects", "chargers")
WORLD_KEYS = ("interval_sim", "speedup", "seed", "name")
FLOORPLAN_KEYS = ("bitmap", "resolution", "origin", "size", "pose", "threshold", "name")
FLAG_KEYS = ("obstacle_return", "laser_return", "blob_return", "gripper_return")
FIDUCIAL_KEYS = ("fiducial_return", "fiducial_key")
ROBOT_KEYS = (
    "name", "type", "pose", "color", "sonar", "devices", "size", "mass", "max_speed", "max_accel",
    "odom_error", "odom_noise", "drive", "battery", *FLAG_KEYS, *FIDUCIAL_KEYS,
)  # fmt: skip
BATTERY_KEYS = ("capacity", "charge", "per_metre", "per_radian", "watts", "max_charge")
CHARGER_KEYS = ("name", "pose", "rate", "distance", "angle")
OBJECT_KEYS = ("name", "type", "pose", "color", "size", "mass", *FLAG_KEYS, *FIDUCIAL_KEYS)
DEFAULT_RESOLUTION = 0.05
"""Metres per pixel of a floorplan that gives neither ``resolution`` nor ``size``."""


class Mapper(DeviceSections):
    """Builds the WorldSpec of one YAML world file from its document."""

    def build(self, doc: object, seed: int | None) -> WorldSpec:
        if doc is None:
            raise self.error(1, "the world file is empty; add at least 'robots:' (see docs/simulator.md, YAML worlds)")
        top = self.mapping(doc, 1, "the world file", "world: {interval_sim: 0.1}  robots: [...]")
        if "image" in top and "resolution" in top and not any(k in top for k in TOP_KEYS):
            raise self.error(
                1,
                "this is a map_server map, not a world; use it as a world's floorplan: "
                f"'floorplan: {{bitmap: {Path(self.file).name}}}' (see docs/mapping.md, 'Map files')",
            )
        self.check_keys(top, TOP_KEYS, "the world file")
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
        items = self.sequence(top, "chargers", "the world file", "chargers: [{name: dock0, pose: [0, 0, 0]}]")
        for i, item in enumerate(items):
            m = self.mapping(item, items.line_at(i), f"chargers[{i}]", "{name: dock0, pose: [0, 0, 0], rate: 100}")
            c = self.charger(m, f"chargers[{i}]")
            if c.name in seen:
                raise self.error(
                    m.line_of("name"),
                    f"chargers[{i}]: the name '{c.name}' is taken (line {seen[c.name]}); give each a unique name",
                )
            seen[c.name] = m.line_of("name")
            spec.chargers.append(c)
        if seed is not None:
            spec.seed = int(seed)
        spec.warnings = list(self.warnings)
        return spec

    def world(self, m: LineMap, spec: WorldSpec) -> None:
        self.check_keys(m, WORLD_KEYS, "world")
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
                    f"world.speedup must be a positive real-time factor or 'max', got {short(v)}; "
                    "e.g. speedup: 1.0 or speedup: max",
                )
        spec.seed = self.integer(m, "seed", "world", spec.seed)
        if "name" in m:
            self.text(m, "name", "world")

    def floorplan(self, m: LineMap) -> FloorplanSpec:
        where = "floorplan"
        self.check_keys(m, FLOORPLAN_KEYS, where)
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
        name = self.text(m, "name", where, "floorplan")
        if path.suffix.lower() in MAP_YAML_SUFFIXES:
            for key in ("resolution", "origin", "size", "pose", "threshold"):
                if key in m:
                    raise self.error(
                        m.line_of(key),
                        f"floorplan.{key}: the map_server YAML '{rel}' sets the map's placement and "
                        f"thresholds itself; remove {key}",
                    )
            return read_map_yaml(path, f"floorplan.bitmap '{rel}'", self.file, line, name)
        w, h = image_size(path, f"floorplan.bitmap '{rel}'", self.file, line)
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
        res = self.num(m, "resolution", where, DEFAULT_RESOLUTION, positive=True, unit=" (m/pixel)")
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

    def _common(self, m: LineMap, where: str, spec: ModelSpec) -> None:
        spec.size = self.size(m, "size", where, spec.size)
        spec.mass = self.num(m, "mass", where, spec.mass, lo=0.0, unit=" (kg)")
        for key in FLAG_KEYS:
            setattr(spec, key, self.flag(m, key, where, getattr(spec, key)))
        for key in FIDUCIAL_KEYS:
            setattr(spec, key, self.integer(m, key, where, getattr(spec, key)))

    def robot(self, m: LineMap, where: str) -> ModelSpec:
        name = self.text(m, "name", where, "r0", required=True)
        where = f"{where} ({name})"
        self.check_keys(m, ROBOT_KEYS, where)
        kind = self.choice(m, "type", where, sorted(ROBOT_PRESETS), "pioneer2dx")
        pose = self.pose(m, "pose", where)
        spec = ROBOT_PRESETS[kind](name, pose)
        spec.color = self.color(m, "color", where, spec.color)
        if not self.flag(m, "sonar", where, True):
            spec.rangers = [r for r in spec.rangers if r.kind != "sonar"]
        self._common(m, where, spec)
        for key in ("max_speed", "max_accel", "odom_error", "odom_noise"):
            if key in m:
                v = self.non_negative(m, key, where)
                setattr(spec, key, (v[0], math.radians(v[1])) if len(v) == 2 else tuple(v))
        if "drive" in m:
            drive = self.text(m, "drive", where)
            if drive != "diff":
                self.warn(m.line_of("drive"), f"{where}: drive '{drive}' is not simulated; using 'diff'")
        if "battery" in m:
            self.battery(m, where, spec)
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

    def battery(self, m: LineMap, where: str, spec: ModelSpec) -> None:
        """A robot's ``battery:`` map over its preset's (Pioneer) battery, or ``battery: none``."""
        v = m["battery"]
        if v is None or v is False or (isinstance(v, str) and v.strip().lower() == "none"):
            spec.battery = None
            return
        where = f"{where}.battery"
        b = self.mapping(v, m.line_of("battery"), where, "{capacity: 252, charge: 1.0, watts: 20}")
        self.check_keys(b, BATTERY_KEYS, where)
        bat = spec.battery = spec.battery or BatterySpec()
        bat.capacity = self.num(b, "capacity", where, bat.capacity / 3600.0, positive=True, unit=" (Wh)") * 3600.0
        bat.charge = self.num(b, "charge", where, bat.charge, lo=0.0, unit=" (fraction 0..1)")
        if bat.charge > 1.0:
            raise self.error(b.line_of("charge"), f"{where}.charge must be a fraction from 0 to 1; e.g. charge: 0.8")
        for key, unit in (
            ("per_metre", " (J/m)"),
            ("per_radian", " (J/rad)"),
            ("watts", " (W)"),
            ("max_charge", " (W)"),
        ):
            setattr(bat, key, self.num(b, key, where, getattr(bat, key), lo=0.0, unit=unit))

    def charger(self, m: LineMap, where: str) -> ChargerSpec:
        """A ``chargers[]`` item: a charging station (:class:`~simulator.spec.ChargerSpec`)."""
        name = self.text(m, "name", where, "dock0", required=True)
        where = f"{where} ({name})"
        self.check_keys(m, CHARGER_KEYS, where)
        c = ChargerSpec(name=name, pose=self.pose(m, "pose", where), source=f"{self.file}:{m.line}")
        c.rate = self.num(m, "rate", where, c.rate, positive=True, unit=" (W)")
        c.distance = self.num(m, "distance", where, c.distance, positive=True, unit=" (m)")
        if "angle" in m:
            deg = self.num(m, "angle", where, 20.0, lo=0.0, unit=" (degrees)")
            if deg > 180:
                raise self.error(m.line_of("angle"), f"{where}.angle must be at most 180 degrees; e.g. angle: 20")
            c.angle = math.radians(deg)
        return c

    def non_negative(self, m: LineMap, key: str, where: str) -> list[float]:
        """A robot's ``max_speed``/``max_accel`` (m/s or m/s^2, deg/s or deg/s^2) or
        ``odom_error``/``odom_noise`` (fractions of x, y, yaw motion): numbers >= 0."""
        if key.startswith("max_"):
            example, n = f"{key}: [1.0, 100]   # m/s (m/s^2), deg/s (deg/s^2)", 2
        else:
            example, n = f"{key}: [0.03, 0.03, 0.05]   # fractions of x, y, yaw motion", 3
        v = self.numbers(m, key, where, (n,), example)
        if min(v) < 0:
            raise self.error(m.line_of(key), f"{where}.{key} must not be negative; e.g. {example}")
        return v

    def obj(self, m: LineMap, where: str) -> ModelSpec:
        name = self.text(m, "name", where, "blob0", required=True)
        where = f"{where} ({name})"
        self.check_keys(m, OBJECT_KEYS, where)
        kind = self.choice(m, "type", where, sorted(OBJECT_PRESETS))
        spec = OBJECT_PRESETS[kind](name, self.pose(m, "pose", where))
        spec.color = self.color(m, "color", where, spec.color)
        self._common(m, where, spec)
        return spec
