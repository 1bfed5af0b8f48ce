"""The thesis's Swarm in full (4.2.3): Pioneer 3-ATs with 16 sonars, each with AMCL on its sonar,
Wavefront and VFH served by ``rsal sim --nav vfh --nav-robots '*'``, each driven by a
:class:`ThesisSwarmAgent` that broadcasts its AMCL pose; judged on the simulator's ground truth.

Ground truth here: the simulator's contact counter (``sim:simulation:0`` ``rpc/contacts``, every
physics step), the true poses against each robot's AMCL pose (the monitor's samples), the true
distance each robot drove, and every broadcast counted at every receiver against its sender's own
count. The 100-robot run is ``deploy/scenarios/swarm.yaml`` app ``thesis`` (docs/benchmarks.md).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.scenarios.swarm import crowd_world
from agents.scenarios.swarm.thesis import ThesisSwarmMonitor
from tests.conftest import MAPS

N = 10
DURATION = 30.0  # simulated s
SPEEDUP = "2"  # ten AMCL filters on sonar, ten VFH and Wavefront in the simulator's process


def test_thesis_world_is_the_checked_in_file():
    assert (MAPS / "swarm_thesis.world").read_text() == crowd_world(100, model="pioneer3at", bitmap="hall.png")


def test_monitor_judges_contacts_and_localization_share():
    m = ThesisSwarmMonitor("m", robots=2, duration=1.0, max_loc_error=0.5, loc_share=0.9)
    m.loc_errors = [np.array([0.1, 0.2])] * 9 + [np.array([0.1, np.nan])]  # r1 without an estimate once
    share, p95, worst = m.localization()
    assert share == pytest.approx(0.95) and worst == math.inf
    m.contacts = {"robot_robot": 1, "robot_wall": 0, "robots": {"r1": [1, 0], "r7": [1, 2]}}  # r7 not watched
    assert m.contact_counts() == (1, 0)
    v = m.judge(1.0)
    assert not v.ok and "1 robot-robot and 0 robot-wall contact(s)" in v.text
    m.contacts = {"robot_robot": 0, "robot_wall": 0, "robots": {}}
    m.loc_errors = [np.array([0.1, 0.6])] * 10
    assert "localization within 0.5 m for 50.0 %" in m.judge(1.0).text
    with pytest.raises(ValueError, match="loc_share"):
        ThesisSwarmMonitor("m", robots=2, loc_share=1.5)
