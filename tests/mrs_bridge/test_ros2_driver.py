"""The ``ros2`` import driver's configuration: one-line errors naming the block and the fix
(the driver at work is tested end to end in tests/fabric/test_ros2_export.py)."""

from __future__ import annotations

import pytest

from mrs_bridge.config import ConfigError, parse_config
from mrs_bridge.driver import DRIVERS
from mrs_bridge.ros2.driver import Ros2Import


def make(extra: str, provides: str = '["r5:position2d:0", "r5:laser:0"]'):
    cfg = parse_config(f'[[driver]]\nname = "ros2"\nprovides = {provides}\n{extra}\n', source="cfg/ros.toml")
    return Ros2Import(cfg.drivers[0], None)


def test_the_driver_is_registered_and_reads_its_parameters():
    assert DRIVERS["ros2"] is Ros2Import
    d = make('namespace = "/robot5"\nmax_speed = [0.4, 0.9]\nlaser_pose = [0.1, 0, 90]')
    assert d.p.namespace == "/robot5" and d.p.max_speed == (0.4, 0.9)
    assert str(d.base) == "r5:position2d:0" and str(d.laser) == "r5:laser:0"
    g = d.geometry(d.laser)
    assert g["pose"] == pytest.approx([0.1, 0.0, 1.5707963]) and g["ros"] == "/robot5/scan"


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ("", r"cfg/ros\.toml: driver #1 \(ros2\): needs 'namespace'"),
        ('namespace = "robot5"', r"namespace = 'robot5' must be a ROS namespace like '/robot5'"),
        ('namespace = "/r5"\ndomian = 3', r"unknown parameter 'domian'; did you mean 'domain'"),
        ('namespace = "/r5"\ndomain = 300', r"domain = 300 must be"),
    ],
)
def test_configuration_errors_are_one_line(extra, match):
    with pytest.raises(ConfigError, match=match) as ei:
        make(extra)
    assert "\n" not in str(ei.value)


def test_a_driver_that_provides_something_else_is_refused():
    with pytest.raises(Exception, match="cannot provide 'sonar'"):
        make('namespace = "/r5"', provides='["r5:sonar:0"]')


def test_the_export_driver_provides_nothing_and_checks_its_parameters():
    from mrs_bridge.ros2.export_driver import Ros2Export

    def make_export(extra: str):
        cfg = parse_config(f'[[driver]]\nname = "ros2_export"\n{extra}\n', source="cfg/ros.toml")
        return Ros2Export(cfg.drivers[0], None)

    d = make_export('robots = ["r0", "r1*"]\ndomain = 4')
    assert d.config.robots == ("r0", "r1*") and d.config.domain == 4 and d.cfg.provides == []
    for extra, match in (
        ('robots = ["r/0"]', r"robots = \['r/0'\] must be robot names or patterns"),
        ('node_name = "my-node"', r"node_name = 'my-node' must be a ROS node name"),
        ('frame_prefix = "{ns}/"', r"frame_prefix = '\{ns\}/' may only use \{robot\}"),
    ):
        with pytest.raises(ConfigError, match=match):
            make_export(extra)
