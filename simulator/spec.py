"""World description: the parsed, validated form of a world file.

Both world-file front ends (Stage ``.world`` syntax in :mod:`simulator.stageworld` and the YAML
format in :mod:`simulator.yamlworld`) produce a :class:`WorldSpec`; :class:`simulator.world.World`
is built from it and never sees file syntax. Everything is in SI units: metres and radians, poses
as ``(x, y, yaw)`` (Stage writes ``[x y z a]`` with degrees; the parsers convert).

The model kinds follow Stage (thesis appendix A.1, A.5, A.6): a *position* model is a robot base
with a differential drive; *ranger*, *blobfinder*, *gripper*, *bumper* and *fiducial* models are
devices mounted on it; any other *model* is a passive body (a blob, a box of furniture) that robots
can push, see or grip. The simulator's plug-in for each device kind is in :mod:`simulator.sensors`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "BatterySpec",
    "BlobfinderSpec",
    "ChargerSpec",
    "BumperSegmentSpec",
    "BumperSpec",
    "FiducialSpec",
    "FloorplanSpec",
    "GripperSpec",
    "ModelSpec",
    "RangerSensorSpec",
    "RangerSpec",
    "WorldSpec",
    "NAMED_COLORS",
    "parse_color",
]

Pose = tuple[float, float, float]


@dataclass
class RangerSensorSpec:
    """One transducer group of a ranger: a laser has one with many samples (one reading per
    beam), a sonar ring one per transducer with ``samples == 1`` and ``fov`` the cone width (one
    reading, the nearest hit in the cone). A ranger may mix both."""

    pose: Pose = (0.0, 0.0, 0.0)  # in the robot frame: m, m, rad
    range_min: float = 0.0  # m
    range_max: float = 5.0  # m
    fov: float = math.radians(180.0)  # rad; for a single-sample sensor: the cone width
    samples: int = 180
    noise: float = 0.0  # standard deviation of range noise, m


@dataclass
class RangerSpec:
    """A ranger device (Stage ``ranger``): a list of sensors read together as one scan.

    ``kind`` is ``"laser"`` when it has one multi-sample sensor, ``"sonar"`` otherwise (one
    single-sample cone sensor per transducer, or a mix); the parsers decide, a world may say so
    explicitly. The simulator reads every layout the same way, sensor by sensor.
    """

    name: str = "ranger"
    kind: str = "laser"  # "laser" | "sonar"
    sensors: list[RangerSensorSpec] = field(default_factory=list)
    pose: Pose = (0.0, 0.0, 0.0)  # mount pose of the device on its robot (sensors are relative to it)
    interval: float = 0.1  # s between scans (Stage's update interval of the ranger)


@dataclass
class BlobfinderSpec:
    """A colour-blob camera (Stage ``blobfinder``, thesis A.1)."""

    name: str = "blobfinder"
    pose: Pose = (0.0, 0.0, 0.0)
    colors: list[tuple[int, int, int]] = field(default_factory=list)  # channels looked for
    fov: float = math.radians(60.0)  # rad
    range_max: float = 8.0  # m
    image: tuple[int, int] = (80, 60)  # width, height in pixels
    interval: float = 0.1


@dataclass
class GripperSpec:
    """A two-paddle gripper with a lift and break beams (Stage ``gripper``, Player's gripper)."""

    name: str = "gripper"
    pose: Pose = (0.23, 0.0, 0.0)  # centre of the paddles in the robot frame
    size: tuple[float, float] = (0.1, 0.3)  # depth (x) and width (y) of the space between paddles
    paddle_time: float = 1.0  # s to open or close the paddles
    lift_time: float = 1.0  # s to raise or lower the lift
    interval: float = 0.1


@dataclass
class BumperSegmentSpec:
    """One bumper switch: a straight segment of ``length`` metres centred at ``pose`` (device
    frame), lying across the direction ``pose`` faces (Stage ``bpose[i]``/``blength[i]``)."""

    pose: Pose = (0.0, 0.0, 0.0)
    length: float = 0.1  # m


@dataclass
class BumperSpec:
    """A ring of binary touch sensors (Stage ``bumper``, Player's bumper interface): a segment
    reads 1 while an obstacle (a wall, or a body with ``obstacle_return``) touches it."""

    name: str = "bumper"
    pose: Pose = (0.0, 0.0, 0.0)  # mount pose on the robot; segments are relative to it
    segments: list[BumperSegmentSpec] = field(default_factory=list)
    interval: float = 0.1


@dataclass
class FiducialSpec:
    """A fiducial finder (Stage ``fiducial``, Player's fiducial interface): reports the models
    with a non-zero ``fiducial_return`` and the same ``fiducial_key`` in range, in its field of
    view and in line of sight; their id only within ``range_max_id`` (0 beyond, as Stage)."""

    name: str = "fiducial"
    pose: Pose = (0.0, 0.0, 0.0)
    range_min: float = 0.0  # m; nearer fiducials are reported at this range (Stage)
    range_max: float = 8.0  # m; Stage's default
    range_max_id: float = 5.0  # m; the id is read only nearer than this
    fov: float = math.pi  # rad
    key: int = 0  # sees only models whose fiducial_key equals this (Stage's finder fiducial_key)
    range_noise: float = 0.0  # standard deviation of the range, m (Stage has none)
    bearing_noise: float = 0.0  # standard deviation of the bearing, rad
    interval: float = 0.1


@dataclass
class BatterySpec:
    """A robot's battery and what drains it (:mod:`simulator.energy`): ``capacity`` joules when
    full, ``charge`` the fraction it starts with, ``per_metre`` joules per metre driven,
    ``per_radian`` joules per radian turned, ``watts`` the constant draw of electronics and
    sensors, ``max_charge`` the most watts it takes from a charger (0: whatever the charger gives).
    The defaults are a Pioneer 2DX/3DX's (:data:`simulator.energy.PIONEER_DX`)."""

    capacity: float = 252.0 * 3600.0  # J: three 12 V lead-acid batteries, 252 Wh (a Pioneer)
    charge: float = 1.0  # fraction of capacity at start
    per_metre: float = 20.0  # J/m
    per_radian: float = 4.0  # J/rad
    watts: float = 20.0  # W, constant
    max_charge: float = 0.0  # W, 0: no limit of its own


@dataclass
class ChargerSpec:
    """A charging station (our extension of Stage): a robot whose centre is within ``distance``
    metres of ``pose`` (and, when ``angle`` is set, whose heading is within ``angle`` radians of
    the pose's yaw) is docked and charges at ``rate`` watts. Not a body: robots drive onto it."""

    name: str
    pose: Pose = (0.0, 0.0, 0.0)
    rate: float = 100.0  # W
    distance: float = 0.3  # m
    angle: float | None = None  # rad; None: any heading docks
    source: str = ""


@dataclass
class ModelSpec:
    """A body in the world: a robot when ``position`` is true, otherwise a passive object."""

    name: str
    type_name: str = "model"  # the Stage type or macro it was made from, e.g. "fancypioneer2dx"
    position: bool = False  # true: a robot base with a differential drive (Stage ``position``)
    pose: Pose = (0.0, 0.0, 0.0)
    size: tuple[float, float, float] = (0.44, 0.38, 0.22)  # m; Pioneer 2DX by default
    color: tuple[int, int, int] = (255, 0, 0)
    mass: float = 10.0  # kg
    # What other sensors see of this model (Stage's *_return flags).
    obstacle_return: bool = True
    laser_return: bool = True  # Stage 3 name; Stage 4's ranger_return maps here too
    blob_return: bool = True
    gripper_return: bool = False
    fiducial_return: int = 0  # id fiducial finders read; 0: not seen by them (Stage)
    fiducial_key: int = 0  # only finders with the same key see this model (Stage)
    # Position model (robots only).
    drive: str = "diff"
    max_speed: tuple[float, float] = (1.0, math.radians(90.0))  # |v| m/s, |w| rad/s
    max_accel: tuple[float, float] = (1.0, math.radians(180.0))  # m/s^2, rad/s^2
    # Odometry error: a per-robot scale bias drawn uniformly in [-e, e] for (x, y, yaw) at start,
    # as Stage's ``odom_error``, plus white noise of std ``odom_noise`` (fraction of motion).
    odom_error: tuple[float, float, float] = (0.03, 0.03, 0.05)
    odom_noise: tuple[float, float, float] = (0.01, 0.01, 0.02)
    rangers: list[RangerSpec] = field(default_factory=list)
    blobfinders: list[BlobfinderSpec] = field(default_factory=list)
    grippers: list[GripperSpec] = field(default_factory=list)
    bumpers: list[BumperSpec] = field(default_factory=list)
    fiducials: list[FiducialSpec] = field(default_factory=list)
    # Shape (Stage ``block`` and ``origin``): outlines in any unit, scaled together so that their
    # bounding box is ``size`` and centred on ``origin`` (x, y, yaw in the body frame); no blocks:
    # one ``size`` box. The body's pose is the model's pose; only the shape is offset.
    blocks: list[tuple[tuple[float, float], ...]] = field(default_factory=list)
    origin: Pose = (0.0, 0.0, 0.0)
    battery: BatterySpec | None = field(default_factory=BatterySpec)  # robots only; None: no battery model
    localization: str = "odom"  # what position2d reports: "odom" (odometry) or "gps" (ground truth)
    ctrl: str | None = None  # built-in controller (Stage ``ctrl``), e.g. "wander"; robots only
    source: str = ""  # "file:line" where it was declared, for messages


@dataclass
class FloorplanSpec:
    """The static map: a bitmap where dark pixels are occupied.

    Placement is either Stage's (``size`` in metres and the centre ``pose``) or the mapfile
    driver's (``resolution`` in m/pixel and ``origin`` = world position of the bottom-left
    corner, thesis appendix A.2), or a ROS map_server YAML's. The parsers fill both ``resolution``
    and ``origin``.
    """

    bitmap: Path
    resolution: float  # m per pixel (square cells)
    origin: tuple[float, float]  # world (x, y) of the bottom-left corner of the bitmap
    size: tuple[float, float] | None = None  # m; when given, the bitmap is scaled to it
    name: str = "floorplan"
    threshold: float = 0.5  # a pixel darker than this fraction of full brightness is occupied
    boundary: bool = False  # Stage ``boundary 1``: walls along the map's outer edge
    # From a ROS map_server YAML (``bitmap`` is then the image it names; gridmap.read_map_yaml):
    negate: bool = False  # bright pixels are occupied (``threshold`` then counts from black)
    mode: str = "trinary"  # map_server's trinary/scale (grey levels) or raw (percent values)
    mapfile: Path | None = None  # the YAML the floorplan came from


@dataclass
class WorldSpec:
    """A whole world: floorplan, robots and objects, clock settings."""

    floorplan: FloorplanSpec | None = None
    models: list[ModelSpec] = field(default_factory=list)
    chargers: list[ChargerSpec] = field(default_factory=list)
    interval_sim: float = 0.1  # s per simulation step (Stage ``interval_sim``, in ms in files)
    speedup: float = 1.0  # real-time factor when paced; <= 0 or inf means as fast as possible
    seed: int = 0
    quit_time: float = 0.0  # s of simulated time after which a run stops (Stage ``quit_time``); 0: never
    resolution: float = 0.02  # m, the static map's collision and raytrace grid (Stage ``resolution``)
    #: threads the ray casting runs on (Stage ``threads``: 0 or 1 the stepping thread alone); None: every core.
    #: Parallel casting finishes a step sooner but costs more CPU in all (docs/benchmarks.md, "Crowd").
    threads: int | None = None
    source: str = ""  # path of the file this came from
    warnings: list[str] = field(default_factory=list)  # "file:line: ..." messages from parsing

    def robots(self) -> list[ModelSpec]:
        return [m for m in self.models if m.position]

    def model(self, name: str) -> ModelSpec:
        for m in self.models:
            if m.name == name:
                return m
        raise KeyError(name)


# A small table of X11 colour names used by Stage worlds (Stage looks names up in rgb.txt).
NAMED_COLORS: dict[str, tuple[int, int, int]] = {
    "black": (0, 0, 0),
    "white": (255, 255, 255),
    "red": (255, 0, 0),
    "green": (0, 255, 0),
    "blue": (0, 0, 255),
    "yellow": (255, 255, 0),
    "cyan": (0, 255, 255),
    "magenta": (255, 0, 255),
    "orange": (255, 165, 0),
    "purple": (160, 32, 240),
    "gray": (190, 190, 190),
    "grey": (190, 190, 190),
    "dark gray": (169, 169, 169),
    "darkgray": (169, 169, 169),
    "light gray": (211, 211, 211),
    "lightgray": (211, 211, 211),
    "gray30": (77, 77, 77),
    "gray50": (127, 127, 127),
    "gray70": (179, 179, 179),
    "gray90": (229, 229, 229),
    "brown": (165, 42, 42),
    "pink": (255, 192, 203),
    "dark blue": (0, 0, 139),
    "darkblue": (0, 0, 139),
    "dark green": (0, 100, 0),
    "darkgreen": (0, 100, 0),
    "dark red": (139, 0, 0),
    "darkred": (139, 0, 0),
    "navy": (0, 0, 128),
    "orchid": (218, 112, 214),
    "gold": (255, 215, 0),
}


def parse_color(value: str | tuple | list) -> tuple[int, int, int]:
    """A colour from a name (``"green"``), ``#rrggbb``, or an ``[r g b (a)]`` list of 0..1 floats
    (Stage's ``color_rgba``) or 0..255 ints. Raises ``ValueError`` with the value on failure."""
    if isinstance(value, str):
        v = value.strip().lower()
        if v in NAMED_COLORS:
            return NAMED_COLORS[v]
        if v.startswith("#") and len(v) == 7:
            try:
                return (int(v[1:3], 16), int(v[3:5], 16), int(v[5:7], 16))
            except ValueError:
                pass
        raise ValueError(f"unknown colour {value!r} (use a name such as 'green', '#00ff00' or [r g b])")
    vals = [float(x) for x in value]
    if len(vals) not in (3, 4):
        raise ValueError(f"colour {list(value)!r} needs 3 or 4 numbers")
    if all(0.0 <= x <= 1.0 for x in vals[:3]):
        return tuple(int(round(x * 255)) for x in vals[:3])  # type: ignore[return-value]
    return tuple(int(round(max(0.0, min(255.0, x)))) for x in vals[:3])  # type: ignore[return-value]
