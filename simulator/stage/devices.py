"""Mapping of the devices mounted on a Stage position model to device specs.

Stage 4 semantics (Stage manual; ``libstage/model_ranger.cc``, ``model_blobfinder.cc``,
``model_gripper.cc``, ``model_bumper.cc``, ``model_fiducial.cc``, read for meaning): a
``ranger`` holds ``sensor`` transducer groups (``range [min max]``, ``fov`` in degrees,
``samples``); Stage 3's ``laser`` is one sensor with ``range_min``/``range_max``/``samples``,
and its ``scount``/``spose[i]``/``sview`` sonar rings are read too. A ranger with one
multi-sample sensor becomes :class:`RangerSpec` ``kind="laser"``, else ``"sonar"``.
``blobfinder`` (``colors``, ``fov``/``ptz``, ``range``, ``image``) and ``gripper`` (``size``, our
``paddle_time``/``lift_time``) map to their specs. A ``bumper`` is ``bcount`` segments, segment
``i`` centred at ``bpose[i]`` ``[x y z a]`` (a in degrees; Stage 3's ``[x y a]`` too) and
``blength[i]`` long (else ``blength``, else Stage's 0), lying across the direction it faces. A
``fiducial`` finder reads ``range_min`` (0), ``range_max`` (8), ``range_max_id`` (5), ``fov``
(degrees, 180) and its own ``fiducial_key`` (0): it sees models whose ``fiducial_return`` is
non-zero and whose ``fiducial_key`` matches. Plain ``model`` children (a plate, a laptop) are
decoration, though devices mounted on them are found. Mount poses compose down the
tree; ``update_interval`` is in milliseconds.
"""

from __future__ import annotations

import math

from ..errors import WorldFileError
from ..spec import (
    BlobfinderSpec,
    BumperSegmentSpec,
    BumperSpec,
    FiducialSpec,
    GripperSpec,
    ModelSpec,
    RangerSensorSpec,
    RangerSpec,
    parse_color,
)
from .keywords import (
    BLOBFINDER_KEYS,
    BUMPER_KEYS,
    FIDUCIAL_KEYS,
    GRIPPER_KEYS,
    LASER_KEYS,
    MODEL_KEYS,
    NOT_SIMULATED,
    NOT_SIMULATED_KEYS,
    RANGER_KEYS,
    SENSOR_KEYS,
    SKIPPED,
)  # fmt: skip
from .macros import Inst
from .syntax import INDEX_RE, Prop
from .values import Pose, Reporter, bad, base_key, check, compose, integer, num, nums, parse_pose, parse_size, strings

__all__ = ["DeviceMapping"]


class DeviceMapping(Reporter):
    """The device half of :class:`simulator.stage.mapping.Mapper`."""

    def _devices(self, parent: Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> None:
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
            elif b == "bumper":
                if (bumper := self._bumper(c, robot, offset, counters)) is not None:
                    robot.bumpers.append(bumper)
            elif b == "fiducial":
                robot.fiducials.append(self._fiducial(c, robot, offset, counters))
            elif b == "model":
                # Decoration (a plate, a laptop): validated, not simulated; devices on it are found.
                self.check_keys(c.props, MODEL_KEYS, f"model '{c.type_name}' on '{robot.name}'")
                self._common(c, ModelSpec(name=c.type_name))
                pose = parse_pose(c.props["pose"]) if "pose" in c.props else (0.0, 0.0, 0.0)
                self._devices(c, robot, compose(offset, pose), counters)
            elif b in NOT_SIMULATED:
                self._not_simulated(c)
            elif b == "position":
                self.warn(c.tok, f"position model '{c.type_name}' inside '{robot.name}' is not simulated; skipped")
            elif b == "sensor":
                self.warn(c.tok, f"sensor '{c.type_name}' outside a ranger is skipped; put it inside ranger( ... )")

    def _device_name(self, c: Inst, counters: dict[str, int]) -> str:
        n = counters.get(c.base, 0)
        counters[c.base] = n + 1
        return self._name(c, f"{c.base}:{n}")

    def _mount(self, c: Inst, offset: Pose) -> Pose:
        p = c.props.get("pose")
        return compose(offset, parse_pose(p)) if p is not None else offset

    @staticmethod
    def _interval(c: Inst, default: float) -> float:
        p = c.props.get("update_interval")
        if p is None:
            return default
        v = num(p, "a positive number of milliseconds", "update_interval 100")
        check(v > 0, p, "a positive number of milliseconds", "update_interval 100")
        return v / 1000.0

    def _ranger(self, c: Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> RangerSpec | None:
        name = self._device_name(c, counters)
        what = f"{c.base} '{c.type_name}' of '{robot.name}'"
        P = c.props
        pose = self._mount(c, offset)
        interval = self._interval(c, RangerSpec().interval)
        sensors: list[RangerSensorSpec] = []
        if c.base == "laser":
            self.check_keys(P, LASER_KEYS, what)
            self.scope_not_simulated(P, NOT_SIMULATED_KEYS["laser"])
            rmin = num(P["range_min"], "metres", "range_min 0.02") if "range_min" in P else 0.0
            rmax = num(P["range_max"], "metres", "range_max 5.6") if "range_max" in P else 8.0
            if rmax <= 0 or not 0 <= rmin <= rmax:
                p = P.get("range_max") or P["range_min"]
                raise bad(p, "0 <= range_min <= range_max, range_max > 0", "range_max 5.6")
            fov = self._fov(P.get("fov"), 180.0)
            samples = 180
            if (p := P.get("samples")) is not None:
                samples = integer(p, "an integer >= 1", "samples 682")
                check(samples >= 1, p, "an integer >= 1", "samples 682")
            noise = self._noise(P.get("noise"))
            sensors.append(RangerSensorSpec((0.0, 0.0, 0.0), rmin, rmax, fov, samples, noise))
        else:
            self.check_keys(P, RANGER_KEYS, what)
            self.scope_not_simulated(P, NOT_SIMULATED_KEYS["ranger"])
            for s in c.children:
                if s.base == "sensor":
                    sensors.append(self._sensor(s, what))
                elif s.base == "model":
                    self.check_keys(s.props, MODEL_KEYS, f"model '{s.type_name}' on {what}")
                    self._common(s, ModelSpec(name=s.type_name))
                elif s.base in NOT_SIMULATED:
                    self._not_simulated(s)
                elif s.base not in SKIPPED:
                    self.warn(s.tok, f"'{s.type_name}' inside {what} is skipped; only sensor( ... ) belongs there")
            sensors += self._stage3_sensors(c, what)
        if not sensors:
            self.warn(c.tok, f"{what} has no sensors; skipped (add sensor( ... ) blocks)")
            return None
        kind = "laser" if len(sensors) == 1 and sensors[0].samples > 1 else "sonar"
        return RangerSpec(name=name, kind=kind, sensors=sensors, pose=pose, interval=interval)

    @staticmethod
    def _fov(p: Prop | None, default_deg: float) -> float:
        if p is None:
            return math.radians(default_deg)
        v = num(p, "an angle in degrees, 0 < fov <= 360", "fov 240")
        check(0 < v <= 360, p, "an angle in degrees, 0 < fov <= 360", "fov 240")
        return math.radians(v)

    @staticmethod
    def _noise(p: Prop | None) -> float:
        if p is None:
            return 0.0
        v = num(p, "a standard deviation in metres >= 0", "noise 0.01")
        check(v >= 0, p, "a standard deviation in metres >= 0", "noise 0.01")
        return v

    @staticmethod
    def _range(p: Prop) -> tuple[float, float]:
        v = nums(p, (2,), "[min max] in metres", "range [ 0.02 5.6 ]")
        check(v[1] > 0 and 0 <= v[0] <= v[1], p, "[min max] with 0 <= min <= max, max > 0", "range [ 0.02 5.6 ]")
        return (v[0], v[1])

    def _sensor(self, s: Inst, what: str) -> RangerSensorSpec:
        P = s.props
        self.check_keys(P, SENSOR_KEYS, f"sensor of {what}")
        self.scope_not_simulated(P, NOT_SIMULATED_KEYS["sensor"])
        pose = parse_pose(P["pose"]) if "pose" in P else (0.0, 0.0, 0.0)
        rmin, rmax = self._range(P["range"]) if "range" in P else (0.0, 5.0)
        fov = self._fov(P.get("fov"), math.degrees(0.1))
        samples = 1
        if (p := P.get("samples")) is not None:
            samples = integer(p, "an integer >= 1", "samples 682")
            check(samples >= 1, p, "an integer >= 1", "samples 682")
        if (p := P.get("size")) is not None:
            parse_size(p, 0.0)
        return RangerSensorSpec(pose, rmin, rmax, fov, samples, self._noise(P.get("noise")))

    def _stage3_sensors(self, c: Inst, what: str) -> list[RangerSensorSpec]:
        P = c.props
        count = 0
        if (p := P.get("scount")) is not None:
            count = integer(p, "a number of transducers >= 0", "scount 8")
            check(0 <= count <= 10_000, p, "a number of transducers >= 0", "scount 8")
        example = "sview [ 0 5.0 15 ]"
        view = [0.0, 5.0, 5.0]
        if (p := P.get("sview")) is not None:
            view = nums(p, (3,), "[range_min range_max fov] (m, m, degrees)", example)
        out: list[RangerSensorSpec] = []
        for i in range(count):
            v = view
            if (p := P.get(f"sview[{i}]")) is not None:
                v = nums(p, (3,), "[range_min range_max fov] (m, m, degrees)", example)
            vp = p if p is not None else P.get("sview")
            if vp is not None:
                check(
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
                pose = parse_pose(sp)
            out.append(RangerSensorSpec(pose, v[0], v[1], math.radians(v[2]), 1, 0.0))
        for key, p in P.items():
            if key.startswith("spose[") and INDEX_RE.fullmatch(key[5:]) and int(key[6:-1]) >= count:
                self.warn(p.tok, f"'{key}' ignored: scount is {count}", key=("spose", p.tok.file, p.tok.line))
        return out

    def _blobfinder(self, c: Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> BlobfinderSpec:
        name = self._device_name(c, counters)
        what = f"blobfinder '{c.type_name}' of '{robot.name}'"
        P = c.props
        self.check_keys(P, BLOBFINDER_KEYS, what)
        self.scope_not_simulated(P, NOT_SIMULATED_KEYS["blobfinder"])
        b = BlobfinderSpec(name=name, pose=self._mount(c, offset), interval=self._interval(c, 0.1))
        cp = c.latest("colors", "channels")
        names: list[str] = []
        if cp is not None:
            names = strings(cp, "a list of colour names", 'colors [ "green" "red" ]')
        kp = c.latest("colors_count", "channel_count")
        if kp is not None:
            count = integer(kp, "an integer >= 0", "colors_count 1")
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
                v = nums(p, (3,), "[pan tilt zoom] (degrees)", "ptz [ 0 0 60 ]")
                check(0 < v[2] <= 360, p, "a zoom (fov) angle 0 < zoom <= 360 degrees", "ptz [ 0 0 60 ]")
                b.fov = math.radians(v[2])
            else:
                b.fov = self._fov(p, 60.0)
        if (p := c.latest("range", "range_max")) is not None:
            v = num(p, "a positive range in metres", f"{p.key} 3.0")
            check(v > 0, p, "a positive range in metres", f"{p.key} 3.0")
            b.range_max = v
        if (p := P.get("image")) is not None:
            v = nums(p, (2,), "[width height] in pixels", "image [ 80 60 ]")
            check(
                all(x >= 1 and x == int(x) and x < 1e6 for x in v),
                p,
                "[width height] in pixels",
                "image [ 80 60 ]",
            )
            b.image = (int(v[0]), int(v[1]))
        return b

    def _gripper(self, c: Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> GripperSpec:
        name = self._device_name(c, counters)
        P = c.props
        self.check_keys(P, GRIPPER_KEYS, f"gripper '{c.type_name}' of '{robot.name}'")
        self.scope_not_simulated(P, NOT_SIMULATED_KEYS["gripper"])
        g = GripperSpec(name=name, interval=self._interval(c, 0.1))
        g.pose = self._mount(c, offset) if "pose" in P else compose(offset, g.pose)
        if (p := P.get("size")) is not None:
            sx, sy, _ = parse_size(p, 0.0)
            g.size = (sx, sy)
        for key in ("paddle_time", "lift_time"):
            if (p := P.get(key)) is not None:
                v = num(p, "seconds >= 0", f"{key} 1.0")
                check(v >= 0, p, "seconds >= 0", f"{key} 1.0")
                setattr(g, key, v)
        return g

    def _bumper(self, c: Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> BumperSpec | None:
        name = self._device_name(c, counters)
        what = f"bumper '{c.type_name}' of '{robot.name}'"
        P = c.props
        self.check_keys(P, BUMPER_KEYS, what)
        self.scope_not_simulated(P, NOT_SIMULATED_KEYS["bumper"])
        count = 0
        if (p := P.get("bcount")) is not None:
            count = integer(p, "a number of segments >= 1", "bcount 5")
            check(1 <= count <= 10_000, p, "a number of segments >= 1", "bcount 5")
        if count == 0:
            self.warn(c.tok, f"{what} has no segments; skipped (add bcount, bpose[i] and blength)")
            return None
        length = 0.0  # Stage reads a missing blength as 0
        if (p := P.get("blength")) is not None:
            length = num(p, "a length in metres >= 0", "blength 0.1")
            check(length >= 0, p, "a length in metres >= 0", "blength 0.1")
        example = "bpose[0] [ 0.17 0.12 0 45 ]"
        segments: list[BumperSegmentSpec] = []
        for i in range(count):
            seg_pose: Pose = (0.0, 0.0, 0.0)  # Stage reads a missing bpose[i] as [0 0 0 0]
            if (p := P.get(f"bpose[{i}]")) is not None:
                v = nums(p, (3, 4), "[x y z a] (m, m, m, degrees)", example)
                seg_pose = (v[0], v[1], math.radians(v[-1]))
            else:
                self.warn(c.tok, f"{what}: bcount is {count} but bpose[{i}] is missing; using [0 0 0 0]")
            seg_len = length
            if (p := P.get(f"blength[{i}]")) is not None:
                seg_len = num(p, "a length in metres >= 0", f"blength[{i}] 0.1")
                check(seg_len >= 0, p, "a length in metres >= 0", f"blength[{i}] 0.1")
            segments.append(BumperSegmentSpec(seg_pose, seg_len))
        if any(s.length == 0 for s in segments):
            self.warn(c.tok, f"{what} has segments of length 0, which touch nothing; set blength 0.1 (metres)")
        for key, p in P.items():
            i = key.find("[")
            if base_key(key) in ("bpose", "blength") and INDEX_RE.fullmatch(key[i:]) and int(key[i + 1 : -1]) >= count:
                self.warn(p.tok, f"'{key}' ignored: bcount is {count}", key=("bpose", p.tok.file, p.tok.line))
        return BumperSpec(name=name, pose=self._mount(c, offset), segments=segments, interval=self._interval(c, 0.1))

    def _fiducial(self, c: Inst, robot: ModelSpec, offset: Pose, counters: dict[str, int]) -> FiducialSpec:
        name = self._device_name(c, counters)
        P = c.props
        self.check_keys(P, FIDUCIAL_KEYS, f"fiducial '{c.type_name}' of '{robot.name}'")
        self.scope_not_simulated(P, NOT_SIMULATED_KEYS["fiducial"])
        self.mark_present("fiducial")
        f = FiducialSpec(name=name, pose=self._mount(c, offset), interval=self._interval(c, 0.1))
        for key in ("range_min", "range_max", "range_max_id"):
            if (p := P.get(key)) is not None:
                v = num(p, "a range in metres >= 0", f"{key} {getattr(f, key):g}")
                check(v >= 0, p, "a range in metres >= 0", f"{key} {getattr(f, key):g}")
                setattr(f, key, v)
        if f.range_min > f.range_max:
            p = P.get("range_min") or P["range_max"]
            raise bad(p, "range_min <= range_max", "range_min 0 range_max 8")
        f.fov = self._fov(P.get("fov"), 180.0)
        if (p := P.get("fiducial_key")) is not None:
            f.key = integer(p, "an integer key >= 0", "fiducial_key 1")
            check(f.key >= 0, p, "an integer key >= 0", "fiducial_key 1")
        return f
