"""The key space (rsal/keys.py): device addresses, the keys built from them, templates, errors."""

from __future__ import annotations

import pytest
import zenoh

from rsal import keys
from rsal.keys import DeviceAddr, check_name, parse_device, parse_key, template_to_keyexpr

R0_LASER = DeviceAddr("r0", "laser", 0)


# ---------------------------------------------------------------------------- names
@pytest.mark.parametrize("name", ["r0", "robot_1", "pioneer-2dx", "tams.floor", "A9"])
def test_check_name_accepts_single_key_chunks(name):
    assert check_name("node", name) == name


@pytest.mark.parametrize("name", ["", "r/0", "r*", "r 0", "r:0", "r$", "r?", "r#", None, 3])
def test_check_name_rejects_what_would_break_a_key(name):
    with pytest.raises(ValueError) as ei:
        check_name("node", name)
    text = str(ei.value)
    assert text.startswith(f"node {name!r}")
    assert "letters, digits" in text


# ---------------------------------------------------------------------------- DeviceAddr
def test_device_addr_path_str_and_default_index():
    a = DeviceAddr("r0", "position2d")
    assert a.index == 0
    assert a.path == "r0/position2d/0"
    assert str(a) == "r0:position2d:0"
    assert str(DeviceAddr("r0", "position2d", 1, "odometry")) == "odometry::r0:position2d:1"


def test_device_addr_key_is_part_of_identity_until_removed():
    keyed = DeviceAddr("r0", "map", 0, "laser")
    assert keyed != DeviceAddr("r0", "map", 0)
    assert keyed.without_key() == DeviceAddr("r0", "map", 0)
    assert keyed.without_key().key == ""
    assert hash(keyed.without_key()) == hash(DeviceAddr("r0", "map", 0))


def test_device_addrs_sort_by_node_interface_index():
    addrs = [DeviceAddr("r1", "laser", 0), DeviceAddr("r0", "sonar", 0), DeviceAddr("r0", "laser", 2)]
    assert [str(a) for a in sorted(addrs)] == ["r0:laser:2", "r0:sonar:0", "r1:laser:0"]


def test_device_addr_is_frozen():
    with pytest.raises(AttributeError):
        R0_LASER.index = 1  # type: ignore[misc]


@pytest.mark.parametrize("index", [-1, 1.0, "0", True, None])
def test_device_addr_rejects_an_index_that_is_not_a_non_negative_int(index):
    with pytest.raises(ValueError, match="non-negative integer"):
        DeviceAddr("r0", "laser", index)


@pytest.mark.parametrize(("node", "iface"), [("r/0", "laser"), ("r0", "las er"), ("", "laser"), ("r0", "*")])
def test_device_addr_rejects_bad_node_or_interface(node, iface):
    with pytest.raises(ValueError, match="must be letters"):
        DeviceAddr(node, iface, 0)


# ---------------------------------------------------------------------------- parse_device
@pytest.mark.parametrize(
    ("text", "default", "expected"),
    [
        ("r0:laser:0", None, DeviceAddr("r0", "laser", 0)),
        ("laser:3", "r0", DeviceAddr("r0", "laser", 3)),
        ("r1:laser:3", "r0", DeviceAddr("r1", "laser", 3)),
        ("odometry::r0:position2d:0", None, DeviceAddr("r0", "position2d", 0, "odometry")),
        ("laser::map:0", "r2", DeviceAddr("r2", "map", 0, "laser")),
        # Player's "key:::iface:idx" (key, empty host) takes the default node
        ("output:::position2d:1", "r0", DeviceAddr("r0", "position2d", 1, "output")),
        ("  r0:sonar:0 \n", None, DeviceAddr("r0", "sonar", 0)),
        ("r0:laser:007", None, DeviceAddr("r0", "laser", 7)),
    ],
)
def test_parse_device_accepts_the_player_forms(text, default, expected):
    a = parse_device(text, default)
    assert a == expected
    assert a.key == expected.key


@pytest.mark.parametrize(
    "addr", [DeviceAddr("r0", "laser", 0), DeviceAddr("robot-7", "position2d", 12, "odometry"), DeviceAddr("a.b", "x")]
)
def test_str_of_an_address_parses_back_to_it(addr):
    back = parse_device(str(addr))
    assert back == addr and back.key == addr.key


@pytest.mark.parametrize(
    ("text", "default", "fragment"),
    [
        ("laser:0", None, "names no node; write it as 'node:laser:0'"),
        ("laser", "r0", "must look like '[key::][node:]interface:index'"),
        ("a:b:c:d", None, "must look like '[key::][node:]interface:index'"),
        ("", "r0", "must look like"),
        ("r0:laser:x", None, "index 'x' is not an integer"),
        ("r0:laser:1.5", None, "index '1.5' is not an integer"),
        ("r0:laser:-1", None, "non-negative integer"),
        ("r/0:laser:0", None, "node 'r/0' must be letters"),
        ("r0:la ser:0", None, "interface 'la ser' must be letters"),
        ("bad key::r0:laser:0", None, "device key 'bad key' must be letters"),
    ],
)
def test_parse_device_errors_name_the_text_and_the_problem(text, default, fragment):
    with pytest.raises(ValueError) as ei:
        parse_device(text, default)
    assert str(ei.value).startswith(f"device {text!r}")
    assert fragment in str(ei.value)


@pytest.mark.parametrize("text", [None, 5, ["r0", "laser", 0]])
def test_parse_device_rejects_non_strings(text):
    with pytest.raises(ValueError, match="must be a string like 'r0:laser:0'"):
        parse_device(text)


# ---------------------------------------------------------------------------- keys
def test_keys_of_a_device():
    assert keys.device_key(R0_LASER) == "rsal/r0/laser/0"
    assert keys.data_key(R0_LASER) == "rsal/r0/laser/0/data"
    assert keys.cmd_key(R0_LASER) == "rsal/r0/laser/0/cmd"
    assert keys.event_key(R0_LASER) == "rsal/r0/laser/0/event"
    assert keys.rpc_key(R0_LASER, "describe") == "rsal/r0/laser/0/rpc/describe"


def test_keys_ignore_the_role_name():
    keyed = DeviceAddr("r0", "laser", 0, "laser")
    assert keys.data_key(keyed) == keys.data_key(R0_LASER)


@pytest.mark.parametrize("op", ["a/b", "*", "", "set pose"])
def test_rpc_key_rejects_an_operation_that_is_not_one_chunk(op):
    with pytest.raises(ValueError, match="operation"):
        keys.rpc_key(R0_LASER, op)


@pytest.mark.parametrize(
    "key",
    [
        keys.device_key(DeviceAddr("r0", "position2d", 1)),
        keys.data_key(R0_LASER),
        keys.rpc_key(R0_LASER, "get"),
        keys.agent_key("hunter-1"),
        keys.service_key("send_position", "a1"),
        keys.service_key("send_position"),
    ],
)
def test_built_keys_are_valid_zenoh_key_expressions(key):
    assert str(zenoh.KeyExpr(key)) == key


def test_agent_and_service_keys():
    assert keys.agent_key("hunter-1") == "agents/hunter-1"
    assert keys.service_key("new_goal") == "svc/new_goal/*"
    assert keys.service_key("new_goal", "a7") == "svc/new_goal/a7"
    with pytest.raises(ValueError, match="agent id"):
        keys.agent_key("a/b")
    with pytest.raises(ValueError, match="sender id"):
        keys.service_key("new_goal", "a**")
    with pytest.raises(ValueError, match="service"):
        keys.service_key("new goal")


# ---------------------------------------------------------------------------- parse_key
@pytest.mark.parametrize(
    ("key", "channel", "op"),
    [
        ("rsal/r0/laser/0", "", ""),
        ("rsal/r0/laser/0/data", "data", ""),
        ("rsal/r0/laser/0/cmd", "cmd", ""),
        ("rsal/r0/laser/0/event", "event", ""),
        ("rsal/r0/laser/0/rpc/describe", "rpc", "describe"),
    ],
)
def test_parse_key_splits_device_channel_and_op(key, channel, op):
    assert parse_key(key) == (R0_LASER, channel, op)


@pytest.mark.parametrize(
    "key",
    [
        "agents/a1",
        "svc/hello/a1",
        "rsal/r0/laser",
        "other/r0/laser/0",
        "rsal/r0/laser/x",
        "rsal/r0/laser/-1",
        "rsal/r0/laser/0/rpc",
        "rsal/r0/laser/0/rpc/a/b",
        "rsal/r0/laser/0/status",
        "rsal/r0/laser/0/data/extra",
        "rsal/r 0/laser/0",
    ],
)
def test_parse_key_returns_none_for_other_keys(key):
    assert parse_key(key) is None


def test_parse_key_inverts_the_key_builders():
    a = DeviceAddr("robot-2", "gripper", 3)
    assert parse_key(keys.device_key(a)) == (a, "", "")
    assert parse_key(keys.cmd_key(a)) == (a, "cmd", "")
    assert parse_key(keys.rpc_key(a, "open")) == (a, "rpc", "open")


# ---------------------------------------------------------------------------- templates
@pytest.mark.parametrize(
    ("template", "expr"),
    [
        ("", "rsal/**"),
        (None, "rsal/**"),
        ("*", "rsal/**"),
        ("**", "rsal/**"),
        ("rsal", "rsal/**"),
        ("r0:*:*", "rsal/r0/*/*"),
        ("*:laser:*", "rsal/*/laser/*"),
        ("laser:0", "rsal/*/laser/0"),
        ("r0::", "rsal/r0/*/*"),
        ("r0", "rsal/r0/**"),
        ("r0/", "rsal/r0/**"),
        ("r0/**", "rsal/r0/**"),
        ("rsal/r0/**", "rsal/r0/**"),
        ("rsal/*/ranger/*", "rsal/*/ranger/*"),
        ("rsal/r0/laser", "rsal/r0/laser/**"),
        ("rsal/r0/laser/0", "rsal/r0/laser/0"),
    ],
)
def test_template_to_keyexpr(template, expr):
    assert template_to_keyexpr(template) == expr
    zenoh.KeyExpr(expr)  # and it is a valid key expression


@pytest.mark.parametrize(
    ("template", "matching", "other"),
    [
        ("r0:*:*", "r0:laser:0", "r1:laser:0"),
        ("*:laser:*", "r5:laser:2", "r5:sonar:2"),
        ("r0", "r0:position2d:0", "r00:position2d:0"),
        ("rsal/*/ranger/*", "r0:ranger:1", "r0:laser:1"),
    ],
)
def test_templates_match_the_token_keys_they_mean(template, matching, other):
    ke = zenoh.KeyExpr(template_to_keyexpr(template))
    assert ke.intersects(zenoh.KeyExpr(keys.device_key(parse_device(matching))))
    assert not ke.intersects(zenoh.KeyExpr(keys.device_key(parse_device(other))))


@pytest.mark.parametrize("template", ["a:b:c:d", "r0:laser:0:1"])
def test_template_with_too_many_parts_is_an_error(template):
    with pytest.raises(ValueError) as ei:
        template_to_keyexpr(template)
    assert repr(template) in str(ei.value)
    assert "node:interface:index" in str(ei.value)


def test_host_daemon_keys():
    assert keys.host_key("robot1") == "hosts/robot1" and keys.host_key("*") == "hosts/*"
    assert keys.host_rpc_key("robot1", "launch") == "hosts/robot1/rpc/launch"
    assert keys.host_rpc_key("robot1") == "hosts/robot1/rpc/*"
    assert keys.host_run_key("robot1", "ab12", "runner") == "hosts/robot1/run/ab12/runner"
    assert keys.host_run_key("robot1") == "hosts/robot1/run/*/*"
    for k in ("hosts/robot1/rpc/launch", "hosts/robot1/run/ab12/out"):
        assert zenoh.KeyExpr(k).intersects(zenoh.KeyExpr("hosts/**"))
    with pytest.raises(ValueError, match="host operation 'reboot': one of launch, stop, status"):
        keys.host_rpc_key("robot1", "reboot")
    with pytest.raises(ValueError, match="run key part 'log': one of out, exit, runner"):
        keys.host_run_key("robot1", "ab12", "log")
    with pytest.raises(ValueError, match="host name 'a/b' must be"):
        keys.host_key("a/b")
