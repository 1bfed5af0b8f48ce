"""Presets of simulator.presets: the numbers of the thesis's Stage include files (A.1, A.5, A.6)."""

from __future__ import annotations

import math

import pytest

from simulator import presets
from simulator.spec import BlobfinderSpec, GripperSpec, ModelSpec, RangerSpec

D = math.radians


def test_urg04lx():
    r = presets.urg04lx()
    assert isinstance(r, RangerSpec)
    assert r.kind == "laser" and r.pose == (0.13, 0.0, 0.0) and len(r.sensors) == 1
    s = r.sensors[0]
    assert s.fov == pytest.approx(D(240)) and s.samples == 682
    assert (s.range_min, s.range_max, s.noise) == (0.02, 5.6, 0.01)
    assert presets.urg04lx(pose=(0.2, 0.0, D(10))).pose == (0.2, 0.0, D(10))


def test_utm30lx():
    r = presets.utm30lx()
    s = r.sensors[0]
    assert r.kind == "laser"
    assert s.fov == pytest.approx(D(270)) and s.samples == 1080
    assert (s.range_min, s.range_max, s.noise) == (0.1, 30.0, 0.01)


def test_pioneer2dx_sonar_ring():
    r = presets.pioneer2dx_sonar()
    assert r.kind == "sonar" and r.name == "sonar" and len(r.sensors) == 8
    expect = [(0.069, 0.136, 90), (0.114, 0.119, 50), (0.148, 0.078, 30), (0.166, 0.027, 10)]
    expect += [(x, -y, -a) for x, y, a in reversed(expect)]
    for s, (x, y, a) in zip(r.sensors, expect, strict=True):
        assert s.pose == pytest.approx((x, y, D(a)))
        assert s.samples == 1 and s.fov == pytest.approx(D(15))
        assert (s.range_min, s.range_max, s.noise) == (0.0, 5.0, 0.02)


def test_pioneer3at_sonar_ring():
    r = presets.pioneer3at_sonar()
    assert r.kind == "sonar" and len(r.sensors) == 16
    poses = [s.pose for s in r.sensors]
    front = [(0.147, 0.136, 90), (0.193, 0.119, 50), (0.227, 0.079, 30), (0.245, 0.027, 10)]
    front += [(x, -y, -a) for x, y, a in reversed(front)]
    rear = [
        (-0.144, -0.136, -90), (-0.189, -0.119, -130), (-0.223, -0.079, -150), (-0.241, -0.027, -170),
        (-0.241, 0.027, 170), (-0.223, 0.079, 150), (-0.189, 0.119, 130), (-0.144, 0.136, 90),
    ]  # fmt: skip
    for p, (x, y, a) in zip(poses, front + rear, strict=True):
        assert p == pytest.approx((x, y, D(a)))


def test_robots():
    p = presets.pioneer2dx("r0", (1.0, 2.0, D(90)))
    assert isinstance(p, ModelSpec) and p.position and p.name == "r0" and p.type_name == "pioneer2dx"
    assert p.pose == (1.0, 2.0, D(90)) and p.size == (0.44, 0.38, 0.22) and p.mass == 23.0
    assert p.max_speed == pytest.approx((1.0, D(100)))
    assert [len(r.sensors) for r in p.rangers] == [8]
    q = presets.pioneer3at("r1", color="blue")
    assert q.size == (0.626, 0.505, 0.277) and q.mass == 30.0 and q.color == (0, 0, 255)
    assert q.max_speed == pytest.approx((0.7, D(140)))
    assert [len(r.sensors) for r in q.rangers] == [16]


def test_blob_and_box():
    b = presets.blob("blob0", (1.0, 2.0, 0.0))
    assert not b.position and b.size == (0.3, 0.3, 0.3) and b.mass == 0.5 and b.color == (0, 255, 0)
    assert b.gripper_return and b.blob_return and not b.laser_return and not b.obstacle_return
    x = presets.box("crate", color="brown", size=(1.0, 0.5, 0.4))
    assert x.obstacle_return and x.laser_return and not x.gripper_return and x.size == (1.0, 0.5, 0.4)


def test_blobfinder_and_gripper():
    b = presets.blobfinder()
    assert isinstance(b, BlobfinderSpec)
    assert b.colors == [(0, 255, 0)] and b.fov == pytest.approx(D(90)) and b.range_max == 3.0
    assert b.image == (80, 60)
    assert presets.blobfinder(["red", "#0000ff"]).colors == [(255, 0, 0), (0, 0, 255)]
    g = presets.gripper()
    assert isinstance(g, GripperSpec) and g.pose == (0.23, 0.0, 0.0)


def test_presets_are_fresh_objects():
    a = presets.pioneer2dx("a")
    a.rangers[0].sensors[0].noise = 1.0
    a.rangers.append(presets.urg04lx())
    b = presets.pioneer2dx("b")
    assert len(b.rangers) == 1 and b.rangers[0].sensors[0].noise == 0.02


def test_registries():
    assert set(presets.ROBOT_PRESETS) == {"pioneer2dx", "pioneer3at"}
    assert {"urg04lx", "utm30lx", "pioneer2dx_sonar", "pioneer3at_sonar", "blobfinder", "gripper"} <= set(
        presets.DEVICE_PRESETS
    )
    for name, make in presets.DEVICE_PRESETS.items():
        dev = make(pose=(0.1, 0.0, 0.0))
        assert dev.pose == (0.1, 0.0, 0.0), name
    for name, make in presets.ROBOT_PRESETS.items():
        assert make("x", (0.0, 0.0, 0.0)).type_name == name
    assert set(presets.OBJECT_PRESETS) == {"blob", "box"}
