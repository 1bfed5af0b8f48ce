"""The sim driver's conversions of simulator readings and specs to wire messages (mrs_bridge.drivers.simmsgs)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from mrs_bridge.drivers import simmsgs
from rsal.interfaces.fiducial import FiducialData
from rsal.msgs import decode_map, encode
from simulator.spec import BlobfinderSpec, RangerSensorSpec, RangerSpec


def test_a_laser_scan_carries_its_first_beam_angle_and_step():
    sen = RangerSensorSpec(pose=(0.1, 0.0, 0.2), range_min=0.02, range_max=5.6, fov=math.radians(240), samples=5)
    reading = SimpleNamespace(
        time=1.5, ranges=np.array([1.0, 2.0, 3.0, 4.0, 5.0]), spec=RangerSpec(kind="laser", sensors=[sen])
    )
    d = simmsgs.ranger_data(reading)
    assert d.t == 1.5 and list(d.ranges) == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert d.angle_min == pytest.approx(-math.radians(120) + 0.2)
    assert d.angle_step == pytest.approx(math.radians(60))
    assert (d.range_min, d.range_max) == (0.02, 5.6)


def test_a_sonar_ring_has_no_beam_fan_and_spans_its_transducers_ranges():
    sensors = [
        RangerSensorSpec(range_min=0.1, range_max=5.0, samples=1),
        RangerSensorSpec(range_min=0.0, range_max=3.0, samples=1),
    ]
    reading = SimpleNamespace(time=0.2, ranges=np.array([1.0, 2.0]), spec=RangerSpec(kind="sonar", sensors=sensors))
    d = simmsgs.ranger_data(reading)
    assert (d.angle_min, d.angle_step, d.range_min, d.range_max) == (0.0, 0.0, 0.0, 5.0)


def test_an_unidentified_fiducial_travels_as_minus_one():
    seen = [SimpleNamespace(id=0, pose=(1.0, 0.0, 0.0), range=1.0, bearing=0.0),
            SimpleNamespace(id=7, pose=(2.0, 0.0, 0.0), range=2.0, bearing=0.0)]  # fmt: skip
    d = simmsgs.fiducial_data(3.0, seen)
    assert [f.id for f in d.fiducials] == [-1, 7]
    assert FiducialData.from_dict(decode_map(encode(d))).fiducials[1].id == 7


def test_gripper_beams_are_bits_and_a_carried_model_is_stored():
    st = SimpleNamespace(paddles="closed", lift="up", inner_beam=True, outer_beam=True, carrying="blob0")
    d = simmsgs.gripper_data(2.0, st)
    assert (d.beams, d.stored, d.carrying) == (3, 1, "blob0")
    st.inner_beam, st.carrying = False, None
    assert (simmsgs.gripper_data(2.1, st).beams, simmsgs.gripper_data(2.1, st).stored) == (2, 0)


def test_the_battery_runs_from_10_5_to_13_volts():
    assert simmsgs.power_data(0.0, 0.0).volts == pytest.approx(10.5)
    assert simmsgs.power_data(0.0, 100.0).volts == pytest.approx(13.0)


def test_blobfinder_colours_are_packed_rgb():
    spec = BlobfinderSpec(colors=[(0, 255, 0), (255, 0, 0)], image=(80, 60))
    assert simmsgs.blobfinder_geometry(spec)["colors"] == [0x00FF00, 0xFF0000]
    blob = SimpleNamespace(
        color=(0, 255, 0), x=40, y=30, left=35, right=45, top=25, bottom=35, area=100, range=1.0, bearing=0.0
    )
    d = simmsgs.blobfinder_data(1.0, spec, [blob])
    assert (d.width, d.height) == (80, 60) and d.blobs[0].color == 0x00FF00
