"""Energy in the simulator: batteries drain by ground-truth motion and a constant draw, an empty
battery stops its robot, chargers charge docked robots at their rate (simulator/energy.py), and
the world files' battery and charger entries (Stage and YAML)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from simulator.energy import PIONEER_AT, PIONEER_DX
from simulator.errors import ModelError, WorldFileError
from simulator.loader import load_world
from simulator.presets import pioneer2dx, pioneer3at
from simulator.spec import BatterySpec, ChargerSpec, FloorplanSpec, ModelSpec, WorldSpec
from simulator.world import World

BAT = BatterySpec(capacity=10_000.0, charge=1.0, per_metre=50.0, per_radian=10.0, watts=5.0)


def bot(name: str, pose=(0.0, 0.0, 0.0), battery: BatterySpec | None = BAT) -> ModelSpec:
    b = None if battery is None else BatterySpec(**vars(battery))
    return ModelSpec(name=name, position=True, pose=pose, battery=b, odom_error=(0, 0, 0), odom_noise=(0, 0, 0))


def world(*models: ModelSpec, chargers=()) -> World:
    return World(WorldSpec(models=list(models), chargers=list(chargers)))


def used(w: World, name: str) -> float:
    b = w.battery(name)
    return b.capacity - b.energy


def test_drain_over_a_driven_distance_matches_the_model():
    w = world(bot("r0"))
    x0, y0, _ = w.get_pose("r0")
    w.set_velocity("r0", 0.5, 0.0)
    w.step(200)  # 20 s
    x1, y1, _ = w.get_pose("r0")
    dist = math.hypot(x1 - x0, y1 - y0)  # ground truth
    assert dist > 8.0
    expect = BAT.per_metre * dist + BAT.watts * w.time
    assert used(w, "r0") == pytest.approx(expect, rel=0.02)


def test_drain_while_turning_on_the_spot_counts_radians():
    w = world(bot("r0"))
    w.set_velocity("r0", 0.0, 1.0)
    turned = 0.0
    last = w.get_pose("r0")[2]
    for _ in range(100):
        w.step()
        a = w.get_pose("r0")[2]
        turned += abs(math.remainder(a - last, math.tau))
        last = a
    assert turned > 8.0
    expect = BAT.per_radian * turned + BAT.watts * w.time
    assert used(w, "r0") == pytest.approx(expect, rel=0.03)


def test_an_idle_robot_draws_the_constant_power():
    w = world(bot("r0"))
    w.step(300)
    assert w.get_pose("r0")[:2] == pytest.approx((0.0, 0.0), abs=1e-9)
    assert used(w, "r0") == pytest.approx(BAT.watts * 30.0, rel=1e-9)
    assert w.battery("r0").fraction == pytest.approx(1 - 150.0 / BAT.capacity)


def test_an_empty_battery_stops_the_robot():
    w = world(bot("r0"))
    w.set_battery("r0", 0.01)  # 100 J: about 1.8 m at 0.5 m/s
    w.set_velocity("r0", 0.5, 0.0)
    w.step(100)
    b = w.battery("r0")
    assert b.empty and b.energy == 0.0 and b.fraction == 0.0
    stopped_at = w.get_pose("r0")
    assert 1.0 < stopped_at[0] < 2.5
    w.set_velocity("r0", 0.5, 0.3)  # refused by the empty battery: it does not move
    w.step(50)
    assert w.get_pose("r0") == pytest.approx(stopped_at, abs=1e-6)
    assert w.velocity("r0") == (0.0, 0.0)


def test_a_robot_without_a_battery_model_never_empties():
    w = world(bot("r0", battery=None))
    w.set_velocity("r0", 1.0, 0.0)
    w.step(100)
    b = w.battery("r0")
    assert not b.empty and b.fraction == 1.0 and b.capacity == 0.0
    assert w.get_pose("r0")[0] > 5.0


def test_docking_at_a_charger_charges_at_its_rate_and_outside_the_tolerance_does_not():
    dock = ChargerSpec("c0", pose=(0.0, 0.0, 0.0), rate=200.0, distance=0.3)
    far = ChargerSpec("c1", pose=(5.0, 0.0, 0.0), rate=200.0, distance=0.3)
    w = world(bot("in", (0.2, 0.1, 1.0)), bot("out", (5.32, 0.0, 0.0)), chargers=[dock, far])
    w.set_battery("in", 0.5)
    w.set_battery("out", 0.5)
    w.step(100)  # 10 s
    b_in, b_out = w.battery("in"), w.battery("out")
    assert b_in.charging and b_in.charger == "c0"
    assert b_in.energy - 5000.0 == pytest.approx((200.0 - BAT.watts) * 10.0, rel=1e-6)
    assert not b_out.charging and b_out.charger is None
    assert 5000.0 - b_out.energy == pytest.approx(BAT.watts * 10.0, rel=1e-6)


def test_a_charger_with_an_angle_docks_only_robots_facing_its_way():
    dock = ChargerSpec("c0", pose=(0.0, 0.0, math.pi / 2), rate=100.0, distance=0.5, angle=math.radians(10))
    w = world(bot("facing", (0.0, 0.0, math.radians(95))), chargers=[dock])
    w2 = world(bot("askew", (0.0, 0.0, math.radians(120))), chargers=[dock])
    for x, name in ((w, "facing"), (w2, "askew")):
        x.set_battery(name, 0.5)
        x.step(10)
    assert w.battery("facing").charging
    assert not w2.battery("askew").charging and w2.battery("askew").fraction < 0.5


def test_charging_stops_at_capacity_and_respects_the_batterys_own_limit():
    limited = BatterySpec(**{**vars(BAT), "max_charge": 50.0})
    w = world(bot("r0", battery=limited), chargers=[ChargerSpec("c0", rate=500.0, distance=0.3)])
    w.set_battery("r0", 0.5)
    w.step(100)
    assert w.battery("r0").energy - 5000.0 == pytest.approx((50.0 - BAT.watts) * 10.0, rel=1e-6)
    w.set_battery("r0", 1.0)
    w.step(10)
    b = w.battery("r0")
    assert b.energy == pytest.approx(BAT.capacity) and not b.charging and b.charger == "c0"


def test_an_empty_robot_on_a_charger_charges_and_moves_again():
    w = world(bot("r0"), chargers=[ChargerSpec("c0", rate=100.0, distance=0.3)])
    w.set_battery("r0", 0.0)
    w.set_velocity("r0", 0.0, 0.0)
    w.step(1)
    assert not w.battery("r0").empty
    w.set_velocity("r0", 0.3, 0.0)
    w.step(20)
    assert w.get_pose("r0")[0] > 0.3


def test_the_record_keeps_the_lowest_charge_seconds_flat_and_joules_charged():
    dock = ChargerSpec("c0", pose=(-3.0, 0.0, 0.0), rate=100.0, distance=0.3)
    w = world(bot("r0"), bot("r1", (5.0, 0.0, 0.0)), chargers=[dock])
    w.set_battery("r0", 0.01)
    w.set_velocity("r0", 0.5, 0.0)  # off the charger, runs flat after about 2 m, then waits empty
    w.step(100)
    b = w.battery("r0")
    assert b.empty and b.lowest == 0.0 and b.charged == 0.0
    assert 3.0 < b.flat < 7.0  # flat after 100 J at 55 J/s, of 10 s
    r1 = w.battery("r1")
    assert r1.flat == 0.0 and r1.lowest == pytest.approx(1.0 - 50.0 / 10_000.0) and r1.charged == 0.0
    w.set_pose("r0", -3.0, 0.0, 0.0)  # onto the charger: net 95 W for 2 s
    w.step(20)
    b = w.battery("r0")
    assert b.charging and b.charger == "c0" and b.charged == pytest.approx(190.0, rel=0.01)
    assert b.lowest == 0.0 and not b.empty
    w.reset()
    assert w.battery("r0").flat == 0.0 and w.battery("r0").lowest == 1.0


def test_rows_stay_with_their_robots_when_one_is_removed_and_reset_restores_the_charge():
    w = world(bot("a"), bot("b", (3.0, 0.0, 0.0)), bot("c", (6.0, 0.0, 0.0)))
    w.set_battery("c", 0.25)
    w.remove_model("a")
    assert w.battery("c").fraction == pytest.approx(0.25)
    assert w.battery("b").fraction == pytest.approx(1.0)
    w.reset()
    assert w.battery("c").fraction == pytest.approx(1.0)


def test_pioneer_presets_carry_the_datasheet_battery_and_last_hours():
    assert pioneer2dx("r").battery == PIONEER_DX
    assert pioneer3at("r").battery == PIONEER_AT
    wh = PIONEER_DX.capacity / 3600.0
    assert wh == pytest.approx(252.0)  # three 12 V batteries, 252 Wh
    dx_hours = PIONEER_DX.capacity / (PIONEER_DX.watts + 0.5 * PIONEER_DX.per_metre) / 3600.0
    at_hours = PIONEER_AT.capacity / (PIONEER_AT.watts + 0.5 * PIONEER_AT.per_metre) / 3600.0
    assert 8.0 <= dx_hours <= 10.0  # datasheet: 8-10 h
    assert 2.0 <= at_hours <= 4.0  # datasheet: 2-4 h


def test_step_drain_is_vectorised_over_many_robots():
    models = [bot(f"r{i}", (3.0 * (i % 10), 3.0 * (i // 10), 0.0)) for i in range(30)]
    w = world(*models)
    for i in range(30):
        w.set_velocity(f"r{i}", 0.1 * (i % 5), 0.0)
    w.step(50)
    use = np.array([used(w, f"r{i}") for i in range(30)])
    speeds = np.array([0.1 * (i % 5) for i in range(30)])
    assert np.all(np.diff(use[:5]) > 0)  # faster robots used more
    assert use == pytest.approx(BAT.watts * 5.0 + BAT.per_metre * speeds * 5.0, rel=0.05, abs=1.0)


# ---------------------------------------------------------------------------------- world files
def test_stage_world_battery_and_charger(tmp_path: Path):
    p = tmp_path / "e.world"
    p.write_text(
        "define dock charger ( charge_rate 150 dock_distance 0.4 )\n"
        'position( name "r0" battery_capacity 100 battery_charge 0.5 battery_drain [ 10 2 5 ] take_watts 80 )\n'
        'position( name "r1" pose [ 2 0 0 0 ] joules 1000 watts 3 )\n'
        'position( name "r2" pose [ 4 0 0 0 ] battery_capacity 0 )\n'
        'position( name "r3" pose [ 6 0 0 0 ] )\n'
        'dock( name "c0" pose [ 0 0 0 90 ] dock_angle 15 chrage_rate 3 )\n'
    )
    s = load_world(p)
    r0, r1, r2, r3 = s.models
    assert r0.battery == BatterySpec(360_000.0, 0.5, 10.0, 2.0, 5.0, 80.0)
    assert (r1.battery.capacity, r1.battery.charge, r1.battery.watts) == (1000.0, 1.0, 3.0)
    assert r2.battery is None
    assert r3.battery == PIONEER_DX
    (c,) = s.chargers
    assert (c.name, c.rate, c.distance) == ("c0", 150.0, 0.4)
    assert c.pose[2] == pytest.approx(math.pi / 2) and c.angle == pytest.approx(math.radians(15))
    assert any("unknown keyword 'chrage_rate'" in x and "did you mean 'charge_rate'" in x for x in s.warnings)
    assert not any("joules" in x or "watts" in x for x in s.warnings)  # simulated now


@pytest.mark.parametrize(
    "line, expect",
    [
        ('position( name "r0" battery_charge 1.5 )', "'battery_charge' needs a fraction from 0 to 1"),
        ('position( name "r0" battery_drain [ 1 2 ] )', "'battery_drain' needs [J/m J/rad W]"),
        ('charger( name "c" charge_rate -1 )', "'charge_rate' needs watts > 0"),
        ('charger( name "c" dock_angle 200 )', "'dock_angle' needs degrees from 0 to 180"),
    ],
)
def test_stage_energy_errors_are_one_line_with_the_place(tmp_path: Path, line: str, expect: str):
    p = tmp_path / "bad.world"
    p.write_text("interval_sim 100\n" + line + "\n")
    with pytest.raises(WorldFileError) as e:
        load_world(p)
    msg = str(e.value)
    assert expect in msg and f"{p}:2" in msg and "\n" not in msg and "e.g." in msg


def test_yaml_world_battery_and_chargers(tmp_path: Path):
    p = tmp_path / "e.yaml"
    p.write_text(
        "robots:\n"
        "  - {name: r0, battery: {capacity: 100, charge: 0.5, per_metre: 10, watts: 5, max_chrage: 3}}\n"
        "  - {name: r1, type: pioneer3at, pose: [2, 0, 0]}\n"
        "  - {name: r2, pose: [4, 0, 0], battery: none}\n"
        "chargers:\n"
        "  - {name: dock0, pose: [0, 0, 90], rate: 150, distance: 0.4, angle: 15}\n"
    )
    s = load_world(p)
    r0, r1, r2 = s.models
    assert (r0.battery.capacity, r0.battery.charge, r0.battery.per_metre, r0.battery.watts) == (360_000.0, 0.5, 10, 5)
    assert r0.battery.per_radian == PIONEER_DX.per_radian  # the preset's where not given
    assert r1.battery == PIONEER_AT and r2.battery is None
    (c,) = s.chargers
    assert (c.name, c.rate, c.distance, c.angle) == ("dock0", 150.0, 0.4, pytest.approx(math.radians(15)))
    assert any("'max_chrage'" in x and "did you mean 'max_charge'" in x for x in s.warnings)


@pytest.mark.parametrize(
    "body, expect",
    [
        ("robots: [{name: r0, battery: {charge: 2}}]", "robots[0] (r0).battery.charge must be a fraction"),
        ("robots: [{name: r0, battery: {capacity: 0}}]", "robots[0] (r0).battery.capacity must be a positive"),
        ("robots: [{name: r0}]\nchargers: [{name: r0}]", "chargers[0]: the name 'r0' is taken"),
        ("robots: [{name: r0}]\nchargers: [{name: c, rate: -3}]", "chargers[0] (c).rate must be a positive number"),
        ("robots: [{name: r0}]\nchargers: [{pose: [0, 0]}]", "chargers[0] needs 'name'"),
    ],
)
def test_yaml_energy_errors_are_one_line_with_the_place(tmp_path: Path, body: str, expect: str):
    p = tmp_path / "bad.yaml"
    p.write_text(body + "\n")
    with pytest.raises(WorldFileError) as e:
        load_world(p)
    msg = str(e.value)
    assert expect in msg and str(p) in msg and "\n" not in msg


def test_a_charger_outside_the_map_is_refused_in_one_line(tmp_path: Path):
    img = np.full((40, 40), 255, dtype=np.uint8)
    png = tmp_path / "m.png"
    Image.fromarray(img).save(png)
    fp = FloorplanSpec(bitmap=png, resolution=0.1, origin=(0.0, 0.0))
    spec = WorldSpec(floorplan=fp, models=[bot("r0", (1.0, 1.0, 0.0))])
    spec.chargers = [ChargerSpec("dock", pose=(9.0, 1.0, 0.0), source="w.yaml:7")]
    with pytest.raises(ModelError) as e:
        World(spec)
    msg = str(e.value)
    assert msg.startswith("w.yaml:7: charger 'dock' at (9, 1) is outside the map") and "\n" not in msg
