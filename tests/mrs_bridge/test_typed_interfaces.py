"""Interfaces end to end through a real device server (in this process, loopback Zenoh): the
bumper and fiducial proxies against a driver that provides them, and the server's typed hand-over
(``on_cmd`` and ``on_input`` receive the interface's messages, not maps)."""

from __future__ import annotations

import math

import pytest
from bridge_helpers import LiveServer

from mrs_bridge.driver import Driver
from rsal.interfaces.bumper import Bumper, BumperData, BumperGeometry
from rsal.interfaces.fiducial import Fiducial, FiducialData, FiducialGeometry, FiducialItem
from rsal.keys import parse_device
from rsal.msgs import GoalCmd, VelocityCmd
from tests.conftest import wait_until

BUMPER_GEO = {"pose": [0.0, 0.0, 0.0], "segments": [{"pose": [0.25, 0.0, 0.0], "length": 0.3}] * 2}
FIDUCIAL_GEO = {"pose": [0.1, 0.0, 0.0], "fov": math.pi, "range_min": 0.0, "range_max": 5.0, "range_max_id": 3.0}


class Contacts(Driver):
    """Provides a bumper (segment 1 pressed from the 3rd update on) and a fiducial finder (one
    marker, id 7, 1 m ahead and 1 m left)."""

    driver_name = "contacts"
    default_rate = 50.0
    data_types = {"bumper": "BumperData", "fiducial": "FiducialData"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        self.n = 0

    def update(self, now):
        self.n += 1
        for a in self.cfg.provides:
            if a.interface == "bumper":
                self.publish(a, BumperData(now, (0, 1) if self.n >= 3 else (0, 0)))
            else:
                self.publish(a, FiducialData(now, [FiducialItem.at(7, (1.0, 1.0, 0.0))]))

    def geometry(self, addr):
        return BUMPER_GEO if addr.interface == "bumper" else FIDUCIAL_GEO


class Recorder(Driver):
    """A base that records what the server hands it: commands (no ``cmd_types``: the interface's
    own types apply) and the data of the bumper it requires."""

    driver_name = "recorder"
    default_rate = 20.0

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        self.cmds: list = []
        self.inputs: list = []

    def on_cmd(self, addr, msg):
        self.cmds.append(msg)

    def on_input(self, addr, channel, msg):
        if channel == "data":
            self.inputs.append(msg)


CONFIG = """
[[driver]]
name = "contacts"
provides = ["r0:bumper:0", "r0:fiducial:0"]

[[driver]]
name = "recorder"
provides = ["r0:position2d:0"]
requires = ["r0:bumper:0"]
"""


@pytest.fixture
def server(port):
    s = LiveServer(CONFIG, port=port, drivers={"contacts": Contacts, "recorder": Recorder}).start()
    yield s
    s.close()


def test_bumper_and_fiducial_proxies_read_a_live_server(server, port, fabric_factory):
    fab = fabric_factory(port)
    fab.node("**").wait_for("**", count=3, timeout=10)
    bumper = fab.device("r0:bumper:0")
    fid = fab.device("r0:fiducial:0")
    assert isinstance(bumper, Bumper) and isinstance(fid, Fiducial)
    wait_until(lambda: bumper.pressed == (1,), 10, "segment 1 reported pressed")
    assert bumper.any_pressed and bumper.bumpers == (0, 1)
    assert bumper.geometry() == BumperGeometry.from_describe(BUMPER_GEO)
    assert bumper.describe().data == "BumperData"
    fid.wait_for_data(10)
    item = fid.find(7)
    assert item is not None and item.range == pytest.approx(math.sqrt(2)) and fid.find(8) is None
    assert fid.nearest() == item
    g = fid.geometry()
    assert g == FiducialGeometry.from_describe(FIDUCIAL_GEO)
    assert g.to_robot(item) == pytest.approx((1.1, 1.0, 0.0))


def test_server_hands_drivers_typed_commands_and_inputs(server, port, fabric_factory):
    fab = fabric_factory(port)
    fab.node("**").wait_for("r0:position2d:0", timeout=10)
    rec = server.driver("recorder")
    addr = parse_device("r0:position2d:0")
    fab.send(addr, VelocityCmd(0.2, 0.1))
    fab.send(addr, GoalCmd((1.0, 2.0, 0.0)))
    wait_until(lambda: len(rec.cmds) >= 2, 10, "both commands handed to the driver")
    assert rec.cmds[:2] == [VelocityCmd(0.2, 0.1), GoalCmd((1.0, 2.0, 0.0))]
    wait_until(lambda: rec.inputs, 10, "bumper data reached the requiring driver")
    assert all(isinstance(m, BumperData) for m in list(rec.inputs))
