"""What every ``rsal`` process pays before it runs its command: building the command line imports
no driver, simulator, planner, ROS 2 type or recording player (each command imports what it needs
when it runs), and a device server loads the ROS 2 type store only when a ROS 2 driver uses it.
The suite and a fleet start hundreds of ``rsal`` processes; these imports once cost each of them
about 0.35 s of CPU (and every device server 0.15 s more)."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.conftest import ROOT

HEAVY = ("mrs_bridge.drivers", "mrs_bridge.rehearse.coupling", "mrs_bridge.ros2.types", "rsal.record.player",
         "rsal.record.recorder", "simulator", "scipy", "rosbags", "pymunk")  # fmt: skip


def test_building_the_command_line_imports_no_heavy_module():
    code = "import json, sys, rsal.cli; rsal.cli.build_parser(); print(json.dumps(sorted(m for m in sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    loaded = json.loads(out.stdout)
    heavy = [m for m in loaded if any(m == h or m.startswith(h + ".") for h in HEAVY)]
    assert heavy == [], f"imported while building the parser: {heavy}"


def test_a_device_server_without_a_ros2_driver_loads_no_ros2_types():
    code = "import json, sys, mrs_bridge.drivers; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert [m for m in json.loads(out.stdout) if m.startswith("rosbags")] == []


def test_the_lazy_names_still_resolve():
    from mrs_bridge.rehearse import RehearsalDriver
    from rsal.record import Player, Recorder

    assert Player.__module__ == "rsal.record.player" and Recorder.__module__ == "rsal.record.recorder"
    assert RehearsalDriver.__module__ == "mrs_bridge.rehearse.coupling"
    from mrs_bridge.ros2 import types

    assert "sensor_msgs/msg/LaserScan" in types.TYPESTORE.types
