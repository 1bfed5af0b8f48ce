"""The ``devices[]`` of a robot in a YAML world file, as device specs.

Part of :mod:`simulator.yamlworld`: each item names its ``type`` (laser, sonar, blobfinder,
gripper, bumper, fiducial) and either a preset ``model`` of :mod:`simulator.presets` or its own
geometry; lasers and sonars become :class:`~simulator.spec.RangerSpec`, the others their own specs
of :mod:`simulator.spec`. A new sensor plug-in adds its type to :data:`DEVICE_KEYS` and a method
here (see ``docs/contributing.md``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from ..presets import DEVICE_PRESETS, pioneer_bumper
from ..spec import (
    BlobfinderSpec,
    BumperSegmentSpec,
    BumperSpec,
    FiducialSpec,
    GripperSpec,
    RangerSensorSpec,
    RangerSpec,
    parse_color,
)
from .reader import LineMap
from .values import Pose, Values, short

__all__ = ["DEVICE_KEYS", "DEVICE_MODELS", "Device", "DeviceSections"]

DEVICE_KEYS: dict[str, tuple[str, ...]] = {
    "laser": ("type", "name", "model", "pose", "fov", "samples", "range", "noise", "interval"),
    "sonar": ("type", "name", "model", "pose", "sensors", "interval"),
    "blobfinder": ("type", "name", "pose", "colors", "fov", "range", "image", "interval"),
    "gripper": ("type", "name", "pose", "size", "paddle_time", "lift_time", "interval"),
    "bumper": ("type", "name", "model", "pose", "segments", "interval"),
    "fiducial": ("type", "name", "pose", "range", "range_id", "fov", "key", "noise", "interval"),
}
"""The keys each device type takes."""
DEVICE_MODELS = {
    "laser": ("urg04lx", "utm30lx"),
    "sonar": ("pioneer2dx_sonar", "pioneer3at_sonar"),
}
"""The presets a ranger's ``model`` may name."""
_SEGMENT_KEYS = ("pose", "length")
_SENSOR_KEYS = ("pose", "fov", "samples", "range", "noise")
Device = RangerSpec | BlobfinderSpec | GripperSpec | BumperSpec | FiducialSpec


class DeviceSections(Values):
    """Reads one ``devices[]`` item into its device spec."""

    def device(self, m: LineMap, where: str, size: Sequence[float] = (0.44, 0.38, 0.22)) -> Device:
        kind = self.choice(m, "type", where, list(DEVICE_KEYS))
        self.check_keys(m, DEVICE_KEYS[kind], f"{where} ({kind})")
        pose = self.pose(m, "pose", where)
        dev: Device
        if kind == "bumper":
            dev = self.bumper(m, where, pose, size)
        elif kind == "fiducial":
            dev = self.fiducial(m, where, pose)
        elif kind in DEVICE_MODELS:
            dev = self.ranger(m, where, kind, pose)
        elif kind == "blobfinder":
            dev = self.blobfinder(m, where, pose)
        else:
            dev = self.gripper(m, where, pose)
        dev.name = self.text(m, "name", where, dev.name)
        dev.interval = self.num(m, "interval", where, dev.interval, positive=True, unit=" (s)")
        return dev

    def bumper(self, m: LineMap, where: str, pose: Pose, size: Sequence[float]) -> BumperSpec:
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

    def fiducial(self, m: LineMap, where: str, pose: Pose) -> FiducialSpec:
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

    def ranger(self, m: LineMap, where: str, kind: str, pose: Pose) -> RangerSpec:
        if "model" in m:
            model = self.choice(m, "model", where, DEVICE_MODELS[kind])
            r = DEVICE_PRESETS[model](pose=pose)
            assert isinstance(r, RangerSpec)
        elif kind == "laser":
            r = RangerSpec(name="laser", kind="laser", sensors=[RangerSensorSpec()], pose=pose)
        elif "sensors" in m:
            r = RangerSpec(name="sonar", kind="sonar", sensors=[], pose=pose)
        else:
            raise self.error(
                m.line,
                f"{where}: a sonar needs 'model' ({', '.join(DEVICE_MODELS['sonar'])}) or "
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

    def blobfinder(self, m: LineMap, where: str, pose: Pose) -> BlobfinderSpec:
        b = BlobfinderSpec(pose=pose)
        if "colors" in m:
            colors = m["colors"]
            if not isinstance(colors, list):
                colors = [colors]
            for c in colors:
                try:
                    if not isinstance(c, str | list):
                        raise ValueError(f"unknown colour {short(c)}")
                    b.colors.append(parse_color(c))
                except (ValueError, TypeError) as e:
                    raise self.error(m.line_of("colors"), f"{where}.colors: {e}; e.g. colors: [green, red]") from None
        else:
            b.colors.append(parse_color("green"))
        b.fov = math.radians(self.fov(m, where, math.degrees(b.fov)))
        b.range_max = self.num(m, "range", where, b.range_max, positive=True, unit=" (m)")
        if "image" in m:
            v = self.numbers(m, "image", where, (2,), "image: [80, 60]")
            if not all(1 <= x < 1e6 and x == int(x) for x in v):
                raise self.error(m.line_of("image"), f"{where}.image must be [width, height] in pixels")
            b.image = (int(v[0]), int(v[1]))
        return b

    def gripper(self, m: LineMap, where: str, pose: Pose) -> GripperSpec:
        g = GripperSpec()
        if "pose" in m:
            g.pose = pose
        if "size" in m:
            sx, sy, _ = self.size(m, "size", where, (*g.size, 0.0))
            g.size = (sx, sy)
        g.paddle_time = self.num(m, "paddle_time", where, g.paddle_time, lo=0.0, unit=" (s)")
        g.lift_time = self.num(m, "lift_time", where, g.lift_time, lo=0.0, unit=" (s)")
        return g
