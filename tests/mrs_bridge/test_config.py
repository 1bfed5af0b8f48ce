"""Device server configuration (mrs_bridge/config.py): valid TOML and every ConfigError path."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from mrs_bridge.config import ConfigError, load_config, parse_config
from rsal.keys import DeviceAddr

KNOWN = ["sim", "mapfile", "rangertolaser", "replay", "simulation"]

GOOD = """
[server]
node = "r0"

[[driver]]
name = "replay"
provides = ["ranger:1"]
rate = 20
samples = 181

[[driver]]
name = "rangertolaser"
requires = ["r0:ranger:1"]
provides = ["laser:0"]

[[driver]]
name = "mapfile"
node = "world"
provides = ["map:0"]
filename = "../maps/floor.png"
resolution = 0.05
origin = [-31.475, -7.8]

[[driver]]
name = "replay"
requires = ["odometry::r1:position2d:0", "laser::map:0"]
provides = "r1:laser:0"
"""


def parse(text: str, **kw):
    return parse_config(textwrap.dedent(text), source="cfg/robot.toml", **kw)


def error(text: str, **kw) -> str:
    with pytest.raises(ConfigError) as ei:
        parse(text, **kw)
    msg = str(ei.value)
    assert msg.startswith("cfg/robot.toml: "), msg
    assert "\n" not in msg
    return msg


def block(**fields) -> str:
    """One [[driver]] block from Python values (strings quoted, lists as TOML arrays)."""
    lines = ["[[driver]]"]
    for k, v in fields.items():
        if isinstance(v, str):
            lines.append(f'{k} = "{v}"')
        elif isinstance(v, bool):
            lines.append(f"{k} = {str(v).lower()}")
        elif isinstance(v, list):
            lines.append(f"{k} = [" + ", ".join(f'"{x}"' if isinstance(x, str) else str(x) for x in v) + "]")
        else:
            lines.append(f"{k} = {v}")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- valid
def test_a_valid_config_is_parsed_into_driver_blocks():
    cfg = parse(GOOD, base_dir=Path("/srv/cfg"), known_drivers=KNOWN)
    assert cfg.node == "r0" and cfg.source == "cfg/robot.toml"
    replay, r2l, mapfile, keyed = cfg.drivers
    assert replay.name == "replay"
    assert replay.provides == [DeviceAddr("r0", "ranger", 1)]
    assert replay.rate == 20.0 and isinstance(replay.rate, float)
    assert replay.params == {"samples": 181}
    assert replay.where == "cfg/robot.toml: driver #1 (replay)"
    assert r2l.requires == [DeviceAddr("r0", "ranger", 1)] and r2l.provides == [DeviceAddr("r0", "laser", 0)]
    assert r2l.rate is None and r2l.params == {}
    # a block's own node applies to its devices written without one
    assert mapfile.provides == [DeviceAddr("world", "map", 0)]
    assert mapfile.params == {"filename": "../maps/floor.png", "resolution": 0.05, "origin": [-31.475, -7.8]}
    assert mapfile.path_param("filename") == Path("/srv/cfg/../maps/floor.png")
    assert mapfile.path_param("missing") is None
    assert mapfile.param("resolution") == 0.05 and mapfile.param("negate", False) is False
    # Player role keys, and a single string for provides
    assert keyed.required("odometry") == DeviceAddr("r1", "position2d", 0, "odometry")
    assert keyed.required("laser") == DeviceAddr("r0", "map", 0, "laser")
    assert keyed.provides == [DeviceAddr("r1", "laser", 0)]


def test_required_role_missing_names_the_block_and_the_fix():
    keyed = parse(GOOD).drivers[3]
    with pytest.raises(ConfigError) as ei:
        keyed.required("sonar")
    assert str(ei.value) == (
        "cfg/robot.toml: driver #4 (replay): needs a required device with key 'sonar' (e.g. 'sonar::r0:...:0')"
    )


def test_absolute_path_params_stay_absolute():
    cfg = parse(block(name="mapfile", provides=["map:0"], filename="/maps/floor.png"), base_dir=Path("/x"))
    assert cfg.drivers[0].path_param("filename") == Path("/maps/floor.png")


def test_node_defaults_to_robot_and_default_node_overrides_the_file():
    only = block(name="replay", provides=["laser:0"])
    assert parse(only).drivers[0].provides == [DeviceAddr("robot", "laser", 0)]
    cfg = parse('[server]\nnode = "r0"\n' + only, default_node="r7")
    assert cfg.node == "r7" and cfg.drivers[0].provides == [DeviceAddr("r7", "laser", 0)]


def test_the_simulation_driver_may_provide_nothing():
    assert parse(block(name="simulation")).drivers[0].provides == []


def test_load_config_reads_a_file_and_resolves_paths_next_to_it(tmp_path):
    p = tmp_path / "robot.toml"
    p.write_text(GOOD)
    cfg = load_config(p)
    assert cfg.source == str(p)
    assert cfg.drivers[2].path_param("filename") == tmp_path / "../maps/floor.png"
    assert cfg.drivers[0].where == f"{p}: driver #1 (replay)"


def test_load_config_errors_name_the_file(tmp_path):
    missing = tmp_path / "nope.toml"
    with pytest.raises(ConfigError, match=r"nope\.toml: no such configuration file"):
        load_config(missing)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00name")
    with pytest.raises(ConfigError, match=r"bin\.toml: cannot be read"):
        load_config(binary)
    bad = tmp_path / "bad.toml"
    bad.write_text(block(name="replay", provides=["laser:0"], rate=-5))
    with pytest.raises(ConfigError) as ei:
        load_config(bad)
    assert str(ei.value).startswith(f"{bad}: driver #1 (replay): ")


# ---------------------------------------------------------------------------- errors
def test_invalid_toml_names_the_line():
    msg = error('[server\nnode = "r0"\n')
    assert "not valid TOML" in msg and "line 1" in msg


def test_unknown_section():
    msg = error('[servers]\nnode = "r0"\n' + block(name="sim", provides=["position2d:0"]))
    assert "unknown section(s) ['servers']; use [server] and [[driver]] blocks" in msg


def test_server_must_be_a_table():
    assert "[server] must be a table" in error('server = "r0"\n' + block(name="sim", provides=["laser:0"]))


def test_bad_node_name():
    msg = error('[server]\nnode = "r 0"\n' + block(name="sim", provides=["laser:0"]))
    assert "[server] node 'r 0' must be letters" in msg


def test_drivers_must_be_blocks():
    assert "drivers must be [[driver]] blocks" in error('driver = "sim"\n')
    assert "drivers must be [[driver]] blocks" in error("driver = [1, 2]\n")


def test_no_driver_blocks():
    assert error('[server]\nnode = "r0"\n').endswith("no [[driver]] blocks; add at least one driver")


@pytest.mark.parametrize("fields", [{"provides": ["laser:0"]}, {"name": "", "provides": ["laser:0"]}, {"name": 5}])
def test_missing_name(fields):
    msg = error(block(name="sim", provides=["p:0"]) + block(**fields))
    assert "driver #2: missing 'name' (the driver type, e.g. name = \"sim\")" in msg


def test_unknown_driver_suggests_the_closest_name():
    msg = error(block(name="replya", provides=["laser:0"]), known_drivers=KNOWN)
    assert msg == "cfg/robot.toml: driver #1 (replya): unknown driver 'replya'; did you mean 'replay'?"


def test_unknown_driver_without_a_close_name_lists_the_known_ones():
    msg = error(block(name="zzz", provides=["laser:0"]), known_drivers=KNOWN)
    assert msg.endswith("unknown driver 'zzz'; known drivers: mapfile, rangertolaser, replay, sim, simulation")


def test_unknown_drivers_are_left_to_the_server_without_a_list():
    assert parse(block(name="p2os", provides=["position2d:0"])).drivers[0].name == "p2os"


@pytest.mark.parametrize("provides", [[], None])
def test_empty_provides(provides):
    fields = {"name": "replay"} if provides is None else {"name": "replay", "provides": provides}
    msg = error(block(**fields))
    assert msg == (
        "cfg/robot.toml: driver #1 (replay): 'provides' is empty; list the devices it offers, e.g. [\"laser:0\"]"
    )


def test_provides_must_be_a_list():
    msg = error(block(name="replay", provides=5))
    assert "driver #1 (replay): 'provides' must be a list of devices" in msg


@pytest.mark.parametrize("rate", [0, -1, '"fast"', "true", "[10]"])
def test_bad_rate(rate):
    text = block(name="replay", provides=["laser:0"]) + f"rate = {rate}\n"
    msg = error(text)
    assert "driver #1 (replay): 'rate' must be a positive number of Hz, not" in msg


def test_duplicate_device_names_both_blocks():
    text = block(name="replay", provides=["laser:0"]) + block(name="rangertolaser", provides=["r0:laser:0"])
    msg = error('[server]\nnode = "r0"\n' + text)
    assert msg == (
        "cfg/robot.toml: driver #2 (rangertolaser): device r0:laser:0 is already provided by "
        "cfg/robot.toml: driver #1 (replay); give it another index"
    )


def test_duplicate_device_within_one_block():
    msg = error(block(name="replay", provides=["laser:0", "robot:laser:0"]))
    assert "device robot:laser:0 is already provided by cfg/robot.toml: driver #1 (replay)" in msg


def test_a_role_key_does_not_make_a_device_different():
    text = block(name="replay", provides=["a::laser:0"]) + block(name="replay", provides=["b::laser:0"])
    assert "already provided" in error(text)


@pytest.mark.parametrize(
    ("what", "device", "fragment"),
    [
        ("provides", "laser", "must look like '[key::][node:]interface:index'"),
        ("provides", "r0:laser:x", "index 'x' is not an integer"),
        ("provides", "r0:laser:-2", "non-negative integer"),
        ("provides", "r/0:laser:0", "node 'r/0' must be letters"),
        ("requires", "a:b:c:d", "must look like"),
        ("requires", "bad key::r0:ranger:0", "device key 'bad key'"),
    ],
)
def test_bad_device_address_names_block_list_and_device(what, device, fragment):
    fields = {"name": "rangertolaser", "provides": ["laser:0"], what: [device]}
    msg = error(block(**fields))
    assert msg.startswith(f"cfg/robot.toml: driver #1 (rangertolaser): {what}: device {device!r}")
    assert fragment in msg


def test_a_device_that_is_not_a_string():
    msg = error(block(name="replay", provides=[3]))
    assert "driver #1 (replay): provides: device 3 must be a string" in msg
