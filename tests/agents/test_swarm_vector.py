"""The swarm's vectorised host step (agents/scenarios/swarm/vector.py) against the per-robot code.

Property-style: random sonar rings, random behaviour states and parameters, many cycles in a row
(so the stateful parts, the blocked and escape timers, are carried across cycles); the arrays must
give what :func:`rsal.behaviours.fuse_beams`, :class:`agents.scenarios.swarm.behaviour.Disperse`
and :meth:`rsal.robot.Pioneer.update` give robot by robot. The per-robot code defines the
semantics: a change there shows here.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from agents.scenarios.swarm.behaviour import Disperse, SwarmPioneer
from agents.scenarios.swarm.vector import STATES, HostStep, VectorState, fuse_rings
from rsal.behaviours import SECTOR_COUNT, BehaviourParams, ListSectors, fuse_beams
from rsal.clock import Clock, clock, set_clock
from rsal.devices import Position2d, Sonar
from rsal.msgs import Position2dData, RangerData
from rsal.testing import FakeFabric


def random_rings(rng, n: int, k: int):
    """n rings of k beams: origins within 0.25 m, random yaws; ranges with misses, NaN and inf."""
    a = rng.uniform(-math.pi, math.pi, (n, k))
    o = rng.uniform(-0.25, 0.25, (n, k, 2))
    beams = np.concatenate([o, np.cos(a)[..., None], np.sin(a)[..., None]], axis=2)
    rmax = rng.choice([3.0, 5.0], n)
    ranges = rng.uniform(0.02, 6.0, (n, k))
    ranges[rng.random((n, k)) < 0.2] = np.nan
    ranges[rng.random((n, k)) < 0.1] = np.inf
    at_max = rng.random((n, k)) < 0.2  # no echo
    ranges[at_max] = np.broadcast_to(rmax[:, None], (n, k))[at_max]
    return beams, ranges, rmax


@pytest.mark.parametrize("k", [8, 16])
def test_fuse_rings_is_fuse_beams_row_by_row(k):
    rng = np.random.default_rng(k)
    for _ in range(20):
        beams, ranges, rmax = random_rings(rng, 50, k)
        got = fuse_rings(beams, ranges, rmax)
        for i in range(len(beams)):
            ref = fuse_beams([tuple(b) for b in beams[i].tolist()], ranges[i], float(rmax[i]))
            np.testing.assert_allclose(got[i], ref, rtol=1e-12, atol=1e-12)


def random_behaviours(rng, n: int) -> list[Disperse]:
    out = []
    for _ in range(n):
        p = BehaviourParams(
            cruise_speed=float(rng.uniform(0.2, 0.5)),
            turn_rate=float(rng.uniform(0.4, 1.0)),
            stop_dist=float(rng.uniform(0.25, 0.45)),
            avoid_dist=float(rng.uniform(0.6, 0.9)),
            wall_dist=float(rng.uniform(0.4, 0.8)),
            stuck_time=float(rng.choice([0.2, 0.5, 2.0])),
            escape_time=float(rng.choice([0.3, 1.5])),
            side=str(rng.choice(["left", "right"])),
        )
        b = Disperse(p)
        mode = rng.integers(0, 4)
        if mode == 0:
            b.set_command(float(rng.choice([0.0, 0.3])), float(rng.choice([0.0, 0.2])))
        else:
            b.set_wallfollow(True)
        b.heading = None if rng.random() < 0.3 else float(rng.uniform(-math.pi, math.pi))
        out.append(b)
    return out


def random_sectors(rng, blocked: np.ndarray) -> np.ndarray:
    """(n, 36) sectors: open space, walls at wall-following distances, and (rows ``blocked``) an
    obstacle ahead closer than any stop distance."""
    n = len(blocked)
    s = rng.uniform(0.3, 3.0, (n, SECTOR_COUNT))
    s[rng.random((n, SECTOR_COUNT)) < 0.5] = np.inf
    s[rng.random(n) < 0.3] = np.inf  # no wall in sight: the disperse layer
    front = [33, 34, 35, 0, 1, 2, 3]
    s[np.ix_(blocked, front)] = rng.uniform(0.05, 0.24, (blocked.sum(), len(front)))
    return s


def test_vector_state_steps_like_each_robots_disperse_over_many_cycles():
    rng = np.random.default_rng(7)
    n, cycles = 300, 80
    ref = random_behaviours(rng, n)
    vec = copy.deepcopy(ref)
    blocked = rng.random(n) < 0.3
    seen = set()
    for c in range(cycles):
        now = 10.0 + 0.1 * c
        if c % 10 == 0:  # obstacles come and go, so that blocks last long enough to escape, or not
            blocked = rng.random(n) < 0.3
        sectors = random_sectors(rng, blocked)
        stalled = rng.random(n) < 0.05
        yaw = rng.uniform(-math.pi, math.pi, n)
        if c % 7 == 0:  # the agents set new headings now and then
            for b in ref:
                b.heading = None if rng.random() < 0.2 else float(rng.uniform(-4, 4))
            for a, b in zip(ref, vec, strict=True):
                b.heading = a.heading
        want = []
        for i, b in enumerate(ref):
            b.yaw = float(yaw[i])
            want.append(b.step(ListSectors(sectors[i].tolist()), now, bool(stalled[i])))
        st = VectorState.of(vec)
        st.yaw = yaw
        got = st.step(sectors, now, stalled)
        st.write(vec)
        np.testing.assert_allclose(got, np.array(want), rtol=1e-12, atol=1e-12)
        for a, b in zip(ref, vec, strict=True):
            assert (b.state, b.escapes, b._escape_turn) == (a.state, a.escapes, a._escape_turn)
            assert b._escape_until == pytest.approx(a._escape_until)
            assert (b._blocked_since is None) == (a._blocked_since is None)
            if a._blocked_since is not None:
                assert b._blocked_since == pytest.approx(a._blocked_since)
            seen.add(a.state)
    assert {"escape", "avoid", "wallfollow", "disperse", "command"} <= seen <= set(STATES)  # every layer ran
    assert sum(b.escapes for b in ref) > 10


# ---------------------------------------------------------------------------- the host step on robots
SONAR_ANGLES = np.radians([90, 50, 30, 10, -10, -30, -50, -90])
SONAR_GEOMETRY = {"kind": "sonar", "pose": [0.0, 0.0, 0.0], "sensors": [{"pose": [0.1, 0.0, a]} for a in SONAR_ANGLES]}


class ManualClock(Clock):
    def __init__(self):
        self.t = 100.0

    def now(self) -> float:
        return self.t


@pytest.fixture
def manual_clock():
    old = clock()
    c = ManualClock()
    set_clock(c)
    yield c
    set_clock(old)


def crowd(fab: FakeFabric, n: int):
    robots = []
    for i in range(n):
        pos = fab.device(Position2d, f"r{i}:position2d:0", {"max_speed": [0.5, 1.0]})
        sonar = fab.device(Sonar, f"r{i}:sonar:0", SONAR_GEOMETRY)
        r = SwarmPioneer([pos, sonar], name=f"r{i}", period=0.1, laser=False)
        r.set_wallfollow(True, side="left" if i % 2 else "right")
        robots.append(r)
    return robots


def test_host_step_drives_swarm_pioneers_as_their_own_update(manual_clock):
    rng = np.random.default_rng(3)
    n = 40
    fa, fb = FakeFabric(), FakeFabric()
    ra, rb = crowd(fa, n), crowd(fb, n)
    step = HostStep(lambda: manual_clock.t)
    states = []
    for c in range(60):
        manual_clock.t += 0.1
        pose = rng.uniform(-5, 5, (n, 3))
        stall = rng.random(n) < 0.05
        ranges = rng.uniform(0.05, 4.0, (n, 8))
        ranges[rng.random((n, 8)) < 0.4] = 5.0
        if c >= 30:
            ranges[: n // 2] = 0.1  # half the crowd blocked for 3 s: escapes
        heading = None if c % 2 else float(rng.uniform(-3, 3))
        for robots, fab in ((ra, fa), (rb, fb)):
            for i, r in enumerate(robots):
                fab.push(r.position2d, Position2dData(0.0, tuple(pose[i]), (0.0, 0.0, 0.0), bool(stall[i])))
                fab.push(r.sonars[0], RangerData(0.0, ranges[i], 0.0, 0.0, 0.1, 5.0))
                r.behaviour.heading = heading
        for r in ra:
            r.update()
        rest = step(rb)
        if c == 0:  # the first cycle learns the beam geometry robot by robot
            assert rest == rb
            for r in rest:
                r.update()
        else:
            assert rest == []
        states.append([r.state for r in ra])
        assert [r.state for r in rb] == states[-1]
        assert [r.behaviour.escapes for r in rb] == [r.behaviour.escapes for r in ra]
    assert len(fb.velocities()) == len(fa.velocities()) > 50 * n  # every cycle's commands, in order
    np.testing.assert_allclose(fb.velocities(), fa.velocities(), atol=1.5e-3)  # both rounded to 1 mm/s
    assert [r.distance for r in rb] == pytest.approx([r.distance for r in ra])
    assert step.stepped == 59 * n
    assert sum(r.behaviour.escapes for r in ra) >= n // 2
    assert {"escape", "avoid", "wallfollow", "disperse"} <= {s for row in states for s in row}


def test_host_step_leaves_other_robots_to_their_own_update(manual_clock):
    from agents.scenarios.swarm.thesis import ThesisPioneer

    fab = FakeFabric()
    pos = fab.device(Position2d, "t0:position2d:0", {})
    sonar = fab.device(Sonar, "t0:sonar:0", SONAR_GEOMETRY)
    other = ThesisPioneer([pos, sonar], name="t0", period=0.1, laser=False)
    mine = crowd(fab, 1)[0]  # no data yet
    assert HostStep(lambda: manual_clock.t)([other, mine]) == [other, mine]
