"""The ``power`` device over a real ``rsal sim``: the battery model's charge, voltage, charging
flag and the low-battery event reach a client; an empty battery stops the robot (ground truth
from the simulation interface); a robot driven onto a charger charges and reports recovery."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from rsal.interfaces.power import LOW_EVENT, RECOVERED_EVENT, lead_acid_volts
from tests.conftest import rsal_cmd, wait_until

# Small batteries with no constant draw: nothing drains until the test drives.
# r0: 36 J, 30 % charged, 20 J/m: 20 % after 0.18 m, empty after 0.54 m.
# r1: 10 % charged, 0.5 m behind a 2 W charger: 1 % of its 36 J every 0.18 s once docked.
WORLD = """
world: {interval_sim: 0.1, speedup: 1}
robots:
  - {name: r0, pose: [0, 0, 0], sonar: false,
     battery: {capacity: 0.01, charge: 0.3, per_metre: 20, per_radian: 0, watts: 0}}
  - {name: r1, pose: [0, 3, 0], sonar: false,
     battery: {capacity: 0.01, charge: 0.1, per_metre: 0, per_radian: 0, watts: 0}}
chargers:
  - {name: dock, pose: [0.5, 3, 0], rate: 2, distance: 0.1}
"""


def test_power_data_low_event_empty_stop_and_charging(procs, port, fabric_factory, tmp_path: Path):
    world = tmp_path / "energy.yaml"
    world.write_text(WORLD)
    procs(rsal_cmd("sim", str(world), "--listen", f"tcp/127.0.0.1:{port}"))
    fab = fabric_factory(port)
    node = fab.node("*:*:*")
    node.wait_for("r1:power:0", timeout=30)
    node.wait_for("sim:simulation:0", timeout=30)
    events: dict[str, list[dict]] = {"r0": [], "r1": []}
    got = threading.Event()
    power = {}
    for r in ("r0", "r1"):
        power[r] = fab.device(f"{r}:power:0")
        power[r].add_event_listener(lambda e, r=r: (events[r].append(e), got.set()))
    p0 = power["r0"].wait_for_data(10)
    assert p0.percent == pytest.approx(30.0, abs=0.5) and not p0.low and not p0.charging
    assert p0.volts == pytest.approx(lead_acid_volts(p0.fraction), abs=1e-6)
    geo = power["r0"].describe().geometry
    assert geo["battery"] is True and geo["capacity"] == pytest.approx(36.0) and geo["low_battery"] == 20.0
    p1 = power["r1"].wait_for_data(10)
    assert p1.low and not p1.charging  # 10 %: below the threshold from the start

    sim = fab.device("sim:simulation:0")
    (dock,) = sim.describe().geometry["chargers"]
    assert dock == {"name": "dock", "pose": [0.5, 3.0, 0.0], "rate": 2.0, "distance": 0.1, "angle": None}
    pos0, pos1 = fab.device("r0:position2d:0"), fab.device("r1:position2d:0")
    pos0.wait_for_data(10)
    pos1.wait_for_data(10)

    # r0 drives until its battery is empty: the low event first, then it stops by itself.
    def driving(pos, cond):  # a velocity command refreshed at every poll (the base's command timeout)
        return lambda: (pos.set_velocity(0.2, 0.0), cond())[1]

    wait_until(driving(pos0, lambda: any(e["event"] == LOW_EVENT for e in events["r0"])), 15, "r0's low event")
    low = next(e for e in events["r0"] if e["event"] == LOW_EVENT)
    assert (
        low["percent"] < 20.0
        and low["threshold"] == 20.0
        and low["volts"] == pytest.approx(lead_acid_volts(low["percent"] / 100), abs=1e-6)
    )
    empty = driving(pos0, lambda: power["r0"].latest.percent == 0.0 and power["r0"].latest.low)
    wait_until(empty, 15, "r0's battery to be empty")
    stopped = sim.get_pose("r0").as_tuple()
    assert 0.45 < stopped[0] < 0.65  # ground truth: 10.8 J at 20 J/m
    t_end = pos0.latest.t + 3.0  # keep commanding: the empty robot refuses to move
    wait_until(driving(pos0, lambda: pos0.latest.t > t_end), 10, "three more simulated seconds of commands")
    assert sim.get_pose("r0").as_tuple() == pytest.approx(stopped, abs=1e-3)

    # r1 drives onto the charger and stops there: charging, then recovered above 25 %.
    wait_until(driving(pos1, lambda: sim.get_pose("r1").as_tuple()[0] > 0.45), 10, "r1 to reach the charger")
    pos1.stop()
    wait_until(lambda: power["r1"].latest.charging, 10, "r1 to report charging")
    wait_until(lambda: any(e["event"] == RECOVERED_EVENT for e in events["r1"]), 20, "r1's recovered event")
    rec = next(e for e in events["r1"] if e["event"] == RECOVERED_EVENT)
    assert rec["percent"] >= 25.0
    wait_until(lambda: not power["r1"].latest.low, 5, "r1's data to clear the low flag")

    # the simulation's own record of every battery (ground truth for energy verdicts): r0 ran flat
    # and has stayed empty, r1 gained charge on the dock and never ran flat
    truth = sim.batteries()
    assert truth["r0"]["empty"] and truth["r0"]["lowest"] == 0.0 and truth["r0"]["flat"] > 3.0
    assert truth["r0"]["charged"] == 0.0 and truth["r0"]["charger"] is None
    assert truth["r1"]["flat"] == 0.0 and truth["r1"]["charged"] > 0.0 and truth["r1"]["charger"] == "dock"
    assert truth["r1"]["lowest"] == pytest.approx(0.1, abs=0.02) and truth["r1"]["battery"] is True
    assert truth["r1"]["capacity"] == pytest.approx(36.0)
