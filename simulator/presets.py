"""Built-in device and robot presets: fresh :mod:`simulator.spec` objects for the TAMS hardware.

The numbers are the ones the thesis's Stage include files give (appendix A.1 ``devices.inc``,
A.5 ``urg.inc``, A.6 ``utm30lx.inc``) and the manufacturers' data sheets: the Hokuyo URG-04LX and
UTM-30LX scanning lasers, the sonar rings of the MobileRobots Pioneer 2DX (8 transducers) and
Pioneer 3AT (16), the blob camera and gripper of the TAMS Pioneers, and the green blob they
collect. Every function returns new objects, so callers may change them freely.

The YAML world loader (:mod:`simulator.yamlworld`) looks presets up by name in
:data:`ROBOT_PRESETS`, :data:`DEVICE_PRESETS` and :data:`OBJECT_PRESETS`.

Units: metres, seconds, kilograms; poses are ``(x, y, yaw)`` with yaw in radians (the spec's
convention); angles given as ``*_deg`` arguments are degrees.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

from .energy import PIONEER_AT, PIONEER_DX
from .spec import (
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

__all__ = [
    "DEVICE_PRESETS",
    "OBJECT_PRESETS",
    "ROBOT_PRESETS",
    "blob",
    "blobfinder",
    "box",
    "fiducial_finder",
    "gripper",
    "pioneer2dx",
    "pioneer_bumper",
    "pioneer2dx_sonar",
    "pioneer3at",
    "pioneer3at_sonar",
    "urg04lx",
    "utm30lx",
]

Pose = tuple[float, float, float]
Color = str | tuple[int, int, int] | Sequence[float]

# Sonar transducers of the Pioneers: (x m, y m, yaw deg) in the robot frame.
_P2DX_SONAR: tuple[tuple[float, float, float], ...] = (
    (0.069, 0.136, 90.0),
    (0.114, 0.119, 50.0),
    (0.148, 0.078, 30.0),
    (0.166, 0.027, 10.0),
    (0.166, -0.027, -10.0),
    (0.148, -0.078, -30.0),
    (0.114, -0.119, -50.0),
    (0.069, -0.136, -90.0),
)
_P3AT_FRONT_LEFT: tuple[tuple[float, float, float], ...] = (
    (0.147, 0.136, 90.0),
    (0.193, 0.119, 50.0),
    (0.227, 0.079, 30.0),
    (0.245, 0.027, 10.0),
)
_P3AT_SONAR: tuple[tuple[float, float, float], ...] = (
    *_P3AT_FRONT_LEFT,
    *((x, -y, -a) for x, y, a in reversed(_P3AT_FRONT_LEFT)),
    (-0.144, -0.136, -90.0),
    (-0.189, -0.119, -130.0),
    (-0.223, -0.079, -150.0),
    (-0.241, -0.027, -170.0),
    (-0.241, 0.027, 170.0),
    (-0.223, 0.079, 150.0),
    (-0.189, 0.119, 130.0),
    (-0.144, 0.136, 90.0),
)

SONAR_FOV_DEG = 15.0  # cone width of one Pioneer transducer
SONAR_RANGE = (0.0, 5.0)  # m
SONAR_NOISE = 0.02  # m, standard deviation
LASER_NOISE = 0.01  # m, standard deviation of both Hokuyos


def _pose(pose: Sequence[float]) -> Pose:
    x, y, a = (float(v) for v in pose)
    return (x, y, a)


def _laser(name: str, pose: Sequence[float], fov_deg: float, samples: int, rmin: float, rmax: float) -> RangerSpec:
    sensor = RangerSensorSpec(
        pose=(0.0, 0.0, 0.0),
        range_min=rmin,
        range_max=rmax,
        fov=math.radians(fov_deg),
        samples=samples,
        noise=LASER_NOISE,
    )
    return RangerSpec(name=name, kind="laser", sensors=[sensor], pose=_pose(pose))


def urg04lx(pose: Sequence[float] = (0.13, 0.0, 0.0), *, name: str = "laser") -> RangerSpec:
    """Hokuyo URG-04LX: 240 deg in 682 samples, 0.02 .. 5.6 m (thesis A.5), 1 cm noise."""
    return _laser(name, pose, 240.0, 682, 0.02, 5.6)


def utm30lx(pose: Sequence[float] = (0.13, 0.0, 0.0), *, name: str = "laser") -> RangerSpec:
    """Hokuyo UTM-30LX: 270 deg in 1080 samples, 0.1 .. 30 m (thesis A.6), 1 cm noise."""
    return _laser(name, pose, 270.0, 1080, 0.1, 30.0)


def _sonar_ring(layout: Sequence[tuple[float, float, float]], pose: Sequence[float], name: str) -> RangerSpec:
    sensors = [
        RangerSensorSpec(
            pose=(x, y, math.radians(a)),
            range_min=SONAR_RANGE[0],
            range_max=SONAR_RANGE[1],
            fov=math.radians(SONAR_FOV_DEG),
            samples=1,
            noise=SONAR_NOISE,
        )
        for x, y, a in layout
    ]
    return RangerSpec(name=name, kind="sonar", sensors=sensors, pose=_pose(pose))


def pioneer2dx_sonar(pose: Sequence[float] = (0.0, 0.0, 0.0), *, name: str = "sonar") -> RangerSpec:
    """The Pioneer 2DX front ring: 8 transducers, 15 deg cones, 0 .. 5 m, 2 cm noise."""
    return _sonar_ring(_P2DX_SONAR, pose, name)


def pioneer3at_sonar(pose: Sequence[float] = (0.0, 0.0, 0.0), *, name: str = "sonar") -> RangerSpec:
    """The Pioneer 3AT rings: 8 front (left to right) and 8 rear (right to left) transducers."""
    return _sonar_ring(_P3AT_SONAR, pose, name)


def blobfinder(
    colors: Sequence[Color] = ("green",),
    fov_deg: float = 90.0,
    range_max: float = 3.0,
    image: tuple[int, int] = (80, 60),
    *,
    pose: Sequence[float] = (0.0, 0.0, 0.0),
    name: str = "blobfinder",
) -> BlobfinderSpec:
    """The TAMS blob camera (thesis A.1 ``bobsblobfinder``): 90 deg, 3 m, 80 x 60 pixels."""
    return BlobfinderSpec(
        name=name,
        pose=_pose(pose),
        colors=[parse_color(c) for c in colors],
        fov=math.radians(fov_deg),
        range_max=float(range_max),
        image=(int(image[0]), int(image[1])),
    )


def gripper(
    pose: Sequence[float] = (0.23, 0.0, 0.0),
    size: tuple[float, float] = (0.1, 0.3),
    *,
    paddle_time: float = 1.0,
    lift_time: float = 1.0,
    name: str = "gripper",
) -> GripperSpec:
    """The Pioneer two-paddle gripper, 0.23 m ahead of the centre (thesis A.1 ``bobsgrripper``)."""
    return GripperSpec(
        name=name,
        pose=_pose(pose),
        size=(float(size[0]), float(size[1])),
        paddle_time=float(paddle_time),
        lift_time=float(lift_time),
    )


def pioneer_bumper(
    pose: Sequence[float] = (0.0, 0.0, 0.0),
    size: tuple[float, float] = (0.44, 0.38),
    *,
    clearance: float = 0.015,
    name: str = "bumper",
) -> BumperSpec:
    """The Pioneer bumper rings: 5 segments across the front and 5 across the rear of a body of
    ``size`` (x, y) m, ``clearance`` m outside the hull as the bumper skirts are. Segments 0-4 are
    the front from left to right, 5-9 the rear from right to left (each as seen from the robot)."""
    sx, sy = float(size[0]), float(size[1])
    seg = sy / 5
    ys = [sy / 2 - seg * (i + 0.5) for i in range(5)]
    front = [BumperSegmentSpec((sx / 2 + clearance, y, 0.0), seg) for y in ys]
    rear = [BumperSegmentSpec((-sx / 2 - clearance, -y, math.pi), seg) for y in ys]
    return BumperSpec(name=name, pose=_pose(pose), segments=front + rear)


def fiducial_finder(
    pose: Sequence[float] = (0.0, 0.0, 0.0),
    *,
    range_max: float = 8.0,
    range_max_id: float = 5.0,
    fov_deg: float = 180.0,
    key: int = 0,
    name: str = "fiducial",
) -> FiducialSpec:
    """A fiducial finder with Stage's defaults (8 m, ids within 5 m, 180 degrees)."""
    return FiducialSpec(
        name=name,
        pose=_pose(pose),
        range_max=float(range_max),
        range_max_id=float(range_max_id),
        fov=math.radians(fov_deg),
        key=int(key),
    )


def pioneer2dx(name: str, pose: Sequence[float] = (0.0, 0.0, 0.0), *, color: Color = "red") -> ModelSpec:
    """A Pioneer 2DX base: 0.44 x 0.38 x 0.22 m, 23 kg, 1.0 m/s and 100 deg/s, 8 sonars,
    three 12 V batteries (252 Wh) (:data:`simulator.energy.PIONEER_DX`)."""
    return ModelSpec(
        name=name,
        type_name="pioneer2dx",
        position=True,
        pose=_pose(pose),
        size=(0.44, 0.38, 0.22),
        color=parse_color(color),
        mass=23.0,
        max_speed=(1.0, math.radians(100.0)),
        rangers=[pioneer2dx_sonar()],
        battery=replace(PIONEER_DX),
    )


def pioneer3at(name: str, pose: Sequence[float] = (0.0, 0.0, 0.0), *, color: Color = "red") -> ModelSpec:
    """A Pioneer 3AT base (skid steer, simulated as a differential drive): 0.626 x 0.505 x 0.277 m,
    30 kg, 0.7 m/s and 140 deg/s, 16 sonars, three 12 V batteries (252 Wh)
    (:data:`simulator.energy.PIONEER_AT`)."""
    return ModelSpec(
        name=name,
        type_name="pioneer3at",
        position=True,
        pose=_pose(pose),
        size=(0.626, 0.505, 0.277),
        color=parse_color(color),
        mass=30.0,
        max_speed=(0.7, math.radians(140.0)),
        rangers=[pioneer3at_sonar()],
        battery=replace(PIONEER_AT),
    )


def blob(name: str, pose: Sequence[float] = (0.0, 0.0, 0.0), color: Color = "green") -> ModelSpec:
    """The 30 cm object of thesis A.1 ``define blob model``: blob cameras see it, grippers pick it
    up, rangers and robots pass through it."""
    return ModelSpec(
        name=name,
        type_name="blob",
        position=False,
        pose=_pose(pose),
        size=(0.3, 0.3, 0.3),
        color=parse_color(color),
        mass=0.5,
        obstacle_return=False,
        laser_return=False,
        blob_return=True,
        gripper_return=True,
    )


def box(
    name: str,
    pose: Sequence[float] = (0.0, 0.0, 0.0),
    color: Color = "gray",
    size: Sequence[float] = (0.5, 0.5, 0.5),
    mass: float = 5.0,
) -> ModelSpec:
    """A solid box (furniture, a crate): robots bump into it and every sensor sees it."""
    sx, sy, sz = (float(v) for v in size)
    return ModelSpec(
        name=name,
        type_name="box",
        position=False,
        pose=_pose(pose),
        size=(sx, sy, sz),
        color=parse_color(color),
        mass=float(mass),
        obstacle_return=True,
        laser_return=True,
        blob_return=True,
        gripper_return=False,
    )


ROBOT_PRESETS: dict[str, Callable[..., ModelSpec]] = {
    "pioneer2dx": pioneer2dx,
    "pioneer3at": pioneer3at,
}
"""Robot bases by name: ``f(name, pose, *, color)``."""

DEVICE_PRESETS: dict[str, Callable[..., RangerSpec | BlobfinderSpec | GripperSpec | BumperSpec | FiducialSpec]] = {
    "urg04lx": urg04lx,
    "utm30lx": utm30lx,
    "pioneer2dx_sonar": pioneer2dx_sonar,
    "pioneer3at_sonar": pioneer3at_sonar,
    "blobfinder": blobfinder,
    "gripper": gripper,
    "pioneer_bumper": pioneer_bumper,
    "fiducial_finder": fiducial_finder,
}
"""Devices by name; every one takes a ``pose=`` keyword (the mount pose on the robot)."""

OBJECT_PRESETS: dict[str, Callable[..., ModelSpec]] = {
    "blob": blob,
    "box": box,
}
"""Passive objects by name: ``f(name, pose, color)``."""
