"""The simulator's readings and device specs as wire messages: the ``sim`` driver's conversions.

The simulator imports nothing of ours (docs/concepts.md, "Layers"), so turning its readings
(:mod:`simulator.sensors`) and device specs (:mod:`simulator.spec`) into the Player interfaces'
messages of :mod:`rsal.interfaces` happens on this side, one function per interface: the data a
device publishes and the geometry its ``rpc/describe`` reports. Used by
:mod:`mrs_bridge.drivers.sim` and the test rigs (:mod:`mrs_bridge.rigs.stacksim`).
"""

from __future__ import annotations

from typing import Any

from rsal.interfaces.bumper import BumperData, BumperGeometry, BumperSegment
from rsal.interfaces.fiducial import FiducialData, FiducialGeometry, FiducialItem
from rsal.interfaces.power import lead_acid_volts
from rsal.msgs import BlobData, BlobfinderData, GripperData, PowerData, RangerData

__all__ = [
    "battery_truth",
    "battery_volts",
    "blobfinder_data",
    "blobfinder_geometry",
    "bumper_data",
    "bumper_geometry",
    "charger_geometry",
    "fiducial_data",
    "fiducial_geometry",
    "gripper_data",
    "gripper_geometry",
    "power_data",
    "ranger_data",
    "ranger_geometry",
]


def _rgb(c) -> int:
    """``(r, g, b)`` as Player's packed ``0xRRGGBB``."""
    return (c[0] << 16) | (c[1] << 8) | c[2]


# ---------------------------------------------------------------------------------- data
def ranger_data(r) -> RangerData:
    """A :class:`simulator.sensors.ranger.RangerReading` as RangerData: a laser (one sensor of many
    samples) with its first beam's angle and the step between beams; a sonar ring without them."""
    s = r.spec.sensors
    if r.spec.kind == "sonar" or len(s) != 1:
        return RangerData(r.time, r.ranges, 0.0, 0.0, min(x.range_min for x in s), max(x.range_max for x in s))
    sen = s[0]
    step = sen.fov / (sen.samples - 1) if sen.samples > 1 else 0.0
    return RangerData(r.time, r.ranges, -sen.fov / 2 + sen.pose[2], step, sen.range_min, sen.range_max)


def blobfinder_data(t: float, spec, blobs) -> BlobfinderData:
    """The blobs a blobfinder of ``spec`` (:class:`simulator.spec.BlobfinderSpec`) sees at ``t``."""
    items = [
        BlobData(i, _rgb(b.color), b.x, b.y, b.left, b.right, b.top, b.bottom, b.area, b.range, b.bearing)
        for i, b in enumerate(blobs)
    ]
    return BlobfinderData(t, spec.image[0], spec.image[1], items)


def gripper_data(t: float, st) -> GripperData:
    """A :class:`simulator.sensors.gripper.GripperState` as GripperData (beams as bits 0 and 1)."""
    beams = int(st.inner_beam) | (int(st.outer_beam) << 1)
    return GripperData(t, st.paddles, st.lift, beams, 1 if st.carrying else 0, st.carrying)


def bumper_data(b) -> BumperData:
    """A :class:`simulator.sensors.bumper.BumperReading` as BumperData (one 0/1 per segment)."""
    return BumperData(b.time, tuple(int(x) for x in b.pressed))


def fiducial_data(t: float, seen) -> FiducialData:
    """What a fiducial finder saw (:class:`simulator.sensors.fiducial.Fiducial` list) at ``t``;
    Stage's id 0 (beyond ``range_max_id``) travels as -1, the wire's "not identified"
    (``fiducial_return`` 0 is never a real id)."""
    return FiducialData(t, [FiducialItem(f.id or -1, f.pose, f.range, f.bearing) for f in seen])


def battery_volts(percent: float) -> float:
    """The simulated battery's voltage at ``percent`` charge: the lead-acid curve of
    :func:`rsal.interfaces.power.lead_acid_volts`, 10.5 V empty to 13 V full."""
    return lead_acid_volts(percent / 100.0)


def power_data(t: float, percent: float, charging: bool = False, low: bool = False) -> PowerData:
    """The simulated battery at ``percent`` charge (a :class:`simulator.energy.BatteryState`'s
    ``fraction`` times 100)."""
    return PowerData(t, battery_volts(percent), min(100.0, max(0.0, percent)), bool(charging), bool(low))


def battery_truth(b) -> dict[str, Any]:
    """A :class:`simulator.energy.BatteryState` as an entry of the simulation's ``batteries`` rpc:
    ``battery`` (false: no battery model), ``capacity`` J, ``fraction``, ``charging``, ``charger`` (nil: not docked),
    ``empty``, and the record since the world was built: ``lowest`` fraction, ``flat`` s, ``charged`` J."""
    return {
        "battery": b.capacity > 0, "capacity": b.capacity, "fraction": b.fraction, "charging": b.charging,
        "charger": b.charger, "empty": b.empty, "lowest": b.lowest, "flat": b.flat, "charged": b.charged,
    }  # fmt: skip


# ---------------------------------------------------------------------------------- geometry
def charger_geometry(c) -> dict[str, Any]:
    """A :class:`simulator.spec.ChargerSpec` as an entry of the simulation's ``describe``
    ``chargers``: ``name``, ``pose`` [x, y, yaw], ``rate`` W, ``distance`` m, ``angle`` rad (nil:
    any heading docks)."""
    return {"name": c.name, "pose": list(c.pose), "rate": c.rate, "distance": c.distance, "angle": c.angle}


def ranger_geometry(r) -> dict[str, Any]:
    """A :class:`simulator.spec.RangerSpec` as the ranger's ``describe`` geometry."""
    sensors = [
        {"pose": list(x.pose), "fov": x.fov, "samples": x.samples, "range_min": x.range_min, "range_max": x.range_max}
        for x in r.sensors
    ]
    return {"kind": r.kind, "pose": list(r.pose), "sensors": sensors}


def blobfinder_geometry(b) -> dict[str, Any]:
    """A :class:`simulator.spec.BlobfinderSpec` as the blobfinder's ``describe`` geometry."""
    return {
        "pose": list(b.pose),
        "fov": b.fov,
        "range_max": b.range_max,
        "image": list(b.image),
        "colors": [_rgb(c) for c in b.colors],
    }


def gripper_geometry(g) -> dict[str, Any]:
    """A :class:`simulator.spec.GripperSpec` as the gripper's ``describe`` geometry."""
    return {"pose": list(g.pose), "size": list(g.size), "capacity": 1}


def bumper_geometry(b) -> dict[str, Any]:
    """A :class:`simulator.spec.BumperSpec` as BumperGeometry's map."""
    return BumperGeometry(b.pose, tuple(BumperSegment(x.pose, x.length) for x in b.segments)).to_dict()


def fiducial_geometry(f) -> dict[str, Any]:
    """A :class:`simulator.spec.FiducialSpec` as FiducialGeometry's map."""
    return FiducialGeometry(tuple(f.pose), f.fov, f.range_min, f.range_max, f.range_max_id).to_dict()
