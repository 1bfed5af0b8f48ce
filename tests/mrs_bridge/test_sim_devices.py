"""A simulated robot's devices come from its world model (``mrs_bridge.drivers.sim.robot_devices``,
each simulator sensor plug-in declaring what it serves), and the ``sim`` driver serves the bumper
and fiducial devices end to end: a real device server in this process (loopback Zenoh) read by
the client proxies, judged against the simulator's ground truth."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from bridge_helpers import LiveServer

import mrs_bridge.drivers  # noqa: F401  (registers the built-in drivers)
from mrs_bridge.cli import sim_config
from mrs_bridge.config import ConfigError, DriverConfig, ServerConfig
from mrs_bridge.drivers.sim import robot_devices
from rsal.interfaces.bumper import Bumper, BumperGeometry
from rsal.interfaces.fiducial import Fiducial, FiducialGeometry
from rsal.keys import DeviceAddr
from simulator.presets import fiducial_finder, pioneer_bumper
from simulator.spec import ModelSpec, RangerSensorSpec, RangerSpec, WorldSpec
from simulator.world import World
from tests.conftest import wait_until


def robot(name: str, pose=(0.0, 0.0, 0.0), **kw) -> ModelSpec:
    kw.setdefault("odom_error", (0.0, 0.0, 0.0))
    kw.setdefault("odom_noise", (0.0, 0.0, 0.0))
    return ModelSpec(name=name, position=True, pose=pose, size=(0.44, 0.38, 0.22), **kw)


def contact_world() -> World:
    """r0 at the origin facing +x with the Pioneer bumper rings (updated every 0.3 s, every third
    step) and a fiducial finder (ids within 2 m); a box against its front bumper; markers 7
    (1.70 m away) and 9 (3.35 m: seen, id unread); r1 with a laser only."""
    laser = RangerSpec(name="laser", kind="laser", sensors=[RangerSensorSpec(samples=9)])
    models = [
        robot("r0", bumpers=[replace(pioneer_bumper(), interval=0.3)], fiducials=[fiducial_finder(range_max_id=2.0)]),
        robot("r1", pose=(-3.0, 2.0, 0.0), rangers=[laser]),
        ModelSpec(name="box", pose=(0.38, 0.0, 0.0), size=(0.3, 0.3, 0.3), mass=1000.0),
        ModelSpec(name="m7", pose=(1.5, 0.8, 0.0), size=(0.1, 0.1, 0.1), obstacle_return=False, fiducial_return=7),
        ModelSpec(name="m9", pose=(3.0, -1.5, 0.0), size=(0.1, 0.1, 0.1), obstacle_return=False, fiducial_return=9),
    ]
    return World(WorldSpec(models=models, speedup=4.0), seed=0)


def test_a_robots_devices_come_from_its_world_model():
    w = contact_world()
    assert robot_devices(w.model_spec("r0")) == [("position2d", 0), ("bumper", 0), ("fiducial", 0), ("power", 0)]
    assert robot_devices(w.model_spec("r1")) == [("position2d", 0), ("ranger", 0), ("laser", 0), ("power", 0)]
    provided = {str(a) for d in sim_config(w).drivers for a in d.provides}
    assert {"r0:bumper:0", "r0:fiducial:0", "r1:laser:0"} <= provided
    assert not {"r1:bumper:0", "r1:fiducial:0", "r0:laser:0"} & provided


def test_nav_robots_star_gives_every_robot_with_a_laser_or_sonar_the_navigation_stack(tmp_path):
    from PIL import Image

    from simulator.presets import pioneer2dx_sonar
    from simulator.spec import FloorplanSpec

    img = np.full((80, 80), 255, dtype=np.uint8)
    img[:2, :] = img[-2:, :] = img[:, :2] = img[:, -2:] = 0
    Image.fromarray(img).save(tmp_path / "room.png")
    laser = RangerSpec(name="laser", kind="laser", sensors=[RangerSensorSpec(samples=9)])
    models = [
        robot("a", rangers=[laser]),
        robot("b", pose=(1.0, 1.0, 0.0), rangers=[pioneer2dx_sonar()]),
        robot("c", pose=(-1.0, -1.0, 0.0)),
    ]
    fp = FloorplanSpec(bitmap=tmp_path / "room.png", resolution=0.05, origin=(-2.0, -2.0))
    w = World(WorldSpec(floorplan=fp, models=models), seed=0)

    def amcl(nav_robots):
        cfg = sim_config(w, nav="vfh", nav_robots=nav_robots)
        return {d.provides[0].node: [str(r) for r in d.requires] for d in cfg.drivers if d.name == "amcl"}

    assert set(amcl(None)) == {"a"}  # default: the robots with a laser
    star = amcl(["*"])
    assert set(star) == {"a", "b"}  # c has no ranger
    assert "b:sonar:0" in star["b"] and "a:laser:0" in star["a"]


def test_a_device_the_model_lacks_is_refused_with_the_fix():
    w = contact_world()
    cfg = ServerConfig(
        node="sim",
        drivers=[
            sim_config(w).drivers[0],
            DriverConfig("sim", [DeviceAddr("r1", "bumper", 0)], [], {"model": "r1"}, None, "t.toml:3"),
        ],
    )
    from mrs_bridge.drivers.sim import SimDriver

    class _Server:
        shared = {"simulator.world": w}

    with pytest.raises(ConfigError, match=r"t.toml:3: model 'r1' has no bumper:0; add one in the world"):
        SimDriver(cfg.drivers[1], _Server())


@pytest.fixture
def live(port):
    w = contact_world()
    s = LiveServer(sim_config(w, map_device=False), port=port, shared={"simulator.world": w}).start()
    yield w, s
    s.close()


def test_sim_serves_bumper_and_fiducial_devices(live, port, fabric_factory):
    w, _ = live
    fab = fabric_factory(port)
    fab.node("**").wait_for("r0:fiducial:0", timeout=20)
    bumper, fid = fab.device("r0:bumper:0"), fab.device("r0:fiducial:0")
    assert isinstance(bumper, Bumper) and isinstance(fid, Fiducial)

    # Bumper: the box touches the front ring, nothing the rear; the wire carries the simulator's reading.
    wait_until(lambda: bumper.latest is not None and bumper.latest.t > 0.3, 20, "bumper data after a few steps")
    truth = w.bumper("r0").pressed
    assert list(bumper.bumpers) == [int(x) for x in truth]
    assert 2 in bumper.pressed and not set(bumper.pressed) & {5, 6, 7, 8, 9}
    g = bumper.geometry()
    assert isinstance(g, BumperGeometry) and len(g.segments) == 10
    spec = w.model_spec("r0").bumpers[0]
    assert np.allclose([s.pose for s in g.segments], [s.pose for s in spec.segments])
    assert [s.length for s in g.segments] == pytest.approx([s.length for s in spec.segments])
    assert bumper.describe().data == "BumperData"

    # Fiducial: marker 7 with its id at its ground-truth range and bearing, marker 9 beyond
    # range_max_id reported with id -1.
    wait_until(lambda: fid.latest is not None and len(fid.fiducials) == 2, 20, "both markers in view")
    x, y, a = w.get_pose("r0")
    for name, want_id in (("m7", 7), ("m9", -1)):
        mx, my, _ = w.get_pose(name)
        item = min(fid.fiducials, key=lambda f: abs(f.range - math.hypot(mx - x, my - y)))
        assert item.id == want_id
        assert item.range == pytest.approx(math.hypot(mx - x, my - y), abs=1e-3)
        assert item.bearing == pytest.approx(math.atan2(my - y, mx - x) - a, abs=1e-3)
    assert fid.find(7) is not None and fid.find(9) is None
    fg = fid.geometry()
    assert fg == FiducialGeometry((0.0, 0.0, 0.0), math.pi, 0.0, 8.0, 2.0)


def test_bumper_and_fiducial_publish_at_the_sensors_rate(live, port, fabric_factory):
    w, _ = live
    fab = fabric_factory(port)
    fab.node("**").wait_for("r0:bumper:0", timeout=20)
    bumper = fab.device("r0:bumper:0")
    bumper.wait_for_data(20)
    first = bumper.latest.t
    n0 = bumper.count
    wait_until(lambda: bumper.latest.t >= first + 1.0, 20, "a simulated second of bumper data")
    span = bumper.latest.t - first
    per_s = (bumper.count - n0) / span
    interval = w.model_spec("r0").bumpers[0].interval
    assert per_s == pytest.approx(1.0 / interval, rel=0.25)  # one message per bumper update, not one per step


def test_simulation_contacts_rpc_reports_a_robot_moved_onto_another(live, port, fabric_factory):
    w, _ = live
    fab = fabric_factory(port)
    fab.node("**").wait_for("sim:simulation:0", timeout=20)
    sim = fab.device("sim:simulation:0")
    c = sim.rpc("contacts")
    assert (c["robot_robot"], c["robot_wall"], c["robots"]) == (0, 0, {})  # the box is no robot
    sim.rpc("set_pose", name="r1", pose=[0.0, -0.37, 0.0])  # 1 cm into r0's side
    wait_until(lambda: sim.rpc("contacts")["robot_robot"] >= 1, 20, "the contact counted after the next step")
    c = sim.rpc("contacts")
    assert set(c["robots"]) == {"r0", "r1"} and c["robot_wall"] == 0
    assert c["robots"]["r1"][0] >= 1 and c["robots"]["r0"][0] >= 1
