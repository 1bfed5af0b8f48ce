"""Mapping of expanded Stage models to the simulator's :class:`~simulator.spec.WorldSpec`.

Stage 4 semantics (Stage manual; ``libstage/world.cc``, ``model.cc``, ``model_position.cc``, read for
meaning, no code shared):

* Top-level ``position`` models (or defines of it) are robots, with the devices of
  :mod:`simulator.stage.devices`. The first non-position top-level model with a ``bitmap`` is
  the floorplan: Stage stretches the bitmap to ``size`` and centres it on ``pose``, so resolution =
  size_x / width in pixels and origin = pose - size / 2. Without ``size``, our extension keys
  ``map_resolution`` (default 0.05 m/pixel) and ``origin [x y]`` place it like Player's mapfile
  driver (default: centred on pose). Every other top-level model is a passive body.
* Units become SI: ``interval_sim``/``interval_real`` are in milliseconds; unnamed models are
  named ``<type>:<n>`` as Stage does (``n`` counts the models of that built-in type at their level).
* Extensions: ``odom_noise [x y a]`` on a position model, ``map_resolution``/``origin`` on a
  floorplan, ``seed`` at world level.
* Energy (:mod:`simulator.energy`): a position model's battery is the Pioneer's unless it says
  otherwise, with Stage's power-pack keywords (``joules`` stored and capacity, ``kjoules``,
  ``joules_capacity``, ``watts`` the constant draw, ``take_watts`` the most it charges at) or ours
  (``battery_capacity`` in Wh, 0: no battery model; ``battery_charge`` the starting fraction;
  ``battery_drain [J/m J/rad W]``). A top-level ``charger`` model (ours) is a charging station:
  ``pose``, ``charge_rate`` (W), ``dock_distance`` (m), ``dock_angle`` (degrees; absent: any
  heading).
"""

from __future__ import annotations

import math
from pathlib import Path

from ..controllers import CONTROLLERS
from ..energy import battery_problem
from ..errors import WorldFileError, did_you_mean
from ..gridmap import MAP_YAML_SUFFIXES, image_size, read_map_yaml
from ..spec import BatterySpec, ChargerSpec, FloorplanSpec, ModelSpec, WorldSpec, parse_color
from .devices import DeviceMapping
from .keywords import (
    BLOCK_KEYS,
    CHARGER_KEYS,
    DEVICE_TYPES,
    MODEL_KEYS,
    NOT_SIMULATED,
    NOT_SIMULATED_KEYS,
    POSITION_KEYS,
    SKIPPED,
    WORLD_KEYS,
)  # fmt: skip
from .macros import Inst
from .syntax import Prop
from .values import (
    base_key,
    boolean,
    check,
    integer,
    num,
    nums,
    parse_pose,
    parse_size,
    string,
    where,
)  # fmt: skip

__all__ = ["Mapper"]

DEFAULT_MAP_RESOLUTION = 0.05  # m/pixel, Player's mapfile default


class Mapper(DeviceMapping):
    """Builds a :class:`WorldSpec` from the world properties and top-level models of a load."""

    def __init__(self, display: str, world_props: dict[str, Prop], top: list[Inst]):
        super().__init__()
        self.display = display
        self.world_props = world_props
        self.top = top

    def build(self, seed: int | None) -> WorldSpec:
        spec = WorldSpec(source=self.display)
        self._world(spec)
        counters: dict[str, int] = {}
        seen: dict[str, str] = {}
        for inst in self.top:
            base = inst.base
            if base in SKIPPED:
                continue
            n = counters.get(base, 0)
            counters[base] = n + 1
            if base in NOT_SIMULATED:
                self._not_simulated(inst)
                continue
            if base in DEVICE_TYPES or base == "sensor":
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
            seen[name] = where(inst.tok)
            if base == "charger":
                spec.chargers.append(self._charger(inst, name))
                continue
            model = self._robot(inst, name) if base == "position" else self._passive(inst, name)
            spec.models.append(model)
        if seed is not None:
            spec.seed = int(seed)
        self.report_not_simulated(self.display)
        spec.warnings = list(self.warnings)
        return spec

    def _name(self, inst: Inst, auto: str) -> str:
        p = inst.props.get("name")
        if p is None:
            return auto
        name = string(p, "a quoted name", 'name "r0"').strip()
        check(bool(name), p, "a non-empty name", 'name "r0"')
        return name

    def _not_simulated(self, inst: Inst) -> None:
        what = f"model type '{inst.base}'"
        if inst.type_name != inst.base:
            what += f" ('{inst.type_name}')"
        self.not_simulated(inst.tok, what)

    def _world(self, spec: WorldSpec) -> None:
        wp = self.world_props
        for key, p in wp.items():
            if base_key(key) not in WORLD_KEYS and not key.startswith("gui_"):
                hint = did_you_mean(base_key(key), sorted(WORLD_KEYS))
                hint = f"; {hint}" if hint else ""
                self.warn(p.tok, f"unknown world keyword '{key}' ignored{hint}", key=("key", p.tok.file, key))
        if (p := wp.get("interval_sim")) is not None:
            v = num(p, "a positive number of milliseconds", "interval_sim 100")
            check(v > 0, p, "a positive number of milliseconds", "interval_sim 100")
            spec.interval_sim = v / 1000.0
        if (p := wp.get("interval_real")) is not None:
            v = num(p, "milliseconds >= 0 (0: as fast as possible)", "interval_real 100")
            check(v >= 0, p, "milliseconds >= 0 (0: as fast as possible)", "interval_real 100")
            spec.speedup = math.inf if v == 0 else spec.interval_sim * 1000.0 / v
        if (p := wp.get("speedup")) is not None:
            v = num(p, "a real-time factor (-1: as fast as possible)", "speedup 1.0")
            spec.speedup = math.inf if v <= 0 else v
        if (p := wp.get("seed")) is not None:
            spec.seed = integer(p, "an integer", "seed 42")
        if (p := wp.get("resolution")) is not None:
            v = num(p, "a positive number of metres", "resolution 0.02")
            check(v > 0, p, "a positive number of metres", "resolution 0.02")
            spec.resolution = v
        if (p := wp.get("quit_time")) is not None:  # Stage: stop when sim time >= quit_time > 0
            v = num(p, "seconds >= 0 (0: never)", "quit_time 3600")
            check(v >= 0, p, "seconds >= 0 (0: never)", "quit_time 3600")
            spec.quit_time = v
        if (p := wp.get("show_clock_interval")) is not None:
            need, example = "a number of updates", "show_clock_interval 100"
            check(num(p, need, example) >= 0, p, need, example)
        self.scope_not_simulated(wp, NOT_SIMULATED_KEYS["world"])
        if (p := wp.get("threads")) is not None:
            v = integer(p, "a number of threads >= 0 (0: none besides the stepping thread)", "threads 1")
            check(v >= 0, p, "a number of threads >= 0 (0: none besides the stepping thread)", "threads 1")
            spec.threads = max(1, v)
        for key in ("paused", "show_clock"):
            if (p := wp.get(key)) is not None:
                boolean(p)
        if (p := wp.get("name")) is not None:
            string(p, "a quoted name", 'name "tams"')

    # ------------------------------------------------------------------ models
    def _common(self, inst: Inst, m: ModelSpec) -> None:
        P = inst.props
        if (p := P.get("pose")) is not None:
            m.pose = parse_pose(p)
        if (p := P.get("size")) is not None:
            m.size = parse_size(p, m.size[2])
        if (p := inst.latest("color", "color_rgba")) is not None:
            if p.key == "color":
                cname = string(p, "a colour name", 'color "red"')
                try:
                    m.color = parse_color(cname)
                except ValueError as e:
                    self.warn(p.at, f"{e}; keeping {m.color}", key=("color", p.tok.file, cname.lower()))
            else:
                rgba = nums(p, (3, 4), "[r g b a] from 0 to 1", "color_rgba [ 0 1 0 1 ]")
                m.color = parse_color(rgba)
        if (p := P.get("mass")) is not None:
            v = num(p, "kilograms >= 0", "mass 23.0")
            check(v >= 0, p, "kilograms >= 0", "mass 23.0")
            m.mass = v
        if (p := inst.latest("laser_return", "ranger_return")) is not None:
            if p.key == "ranger_return":  # Stage 4: a float; rangers see the model when it is >= 0
                v = num(p, "a number (>= 0: seen by rangers, < 0: invisible to them)", "ranger_return 1")
                m.laser_return = v >= 0.0
            else:  # Stage 3: 0 invisible, 1 visible, 2 bright
                m.laser_return = boolean(p, levels=True)
        for key in ("obstacle_return", "blob_return", "gripper_return"):
            if (p := P.get(key)) is not None:
                setattr(m, key, boolean(p))
        for key in ("fiducial_return", "fiducial_key"):  # Stage: ints; fiducial finders see return != 0
            if (p := P.get(key)) is not None:
                v = integer(p, "an integer id >= 0 (0: not seen by fiducial finders)", f"{key} 1")
                check(v >= 0, p, "an integer id >= 0 (0: not seen by fiducial finders)", f"{key} 1")
                setattr(m, key, v)
        if (p := P.get("origin")) is not None and "bitmap" not in P:
            m.origin = parse_pose(p)
        m.blocks = self._blocks(inst)
        m.source = where(inst.tok)

    def _blocks(self, inst: Inst) -> list[tuple[tuple[float, float], ...]]:
        """The outlines of the model's ``block( points N point[i] [x y] ... )`` children."""
        out = []
        for b in inst.children:
            if b.base != "block":
                continue
            P = b.props
            self.check_keys(P, BLOCK_KEYS, f"block of '{inst.type_name}'")
            pp = P.get("points")
            if pp is None:
                raise WorldFileError(
                    "block without 'points': write e.g. 'block( points 4 point[0] [0 0] point[1] [1 0] "
                    "point[2] [1 1] point[3] [0 1] z [0 1] )'",
                    b.tok.file,
                    b.tok.line,
                )
            n = integer(pp, "a number of corners >= 3", "points 4")
            check(3 <= n <= 10_000, pp, "a number of corners >= 3", "points 4")
            pts = []
            for i in range(n):
                q = P.get(f"point[{i}]")  # Stage reads a missing corner as [0 0]
                x, y = nums(q, (2,), "[x y]", f"point[{i}] [ 0 1 ]") if q is not None else (0.0, 0.0)
                pts.append((x, y))
            if (q := P.get("z")) is not None:
                nums(q, (2,), "[bottom top] heights", "z [ 0 1 ]")
            out.append(tuple(pts))
        return out

    def _passive(self, inst: Inst, name: str) -> ModelSpec:
        self.check_keys(inst.props, MODEL_KEYS, f"model '{name}'")
        self.scope_not_simulated(inst.props, NOT_SIMULATED_KEYS["model"])
        m = ModelSpec(name=name, type_name=inst.type_name, position=False)
        self._common(inst, m)
        for c in inst.children:
            if c.base in DEVICE_TYPES or c.base == "position":
                self.warn(
                    c.tok,
                    f"'{c.type_name}' on the passive model '{name}' is not simulated: mount devices "
                    "on a position model",
                    key=("passive-dev", c.tok.file, c.tok.line),
                )
        return m

    def _robot(self, inst: Inst, name: str) -> ModelSpec:
        P = inst.props
        self.check_keys(P, POSITION_KEYS, f"position '{name}'")
        self.scope_not_simulated(P, NOT_SIMULATED_KEYS["position"])
        m = ModelSpec(name=name, type_name=inst.type_name, position=True)
        self._common(inst, m)
        if (p := P.get("localization")) is not None:
            loc = string(p, '"odom" or "gps"', 'localization "odom"')
            check(loc in ("odom", "gps"), p, '"odom" or "gps"', 'localization "odom"')
            m.localization = loc
        if (p := P.get("ctrl")) is not None:
            words = string(p, 'a controller name and its arguments ("wander")', 'ctrl "wander"').split()
            if words and words[0] in CONTROLLERS:
                m.ctrl = words[0]
            else:
                got = words[0] if words else ""
                self.warn(
                    p.at,
                    f"controller '{got}' of '{name}' is not built in (known: {', '.join(sorted(CONTROLLERS))}); "
                    "the robot gets no controller",
                    key=("ctrl", p.tok.file, p.tok.line),
                )
        if (p := P.get("drive")) is not None:
            drive = string(p, 'a drive name ("diff")', 'drive "diff"')
            if drive != "diff":
                self.warn(
                    p.at,
                    f"drive '{drive}' is not simulated; '{name}' uses a differential drive",
                    key=("drive", p.tok.file, p.tok.line),
                )
        for key in ("velocity_bounds", "acceleration_bounds"):
            if (p := P.get(key)) is not None:
                example = f"{key} [ -0.5 0.5 0 0 0 0 -90 90 ]"
                v = nums(p, (8,), "[xmin xmax ymin ymax zmin zmax amin amax] (m and degrees)", example)
                lin = max(abs(v[0]), abs(v[1]))
                ang = math.radians(max(abs(v[6]), abs(v[7])))
                if key == "velocity_bounds":
                    m.max_speed = (lin, ang)
                else:
                    m.max_accel = (lin, ang)
        if (p := P.get("odom_error")) is not None:
            v = nums(p, (3, 4), "[x y z a] error fractions >= 0", "odom_error [ 0.03 0.03 0.00 0.05 ]")
            check(min(v) >= 0, p, "[x y z a] error fractions >= 0", "odom_error [ 0.03 0.03 0.00 0.05 ]")
            m.odom_error = (v[0], v[1], v[-1])
        if (p := P.get("odom_noise")) is not None:
            v = nums(p, (3,), "[x y a] noise fractions >= 0", "odom_noise [ 0.01 0.01 0.02 ]")
            check(min(v) >= 0, p, "[x y a] noise fractions >= 0", "odom_noise [ 0.01 0.01 0.02 ]")
            m.odom_noise = (v[0], v[1], v[2])
        self._battery(inst, m)
        self._devices(inst, m, (0.0, 0.0, 0.0), {})
        return m

    # ------------------------------------------------------------------ energy
    def _battery(self, inst: Inst, m: ModelSpec) -> None:
        """The robot's battery from Stage's power-pack keywords and ours (module docstring)."""
        P = inst.props
        b = m.battery = BatterySpec() if m.battery is None else m.battery
        stored: float | None = None
        for key, scale in (("joules", 1.0), ("kjoules", 1000.0)):
            if (p := P.get(key)) is not None:
                v = num(p, "joules > 0", f"{key} 900000")
                check(v > 0, p, "joules > 0", f"{key} 900000")
                stored = b.capacity = v * scale
                b.charge = 1.0
        if (p := P.get("joules_capacity")) is not None:
            v = num(p, "joules > 0", "joules_capacity 907200")
            check(v > 0, p, "joules > 0", "joules_capacity 907200")
            b.capacity = v
            b.charge = 1.0 if stored is None else min(1.0, stored / v)
        if (p := P.get("battery_capacity")) is not None:
            v = num(p, "watt-hours >= 0 (0: no battery model)", "battery_capacity 252")
            check(v >= 0, p, "watt-hours >= 0 (0: no battery model)", "battery_capacity 252")
            if v == 0:
                m.battery = None
                return
            b.capacity = v * 3600.0
        if (p := P.get("battery_charge")) is not None:
            v = num(p, "a fraction from 0 to 1", "battery_charge 0.8")
            check(0 <= v <= 1, p, "a fraction from 0 to 1", "battery_charge 0.8")
            b.charge = v
        if (p := P.get("battery_drain")) is not None:
            need, example = "[J/m J/rad W] >= 0 (per metre, per radian, constant)", "battery_drain [ 20 4 20 ]"
            v = nums(p, (3,), need, example)
            check(min(v) >= 0, p, need, example)
            b.per_metre, b.per_radian, b.watts = v
        for key, attr in (("watts", "watts"), ("take_watts", "max_charge")):
            if (p := P.get(key)) is not None:
                v = num(p, "watts >= 0", f"{key} 20")
                check(v >= 0, p, "watts >= 0", f"{key} 20")
                setattr(b, attr, v)
        if (why := battery_problem(b)) is not None:  # pragma: no cover - each key is checked above
            raise WorldFileError(f"'{m.name}': {why}", inst.tok.file, inst.tok.line)

    def _charger(self, inst: Inst, name: str) -> ChargerSpec:
        P = inst.props
        self.check_keys(P, CHARGER_KEYS, f"charger '{name}'")
        c = ChargerSpec(name=name, source=where(inst.tok))
        if (p := P.get("pose")) is not None:
            c.pose = parse_pose(p)
        if (p := P.get("size")) is not None:
            parse_size(p, 0.0)
        if (p := P.get("charge_rate")) is not None:
            c.rate = num(p, "watts > 0", "charge_rate 100")
            check(c.rate > 0, p, "watts > 0", "charge_rate 100")
        if (p := P.get("dock_distance")) is not None:
            c.distance = num(p, "metres > 0", "dock_distance 0.3")
            check(c.distance > 0, p, "metres > 0", "dock_distance 0.3")
        if (p := P.get("dock_angle")) is not None:
            v = num(p, "degrees from 0 to 180", "dock_angle 20")
            check(0 <= v <= 180, p, "degrees from 0 to 180", "dock_angle 20")
            c.angle = math.radians(v)
        return c

    # ------------------------------------------------------------------ floorplan
    def _floorplan(self, inst: Inst, name: str) -> FloorplanSpec:
        P = inst.props
        self.check_keys(P, MODEL_KEYS, f"floorplan '{name}'")
        self.scope_not_simulated(P, NOT_SIMULATED_KEYS["floorplan"])
        self._common(inst, ModelSpec(name=name))  # validates pose, size, colour, flags
        boundary = boolean(P["boundary"]) if "boundary" in P else False
        bp = P["bitmap"]
        rel = string(bp, "a quoted image file name", 'bitmap "floor.png"').strip()
        check(bool(rel), bp, "a quoted image file name", 'bitmap "floor.png"')
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
        if path.suffix.lower() in MAP_YAML_SUFFIXES:
            return self._map_yaml_floorplan(inst, name, path, rel, boundary)
        w, h = image_size(path, f"bitmap '{rel}'", bp.at.file, bp.at.line)
        px, py, pa = parse_pose(P["pose"]) if "pose" in P else (0.0, 0.0, 0.0)
        if pa != 0.0:
            self.warn(P["pose"].at, f"floorplan '{name}': rotation ignored, a bitmap is always axis-aligned")
        if (p := P.get("size")) is not None:
            sx, sy, _ = parse_size(p, 0.0)
            ox = oy = 0.0
            if (q := P.get("origin")) is not None:  # Stage: the bitmap's centre offset from the pose
                ox, oy, _ = parse_pose(q)
            return FloorplanSpec(
                bitmap=path.absolute(),
                resolution=sx / w,
                origin=(px + ox - sx / 2.0, py + oy - sy / 2.0),
                size=(sx, sy),
                name=name,
                boundary=boundary,
            )
        res = DEFAULT_MAP_RESOLUTION
        if (p := P.get("map_resolution")) is not None:
            res = num(p, "metres per pixel > 0", "map_resolution 0.05")
            check(res > 0, p, "metres per pixel > 0", "map_resolution 0.05")
        if (p := P.get("origin")) is not None:
            v = nums(p, (2, 3, 4), "[x y] of the bottom-left corner in metres", "origin [ -31.475 -7.8 ]")
            origin = (v[0], v[1])
        else:
            origin = (px - w * res / 2.0, py - h * res / 2.0)
        return FloorplanSpec(
            bitmap=path.absolute(), resolution=res, origin=origin, size=None, name=name, boundary=boundary
        )

    def _map_yaml_floorplan(self, inst: Inst, name: str, path: Path, rel: str, boundary: bool) -> FloorplanSpec:
        """A ``bitmap`` that is a ROS map_server YAML: the YAML places the map (its resolution and
        origin); a ``size`` or ``pose`` that disagrees with it, ``origin`` or ``map_resolution``
        are ignored with a warning."""
        P = inst.props
        bp = P["bitmap"]
        fp = read_map_yaml(path, f"map '{rel}'", bp.at.file, bp.at.line, name)
        fp.boundary = boundary
        w, h = image_size(fp.bitmap, f"map '{rel}'", bp.at.file, bp.at.line)
        res, (x0, y0) = fp.resolution, fp.origin
        sx, sy = w * res, h * res

        def why(key: str) -> str:
            return (
                f"floorplan '{name}': {key} ignored, the map_server YAML '{rel}' places the map "
                f"({sx:g} x {sy:g} m from ({x0:g}, {y0:g})); remove it"
            )

        if (p := P.get("size")) is not None:
            gx, gy, _ = parse_size(p, 0.0)
            if abs(gx - sx) > res / 2 or abs(gy - sy) > res / 2:
                self.warn(p.at, why("size"))
        if (p := P.get("pose")) is not None:
            px, py, _ = parse_pose(p)
            if abs(px - (x0 + sx / 2)) > res / 2 or abs(py - (y0 + sy / 2)) > res / 2:
                self.warn(p.at, why("pose"))
        for key in ("origin", "map_resolution"):
            if (p := P.get(key)) is not None:
                self.warn(p.at, why(key))
        return fp
