"""The ``replay`` driver (mrs_bridge/drivers/replay.py): parameter validation, the scans it makes,
and the same scans over loopback Zenoh through an in-process device server."""

from __future__ import annotations

import math
import textwrap
import time

import numpy as np
import pytest
from bridge_helpers import LiveServer

from mrs_bridge.config import ConfigError, parse_config
from mrs_bridge.driver import DRIVERS
from mrs_bridge.drivers.replay import ReplayDriver
from mrs_bridge.server import DeviceServer
from rsal.keys import parse_device
from rsal.msgs import Describe, ErrorCode, RangerData, RpcError
from rsal.testing import FakeServer
from tests.conftest import wait_until

WHERE = "replay.toml: driver #1 (replay)"


def make(params: str = "", provides: str = '["r0:laser:0"]', rate: str = "") -> tuple[ReplayDriver, FakeServer]:
    text = f'[[driver]]\nname = "replay"\nprovides = {provides}\n{rate}\n{textwrap.dedent(params)}'
    cfg = parse_config(text, source="replay.toml").drivers[0]
    srv = FakeServer()
    return ReplayDriver(cfg, srv), srv


def config_error(params: str, **kw) -> str:
    with pytest.raises(ConfigError) as ei:
        make(params, **kw)
    msg = str(ei.value)
    assert msg.startswith(WHERE + ": "), msg
    return msg[len(WHERE) + 2 :]


# ---------------------------------------------------------------------------- configuration
def test_registered_under_its_name():
    assert DRIVERS["replay"] is ReplayDriver


def test_defaults_are_a_hokuyo_urg():
    d, _ = make()
    assert (d.samples, d.range_min, d.range_max, d.pattern, d.value, d.count, d.stamp) == (
        682,
        0.02,
        5.6,
        "constant",
        1.0,
        None,
        "elapsed",
    )
    assert d.fov == pytest.approx(math.radians(240))
    assert d.angle_min == pytest.approx(-math.radians(120))
    assert d.angle_min + (d.samples - 1) * d.angle_step == pytest.approx(math.radians(120))
    assert d.rate == 10.0


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        ("smaples = 10", "unknown parameter 'smaples'; did you mean 'samples'?"),
        ("colour = 1", "unknown parameter 'colour'; known: samples, fov, range_min, range_max, pattern, value,"),
        ("samples = 0", "samples = 0 must be an integer >= 1"),
        ("samples = 10.5", "samples = 10.5 must be an integer >= 1"),
        ("samples = true", "samples = True must be an integer >= 1"),
        ("count = 0", "count = 0 must be an integer >= 1"),
        ("fov = 0", "fov = 0 must be in (0, 360] degrees"),
        ("fov = 400", "fov = 400 must be in (0, 360] degrees"),
        ('fov = "wide"', "fov = 'wide' must be a finite number"),
        ("fov = nan", "fov = nan must be a finite number"),
        ("range_max = inf", "range_max = inf must be a finite number"),
        (
            "range_min = 2.0\nrange_max = 1.0",
            "range_min = 2 and range_max = 1 m must satisfy 0 <= range_min < range_max",
        ),
        ("range_min = -0.1", "range_min = -0.1 and range_max = 5.6 m must satisfy"),
        ("value = 9.0", "value = 9 m must lie in [range_min, range_max] = [0.02, 5.6]"),
        ("range_max = 0.5", "value = 1 m must lie in [range_min, range_max] = [0.02, 0.5]"),
        ("period = 0", "period = 0 s must be positive"),
        ('pattern = "swep"', "pattern = 'swep' must be one of constant, sweep; did you mean 'sweep'?"),
        ('pattern = "random"', "pattern = 'random' must be one of constant, sweep"),
        ('stamp = "wall"', "stamp = 'wall' must be one of elapsed, monotonic"),
    ],
)
def test_bad_parameters_name_the_block_and_the_value(params, expected):
    assert config_error(params).startswith(expected)


def test_value_only_matters_for_the_constant_pattern():
    d, _ = make('pattern = "sweep"\nrange_max = 0.5')
    assert d.pattern == "sweep" and d.range_max == 0.5


@pytest.mark.parametrize("iface", ["position2d", "sonar", "map"])
def test_it_provides_only_rangers_and_lasers(iface):
    text = f'[[driver]]\nname = "replay"\nprovides = ["r0:{iface}:0"]\n'
    server = DeviceServer(parse_config(text, source="replay.toml"), session=None)
    with pytest.raises(ConfigError) as ei:
        server.start()
    assert str(ei.value) == f"{WHERE}: driver 'replay' cannot provide '{iface}' (it provides ranger, laser)"


# ---------------------------------------------------------------------------- scans
def test_constant_scans_on_every_provided_device():
    d, srv = make("samples = 5\nfov = 90\nvalue = 2.0", provides='["r0:ranger:0", "r0:laser:0"]')
    d.setup()
    d.update(d._t0 + 0.5)
    assert [a for a, _ in srv.published] == ["r0:ranger:0", "r0:laser:0"]
    scan = srv.published[0][1]
    assert srv.published[1][1] is scan
    assert scan.ranges.dtype == np.dtype("<f4") and scan.ranges.tolist() == [2.0] * 5
    assert scan.t == pytest.approx(0.5)
    assert scan.angle_min == pytest.approx(-math.pi / 4)
    assert scan.angle_step == pytest.approx(math.pi / 8)
    assert (scan.range_min, scan.range_max) == (0.02, 5.6)
    assert d.sent == 1 and d.last is scan


def test_a_single_beam_points_straight_ahead():
    d, srv = make("samples = 1")
    d.update(time.monotonic())
    scan = srv.published[0][1]
    assert (scan.angle_min, scan.angle_step, scan.ranges.shape) == (0.0, 0.0, (1,))


def test_sweep_stays_in_range_and_turns_once_per_period():
    d, _ = make('pattern = "sweep"\nsamples = 64\nrange_min = 0.5\nrange_max = 4.5\nperiod = 2.0')
    a, b, c = d.ranges(0.0), d.ranges(0.5), d.ranges(2.0)
    for r in (a, b, c):
        assert r.dtype == np.dtype("<f4")
        assert r.min() >= 0.5 - 1e-6 and r.max() <= 4.5 + 1e-6
    assert not np.allclose(a, b)  # it moves ...
    np.testing.assert_allclose(a, c, atol=1e-5)  # ... and is back after one period
    assert a.max() - a.min() > 3.9  # the wave spans the range


def test_count_stops_publishing_but_keeps_the_devices():
    d, srv = make("count = 3", rate="rate = 50")
    d.setup()
    for i in range(6):
        d.update(d._t0 + i * 0.02)
    assert len(srv.published) == 3 and d.sent == 3
    assert d.rate == 0.0  # the scheduler stops calling update()
    assert d.publish_rate(None) == 50.0  # describe still tells the configured rate


def test_monotonic_stamps_are_time_monotonic():
    d, srv = make('stamp = "monotonic"')
    before = time.monotonic()
    d.update(before)
    assert before <= srv.published[0][1].t <= time.monotonic()


def test_rate_inf_is_reported_as_zero_in_describe():
    d, _ = make(rate="rate = inf")
    assert math.isinf(d.rate) and d.publish_rate(None) == 0.0


def test_rpc_get_returns_the_latest_scan():
    d, _ = make("samples = 3")
    with pytest.raises(RpcError) as ei:
        d.on_rpc(None, "get", {})
    assert ei.value.code == ErrorCode.UNAVAILABLE
    d.update(time.monotonic())
    got = RangerData.from_dict(d.on_rpc(None, "get", {}))
    assert got.ranges.tolist() == [1.0, 1.0, 1.0]
    with pytest.raises(RpcError) as ei:
        d.on_rpc(parse_device("r0:laser:0"), "set", {})
    assert ei.value.code == ErrorCode.UNKNOWN_OP


def test_geometry_has_the_shape_of_the_sim_laser():
    d, _ = make("samples = 181\nfov = 180\nrange_max = 4.0\ncount = 2")
    g = d.geometry(None)
    assert g["kind"] == "laser" and g["pose"] == [0.0, 0.0, 0.0]
    (s,) = g["sensors"]
    assert s["fov"] == pytest.approx(math.pi) and s["samples"] == 181
    assert (s["range_min"], s["range_max"]) == (0.02, 4.0)
    assert (g["pattern"], g["count"]) == ("constant", 2)


# ---------------------------------------------------------------------------- over the fabric
def test_published_scans_reach_a_client(port, fabric_factory):
    text = """
    [[driver]]
    name = "replay"
    provides = ["r0:ranger:0", "r0:laser:0"]
    rate = 50
    samples = 100
    fov = 270
    pattern = "sweep"
    range_max = 4.0
    """
    srv = LiveServer(text, port=port, drivers={"replay": ReplayDriver}).start()
    try:
        fab = fabric_factory(port)
        fab.node("**").wait_for("r0:*:*", count=2, timeout=10)
        laser, ranger = fab.device("r0:laser:0"), fab.device("r0:ranger:0")
        scan = laser.wait_for_data(5)
        assert scan.ranges.shape == (100,)
        assert 0.02 - 1e-6 <= float(scan.ranges.min()) and float(scan.ranges.max()) <= 4.0 + 1e-6
        assert scan.angle_min == pytest.approx(-math.radians(135))
        assert scan.angle_step == pytest.approx(math.radians(270) / 99)
        n = laser.count
        later = laser.wait_for_data(5, newer_than=n)
        assert later.t > scan.t and not np.array_equal(later.ranges, scan.ranges)  # the sweep moves
        ranger.wait_for_data(5)
        d = laser.describe()
        assert isinstance(d, Describe)
        assert (d.driver, d.rate, d.data, d.ops) == ("replay", 50.0, "RangerData", ["describe", "get"])
        got = RangerData.from_dict(laser.rpc("get"))
        assert got.ranges.shape == (100,)
        # the proxy can place every beam (the shape Robot.obstacle_points uses)
        assert laser.sensor_poses().shape == (100, 3)
    finally:
        srv.close()


def test_count_with_rate_inf_sends_that_many_as_fast_as_it_goes(port, fabric_factory):
    text = """
    [[driver]]
    name = "replay"
    provides = ["r0:laser:0"]
    rate = inf
    count = 25
    samples = 10
    """
    srv = LiveServer(text, port=port, drivers={"replay": ReplayDriver}).start()
    try:
        drv = srv.driver("replay")
        wait_until(lambda: drv.sent == 25, 5, "25 scans")
        fab = fabric_factory(port)
        node = fab.node("**")
        node.wait_for("r0:laser:0", timeout=10)
        d = fab.device("r0:laser:0").describe()
        assert d.rate == 0.0 and d.geometry["count"] == 25
        # nobody subscribed to the scans, so the server dropped them before encoding (data go out
        # only while someone listens): every one of the 25 reached it, none was put
        st = srv.server.stats
        assert drv.sent == 25 and st["published"] + st["unheard"] == 25 and st["published"] == 0
        assert srv.error is None
    finally:
        srv.close()
