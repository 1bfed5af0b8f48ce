"""Hunt and Prey with energy stations (thesis 4.2.1, "An Advanced Hunt and Prey Scenario").

Without a network: the prey's recharge decision (:func:`recharge_mode`, and its step on fakes),
its way to a station (:func:`nearest_station`, :func:`steer`), the hunters' choice of station to
wait at (:func:`watch_station`, :func:`watch_point`, and the hunter's step: ambush out of sight,
chase in sight), argument errors, the scenario entry, and the verdict's energy note on
fakes. With real processes: ``rsal run deploy/scenarios/hunt_prey.yaml --app energy`` on a free
loopback port at the simulator's speed-up; the runner's ground truth (the simulator's true poses
and the prey's ``power:0``, driven by the simulator's battery model) confirms the catch, says
where the prey was against the stations, its true battery at the catch, and that it truly charged
or ran flat before. Every wait has a deadline.
"""

from __future__ import annotations

import asyncio
import math
import re
from types import SimpleNamespace

import pytest

from agents.dispatch import Charger
from agents.scenario import load_scenario
from agents.scenarios.hunt import EnergyEscapeAgent, FollowAgent
from agents.scenarios.hunt.energy import recharge_mode, steer
from agents.scenarios.hunt.stations import nearest_station, watch_point, watch_station
from agents.services import Message, Outcome, SendPosition
from agents.verdict import NEAR_STATION, GroundTruth
from rsal.clock import Clock, set_clock
from rsal.data import Position
from rsal.interfaces.power import PowerData
from tests.conftest import ROOT, SPEEDUP, free_port, rsal_cmd, wait_until

SCENARIO = ROOT / "deploy" / "scenarios" / "hunt_prey.yaml"
WEST, EAST = Charger("west", -8.8, 1.0, 0.0), Charger("east", 8.8, -1.0, math.pi)
STATIONS = [{"name": "west", "pose": [-8.8, 1.0, 0]}, {"name": "east", "pose": [8.8, -1.0, 180]}]


# ---------------------------------------------------------------------------- the prey's decision
@pytest.mark.parametrize(
    "mode, fraction, charging, expected",
    [
        ("flee", 0.8, False, "flee"),  # enough charge: keep fleeing
        ("flee", 0.49, False, "seek"),  # below the threshold: go and charge
        ("seek", 0.3, False, "seek"),  # not there yet
        ("seek", 0.3, True, "charge"),  # docked: the station charges it
        ("charge", 0.6, True, "charge"),  # charging, below the target
        ("charge", 0.9, True, "flee"),  # at the target: flee on
        ("charge", 0.6, False, "seek"),  # pushed off the station before the target: back to it
        ("flee", 0.0, False, "seek"),  # flat: it still wants a station (and cannot move)
    ],
)
def test_prey_recharge_decision(mode, fraction, charging, expected):
    assert recharge_mode(mode, fraction, charging, threshold=0.5, target=0.9) == expected


def test_prey_heads_for_the_nearest_station_and_steers_onto_it():
    assert nearest_station([WEST, EAST], -2.0, 0.0) is WEST
    assert nearest_station([WEST, EAST], 2.0, 0.0) is EAST
    assert nearest_station([], 0.0, 0.0) is None
    # facing the station: straight on at cruise speed, no turn
    v, w = steer(Position(-6.8, 1.0, math.pi), WEST.x, WEST.y, 0.2)
    assert v == pytest.approx(0.2) and w == pytest.approx(0.0, abs=1e-9)
    # the station behind: turn on the spot towards it (left or right, the shorter way)
    v, w = steer(Position(-6.8, 1.0, 0.0), WEST.x, WEST.y, 0.2)
    assert v == pytest.approx(0.0, abs=1e-9) and abs(w) == pytest.approx(0.8)
    v, w = steer(Position(0.0, 0.0, 0.0), 0.0, 5.0, 0.2)  # station to the left
    assert w > 0 and v == pytest.approx(0.0, abs=1e-9)
    # slowing down over the last metre
    v, _ = steer(Position(-8.5, 1.0, math.pi), WEST.x, WEST.y, 0.2)
    assert 0 < v < 0.1


# ---------------------------------------------------------------------------- the hunters' ambush
def test_hunters_split_the_stations_nearest_the_prey_last_seen_first():
    north = Charger("north", 0.0, 5.0, -math.pi / 2)
    stations = [WEST, EAST, north]
    # one hunter: the station nearest the last sighting
    assert watch_station(stations, (6.0, -2.0), ["hunter1"], "hunter1") is EAST
    assert watch_station(stations, (-6.0, 2.0), ["hunter1"], "hunter1") is WEST
    # two hunters: the first by id takes the nearest, the second the next nearest
    ids = ["hunter2", "hunter1"]
    assert watch_station(stations, (6.0, -2.0), ids, "hunter1") is EAST
    assert watch_station(stations, (6.0, -2.0), ids, "hunter2") is north
    # more hunters than stations: round robin
    many = ["h1", "h2", "h3", "h4"]
    assert [watch_station([WEST, EAST], (-6.0, 0.0), many, h).name for h in many] == ["west", "east"] * 2
    # never seen: by name, still one station each
    assert watch_station(stations, None, ids, "hunter1") is EAST
    assert watch_station(stations, None, ids, "hunter2") is north
    # a hunter not yet heard on hello still gets a station; no stations: none
    assert watch_station(stations, (6.0, -2.0), [], "hunter9") is EAST
    assert watch_station([], (0.0, 0.0), ids, "hunter1") is None


def test_hunter_waits_in_front_of_the_station_facing_it():
    p = watch_point(EAST, 1.5)  # the east station faces west, into the hall
    assert (p.x, p.y) == pytest.approx((7.3, -1.0)) and abs(math.remainder(p.yaw, math.tau)) < 1e-9
    p = watch_point(WEST, 1.5)
    assert (p.x, p.y) == pytest.approx((-7.3, 1.0)) and abs(abs(p.yaw) - math.pi) < 1e-9


class _FakeClock(Clock):
    def __init__(self):
        self.t = 100.0

    def now(self) -> float:
        return self.t


def _position(c, robot, x, y, i=0):
    return Message("send_position", "prey0", f"p{i}", c.t, SendPosition(robot, x, y, 0.0))


def test_hunter_out_of_sight_waits_at_the_station_nearest_the_last_sighting_then_chases():
    c = _FakeClock()
    old = set_clock(c)
    try:
        h = FollowAgent("hunter1", robot="r1", prey="r0", sight=5.0, stations=STATIONS, replan_interval=0.5)
        h.pioneer = SimpleNamespace(position=Position(0.0, 0.0, 0.0))  # the nav robot, as far as step needs
        h._next_report = math.inf
        goals: list[Position] = []

        def start_goal(goal, report=True):
            goals.append(goal)
            h.goal_state = "driving"

        h.start_goal = start_goal
        # never seen (9.5 m away): no station before the first hello round says who else hunts ...
        h._on_position(_position(c, "r0", -8.0, 3.0))
        asyncio.run(h.step())
        assert goals == [] and h.watching is None
        h.hunters, h._looked = ["hunter1", "hunter2"], True  # ... then the first of two by id takes
        asyncio.run(h.step())  # the first station by name (never seen): east
        assert h.watching.name == "east" and (goals[-1].x, goals[-1].y) == pytest.approx((7.3, -1.0))
        h.hunters = ["hunter1"]  # hunting alone from here on
        # seen 4 m east: chase it
        c.t += 1.0
        h._on_position(_position(c, "r0", 4.0, -1.0))
        asyncio.run(h.step())
        assert (goals[-1].x, goals[-1].y) == pytest.approx((4.0, -1.0), abs=0.05) and h.watching is None
        assert h.seen["r0"] == (4.0, -1.0)
        # it gets away east, out of sight: wait in front of the east station (nearest the sighting)
        c.t += 1.0
        h._on_position(_position(c, "r0", 7.0, -4.0, 1))
        h.tracks = type(h.tracks)()  # no track to extrapolate from (the ambush uses the sighting)
        asyncio.run(h.step())
        assert h.watching.name == "east" and (goals[-1].x, goals[-1].y) == pytest.approx((7.3, -1.0))
        n = len(goals)
        c.t += 1.0
        asyncio.run(h.step())  # on the way: no new goal
        h.goal_state = "done"
        c.t += 1.0
        asyncio.run(h.step())  # there: waits, no new goal
        assert len(goals) == n and "waiting for r0 at station east" in h.status()
        # refused on the way (e.g. blocked): tried again after replan_interval
        h.goal_state = "unreachable"
        c.t += 1.0
        asyncio.run(h.step())
        assert len(goals) == n + 1 and (goals[-1].x, goals[-1].y) == pytest.approx((7.3, -1.0))
        # it comes into sight at the station: chase again
        h.pioneer = SimpleNamespace(position=Position(7.3, -1.0, 0.0))
        c.t += 1.0
        h._on_position(_position(c, "r0", 8.5, -2.0, 2))
        asyncio.run(h.step())
        assert h.watching is None and (goals[-1].x, goals[-1].y) == pytest.approx((8.5, -2.0), abs=0.3)
    finally:
        set_clock(old)


def test_prey_goes_to_charge_below_threshold_and_flees_again_at_target():
    c = _FakeClock()
    old = set_clock(c)
    try:
        p = EnergyEscapeAgent("prey0", robot="r0", stations=STATIONS, threshold=0.5, target=0.9, speed=0.2)
        commands: list[tuple[float, float]] = []
        wallfollow: list[bool] = []
        robot = SimpleNamespace(
            position=Position(-6.8, 1.0, math.pi),
            set_command=lambda v, w: commands.append((v, w)),
            set_wallfollow=lambda on, side=None: wallfollow.append(on),
        )
        p.pioneer = robot
        p._next_report = math.inf
        p.power = SimpleNamespace(latest=object(), fraction=0.6, charging=False)
        asyncio.run(p.step())
        assert p.mode == "flee" and commands == []  # enough charge: wall-following untouched
        p.power.fraction = 0.45
        asyncio.run(p.step())
        assert p.mode == "seek" and p.station.name == "west"
        assert commands[-1][0] == pytest.approx(0.2) and commands[-1][1] == pytest.approx(0.0, abs=1e-9)
        p.power.charging = True  # docked
        asyncio.run(p.step())
        assert p.mode == "charge" and commands[-1] == (0.0, 0.0) and p.charges == 1
        p.power.fraction = 0.91
        asyncio.run(p.step())
        assert p.mode == "flee" and wallfollow == [True] and p.station is None
        # caught: it leaves the robot to the spinning
        p.caught_by, p.power.fraction, n = "hunter1", 0.1, len(commands)
        asyncio.run(p.step())
        assert p.mode == "flee" and len(commands) == n
    finally:
        set_clock(old)


def test_bad_arguments_are_clear_errors():
    with pytest.raises(ValueError, match=r"agent p: target 0.4 must be above threshold 0.5"):
        EnergyEscapeAgent("p", robot="r0", threshold=0.5, target=0.4, simulation=True)
    with pytest.raises(ValueError, match=r"agent p: give the energy stations as stations: \[...\] or simulation: true"):
        EnergyEscapeAgent("p", robot="r0")
    with pytest.raises(ValueError, match=r"agent p: chargers\[0\] must be \{name: c0, pose: \[x, y, degrees\]\}"):
        EnergyEscapeAgent("p", robot="r0", stations=[{"name": "w"}])
    with pytest.raises(ValueError, match=r"agent h: a finite sight needs the energy stations"):
        FollowAgent("h", robot="r1", prey="r0", sight=5.0)
    with pytest.raises(ValueError, match=r"agent h: sight -1 must be a number > 0"):
        FollowAgent("h", robot="r1", prey="r0", sight=-1)
    p = EnergyEscapeAgent("p", robot="r0", stations=[{"name": "w", "pose": [-8.8, 1.0, 0]}])
    assert p.stations == [Charger("w", -8.8, 1.0, 0.0)] and p.mode == "flee"
    h = FollowAgent("h", robot="r1", prey="r0")
    assert h.sight == math.inf  # the old hunt: always in sight, no ambush


def test_energy_app_parses_and_matches_the_classes():
    from agents.scenario import check_classes

    sc = load_scenario(SCENARIO)
    app = sc.applications["energy"]
    check_classes(sc, app)
    assert (app.end.event, app.end.count) == ("caught", 1)
    prey = [a for a in app.agents if a.cls == "EnergyEscapeAgent"]
    hunters = [a for a in app.agents if a.cls == "FollowAgent"]
    assert [a.robot for a in prey] == ["r0"] and prey[0].args["threshold"] < prey[0].args["target"]
    assert sorted(a.robot for a in hunters) == list(app.simulator.nav_robots) == ["r1", "r2"]
    assert all(math.isfinite(a.args["sight"]) and a.args["simulation"] for a in hunters)
    assert app.simulator.world.name == "hunt_energy.world"


# ---------------------------------------------------------------------------- the verdict, on fakes
class FakePower:
    def __init__(self):
        self.latest = None
        self._fns = []

    def add_listener(self, fn, **kw):
        self._fns.append(fn)

    def push(self, percent, charging=False):
        self.latest = PowerData(0.0, 12.0, percent, charging)
        for fn in self._fns:
            fn(self.latest)


class FakeSim:
    def __init__(self, poses):
        self.poses = poses

    def get_pose(self, name):
        x, y = self.poses[name]
        return Position(x, y, 0.0)

    def describe(self, timeout=5.0):
        chargers = [{"name": c.name, "pose": [c.x, c.y, c.yaw]} for c in (WEST, EAST)]
        return SimpleNamespace(geometry={"chargers": chargers})


def test_verdict_reports_the_prey_true_battery_and_the_station():
    sc = load_scenario(SCENARIO)
    app = sc.applications["energy"]
    power = FakePower()
    sim = FakeSim({"r0": (-8.5, 1.0), "r2": (-7.6, 1.2)})
    gt = GroundTruth(None, sc, app, sim=sim, get_map=lambda: None, power=lambda robot: power)
    assert set(gt.energy) == {"r0"}  # only the prey that recharges is watched
    for pct, ch in [(40, False), (30, False), (55, True), (95, True), (90, False)]:
        power.push(pct, ch)
    assert gt.check("hunter2", Outcome("caught", "r0", "prey r0 caught by r2")) is None
    assert "r0 at a station (0.3 m from west)" in gt.note
    assert "true battery 90 % (charged before: yes, ran flat: no, lowest 30 %)" in gt.note
    # caught in the open after running flat
    sim.poses.update(r0=(0.0, -4.0), r2=(0.5, -4.0))
    power.push(0.0)
    assert gt.check("hunter2", Outcome("caught", "r0", "prey r0 caught by r2")) is None
    assert "r0 away from a station" in gt.note and "ran flat: yes" in gt.note and NEAR_STATION < 8


# ---------------------------------------------------------------------------- real processes
@pytest.mark.timeout(150)
def test_energy_hunt_runs_and_ground_truth_confirms_catch_and_charge(procs):
    """The whole application: the prey charges at the west station, the hunters wait at the
    stations while it is out of sight, one catches it; the runner's ground truth judges it all."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    run = procs(rsal_cmd("run", str(SCENARIO), "--app", "energy", "--speedup", SPEEDUP, "--listen", ep))
    wait_until(lambda: not run.alive(), 120, "rsal run --app energy to end")
    out = run.output()
    assert run.stop() == 0, out[-3000:]
    assert "result: ok" in out, out[-3000:]
    # the hunters waited at the stations while the prey was out of sight
    assert re.search(r"hunter\d: r0 out of sight; waiting at station (west|east)", out), out[-3000:]
    # the catch, on the simulator's true poses, with the prey's true battery
    m = re.search(
        r"ground truth: r[12] (\d+\.\d+) m from r0 at the catch; r0 (at|away from) a station "
        r"\((\d+\.\d) m from (west|east)\), true battery (\d+) %( charging)? "
        r"\(charged before: (yes|no), ran flat: (yes|no), lowest (\d+) %\)",
        out,
    )
    assert m, out[-3000:]
    d, at, to_station, station, percent, _, charged, flat, lowest = m.groups()
    print(f"catch {d} m; prey {at} a station ({to_station} m, {station}), {percent} %, charged {charged}, flat {flat}")
    assert float(d) <= 1.0 + 0.5
    assert charged == "yes" or flat == "yes"  # the energy was real: it truly charged or truly ran flat
    assert (at == "at") == (float(to_station) <= NEAR_STATION)
