"""The ``hokuyo`` driver (SCIP 2.0): the codec against hand-computed frames, and ``rsal serve`` with
the driver against an emulated URG-04LX / UTM-30LX on a pseudo-terminal
(mrs_bridge/emulators/urg.py): scans with the sensor's geometry, error readings as range_max, a sensor that
goes silent is reported lost and found again without a restart, noise and failed check characters
are dropped and counted, SIGTERM switches the laser off."""

from __future__ import annotations

import math
import signal

import numpy as np
import pytest

from mrs_bridge.config import ConfigError
from mrs_bridge.drivers.hokuyo import (
    MODELS,
    HokuyoDriver,
    ScipError,
    check_char,
    data_lines,
    decode_scan,
    decode_values,
    encode_values,
    parse_fields,
    parse_frame,
)
from mrs_bridge.emulators.urg import HokuyoEmulator
from mrs_bridge.server import make_driver_config
from tests.conftest import rsal_cmd, wait_until


# ---------------------------------------------------------------------------- codec
def test_check_characters_of_the_status_lines():
    assert chr(check_char(b"00")) == "P"  # the "00P" every good answer carries
    assert chr(check_char(b"99")) == "b"  # the "99b" of MD scan frames


def test_three_character_encoding_by_hand():
    # 5432 mm = 1 * 64^2 + 20 * 64 + 56 -> '1' (0x31), 'D' (0x30 + 20), 'h' (0x30 + 56)
    assert encode_values([5432], 3) == b"1Dh"
    assert decode_values(b"1Dh", 3).tolist() == [5432]
    assert decode_values(b"000", 3).tolist() == [0]
    values = np.array([0, 1, 20, 5600, 60000, (1 << 18) - 1])
    assert decode_values(encode_values(values, 3), 3).tolist() == values.tolist()
    with pytest.raises(ValueError):
        encode_values([1 << 18], 3)
    with pytest.raises(ScipError):
        decode_values(b"1D", 3)  # not a whole value
    with pytest.raises(ScipError):
        decode_values(b"1D\x7f", 3)  # outside 0x30-0x6F


def test_a_scan_frame_splits_into_64_character_lines():
    mm = np.arange(100, 100 + 682)
    payload = encode_values(mm, 3)
    lines = data_lines(payload)
    assert [len(ln) for ln in lines[:-1]] == [65] * (len(lines) - 1)  # 64 data + 1 check
    stamp = encode_values([123456], 4)
    raw = b"MD0044072501000\n99b\n" + stamp + bytes([check_char(stamp)]) + b"\n" + b"\n".join(lines)
    frame = parse_frame(raw)
    assert (frame.echo, frame.status) == (b"MD0044072501000", b"99")
    ts, got = decode_scan(frame)
    assert ts == 123456 and got.tolist() == mm.tolist()


def test_frames_with_a_wrong_check_character_are_refused():
    with pytest.raises(ScipError, match="status line"):
        parse_frame(b"BM\n00Q")
    good = data_lines(encode_values([2000] * 30, 3))[0]
    bad = good[:-1] + bytes([good[-1] ^ 1])
    with pytest.raises(ScipError, match="check character"):
        parse_frame(b"GD0044072501\n00P\n" + bad)
    with pytest.raises(ScipError, match="echo"):
        parse_frame(b"\x13\x99garbage\n00P")


def test_parameter_lines_sum_before_the_semicolon_and_with_it():
    body = b"DMAX:5600"
    without = body + b";" + bytes([check_char(body)])
    with_semi = body + b";" + bytes([check_char(body + b";")])
    for ln in (without, with_semi):
        assert parse_fields(parse_frame(b"PP\n00P\n" + ln)) == {"DMAX": "5600"}


def test_configuration_errors_name_the_place_and_the_fix():
    def make(**params):
        return HokuyoDriver(make_driver_config("hokuyo", ["laser:0"], "r0", **params), server=None)

    with pytest.raises(ConfigError, match='needs port = "/dev/ttyACM0"'):
        make()
    with pytest.raises(ConfigError, match="did you mean 'UTM-30LX'"):
        make(port="/dev/x", model="UTM30LX")
    with pytest.raises(ConfigError, match="did you mean 'cluster'"):
        make(port="/dev/x", clusters=2)
    with pytest.raises(ConfigError, match=r"pose = .* must be \[x, y, yaw_degrees\]"):
        make(port="/dev/x", pose=[0, 0])
    with pytest.raises(ConfigError, match="min_angle must be smaller"):
        make(port="/dev/x", min_angle=30, max_angle=-30)


# ---------------------------------------------------------------------------- against the emulator
CONFIG = """\
[server]
node = "r0"

[[driver]]
name = "hokuyo"
provides = ["ranger:0", "laser:0"]
port = "{port}"
model = "{model}"
pose = [0.13, 0, 0]
timeout = 0.5
reconnect = 0.2
"""


@pytest.fixture
def emulator():
    made = []

    def make(model: str = "URG-04LX") -> HokuyoEmulator:
        e = HokuyoEmulator(model)
        made.append(e)
        return e

    yield make
    for e in made:
        e.close()


def serve(tmp_path, procs, port, emu: HokuyoEmulator, model: str):
    cfg = tmp_path / "urg.toml"
    cfg.write_text(CONFIG.format(port=emu.path, model=model))
    return procs(rsal_cmd("serve", str(cfg), "--listen", f"tcp/127.0.0.1:{port}"))


@pytest.mark.parametrize("model", ["URG-04LX", "UTM-30LX"])
def test_scans_arrive_with_the_sensors_geometry(model, tmp_path, procs, port, fabric_factory, emulator):
    emu = emulator(model)
    server = serve(tmp_path, procs, port, emu, model)
    fabric = fabric_factory(port)
    node = fabric.node("r0:*:*")
    node.wait_for("r0:laser:0", 1, 20.0)
    laser = node.device("r0:laser:0")
    scan = laser.wait_for_data(10.0)
    pp = MODELS[model]
    n = pp.amax - pp.amin + 1  # 682 readings for the URG-04LX, 1081 for the UTM-30LX
    assert scan.ranges.size == n
    assert scan.angle_min == pytest.approx((pp.amin - pp.afrt) * 2 * math.pi / pp.ares)
    assert scan.angle_step == pytest.approx(2 * math.pi / pp.ares)
    assert scan.range_max == pytest.approx(pp.dmax / 1000)
    expected = np.full(n, 2.0, dtype=np.float32)
    expected[10] = pp.dmax / 1000  # the error code reads as "nothing seen"
    np.testing.assert_allclose(scan.ranges, expected)
    geo = laser.describe(timeout=5.0).geometry
    assert geo["kind"] == "laser" and geo["model"] == model and geo["sensors"][0]["samples"] == n
    assert geo["pose"] == pytest.approx([0.13, 0.0, 0.0])
    assert b"BM" in emu.commands and any(c.startswith(b"MD") for c in emu.commands)
    assert server.alive()


def test_a_silent_sensor_is_lost_and_found_again(tmp_path, procs, port, fabric_factory, emulator):
    emu = emulator()
    server = serve(tmp_path, procs, port, emu, "URG-04LX")
    fabric = fabric_factory(port)
    node = fabric.node("r0:*:*")
    lost, found = [], []
    node.on_leave(lost.append)
    node.on_join(found.append)
    node.wait_for("r0:laser:0", 1, 20.0)
    laser = node.device("r0:laser:0")
    laser.wait_for_data(10.0)
    emu.set_mode("silent")
    wait_until(lambda: {a.interface for a in lost} >= {"laser", "ranger"}, 10, "the silent laser to be reported lost")
    assert not node.search(node="r0")
    n_found = len(found)
    emu.set_mode("normal")
    wait_until(lambda: len(node.search(node="r0")) == 2, 15, "the laser to come back after it answers again")
    assert len(found) >= n_found + 2
    scan = laser.wait_for_data(10.0)
    assert scan.ranges.size == 682
    assert server.alive(), server.output()


def test_noise_and_bad_check_characters_are_dropped_and_counted(tmp_path, procs, port, fabric_factory, emulator):
    emu = emulator()
    serve(tmp_path, procs, port, emu, "URG-04LX")
    fabric = fabric_factory(port)
    node = fabric.node("r0:*:*")
    node.wait_for("r0:laser:0", 1, 20.0)
    laser = node.device("r0:laser:0")
    laser.wait_for_data(10.0)
    emu.set_mode("garbage")
    wait_until(lambda: laser.rpc("status", timeout=2.0)["dropped"] >= 3, 10, "noise frames to be counted")
    emu.set_mode("badsum")
    dropped = laser.rpc("status", timeout=2.0)["dropped"]
    wait_until(lambda: laser.rpc("status", timeout=2.0)["dropped"] >= dropped + 3, 10, "bad scans to be counted")
    status = laser.rpc("status", timeout=2.0)
    assert status["online"] and status["published"] > 0
    seen = laser.wait_for_data(5.0)  # the good scans still come through
    assert seen.ranges.size == 682 and float(np.median(seen.ranges)) == pytest.approx(2.0)


def test_sigterm_switches_the_laser_off(tmp_path, procs, port, fabric_factory, emulator):
    emu = emulator()
    server = serve(tmp_path, procs, port, emu, "URG-04LX")
    fabric = fabric_factory(port)
    node = fabric.node("r0:*:*")
    node.wait_for("r0:laser:0", 1, 20.0)
    node.device("r0:laser:0").wait_for_data(10.0)
    n = len(emu.commands)
    server.signal(signal.SIGTERM)
    wait_until(lambda: not server.alive(), 15, "rsal serve to exit after SIGTERM")
    assert server.p.returncode == 0, server.output()
    assert b"QT" in emu.commands[n:]
    assert "Traceback" not in server.output()
