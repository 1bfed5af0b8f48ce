"""The thesis swarm's batch step (agents/scenarios/swarm/thesisstep.py) against the per-robot cycle.

The per-robot code defines the semantics: :meth:`ThesisPioneer.update` (its localize guard, its
sectors with the neighbours' bodies and the walls without them, :class:`Disperse` with the
body-aware checks of :func:`params_for_size`) robot by robot, against :class:`ThesisStep` on the
same recorded inputs (odometry, sonar scans, localize poses, the host's received broadcasts, the
clock), many cycles in a row so that the behaviours' timers and the guard's references carry over.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from agents.hub import RobotHub
from agents.scenarios.swarm.behaviour import Disperse
from agents.scenarios.swarm.thesis import ThesisPioneer, _bodies, params_for_size
from agents.scenarios.swarm.thesisstep import ThesisStep, neighbour_bodies
from agents.scenarios.swarm.vector import STATES, VectorState, lane_distances
from rsal.behaviours import SECTOR_COUNT, BehaviourParams, ListSectors, lane_distance
from rsal.clock import Clock, clock, set_clock
from rsal.devices import Position2d, Sonar
from rsal.msgs import Position2dData, RangerData
from rsal.testing import FakeFabric

# a 16-sonar ring like the Pioneer 3-AT's (a bearing per beam, in degrees)
RING = [90, 50, 30, 10, -10, -30, -50, -90, -90, -130, -150, -170, 170, 150, 130, 90]
GEOMETRY = {
    "kind": "sonar",
    "pose": [0.0, 0.0, 0.0],
    "sensors": [
        {"pose": [0.2 * math.cos(math.radians(a)), 0.15 * math.sin(math.radians(a)), math.radians(a)]} for a in RING
    ],
}


def test_lane_distances_are_lane_distance_row_by_row():
    rng = np.random.default_rng(1)
    s = rng.uniform(0.1, 3.0, (400, SECTOR_COUNT))
    s[rng.random(s.shape) < 0.3] = np.inf
    hw = rng.uniform(0.2, 0.5, 400)
    for behind in (False, True):
        got = lane_distances(s, hw, behind)
        want = [lane_distance(ListSectors(row.tolist()), float(w), behind) for row, w in zip(s, hw, strict=True)]
        np.testing.assert_array_equal(got, want)


def test_neighbour_bodies_are_bodies_row_by_row():
    rng = np.random.default_rng(2)
    n, m = 60, 80
    est = np.column_stack([rng.uniform(0, 8, (n, 2)), rng.uniform(-4, 4, n)])
    xy = rng.uniform(0, 8, (m, 2))
    xy[rng.random(m) < 0.1] = np.nan  # stale on the board
    xy[0] = est[0, :2]  # a neighbour exactly where the robot is: skipped
    xy[1] = est[1, :2] + 0.1  # one closer than its radius: it spans half the ring
    own = np.where(rng.random(n) < 0.8, rng.integers(0, m, n), -1)
    reach = rng.uniform(1.5, 3.0, n)
    radius = rng.uniform(0.3, 0.5, n)
    got = neighbour_bodies(est, xy, own, reach, radius)
    for i in range(n):
        ok = [j for j in range(m) if j != own[i] and math.dist(xy[j], est[i, :2]) <= reach[i]]
        want = _bodies(xy[ok].reshape(-1, 2), *est[i], radius[i])
        np.testing.assert_allclose(got[i], want, rtol=1e-12, atol=1e-12)
    assert np.isfinite(got).any(axis=1).sum() > n // 2


def test_vector_state_with_body_checks_and_walls_steps_like_disperse():
    rng = np.random.default_rng(7)
    n, cycles = 300, 80
    ref = []
    for i in range(n):
        base = BehaviourParams(stuck_time=float(rng.choice([0.2, 0.5])), escape_time=0.3, side=("left", "right")[i % 2])
        p = params_for_size(0.626, 0.505, base) if i % 4 else base  # a quarter without body checks
        b = Disperse(p)
        b.set_wallfollow(True) if i % 5 else b.set_command(0.3, 0.0)
        ref.append(b)
    vec = copy.deepcopy(ref)
    seen, guarded = set(), 0
    for c in range(cycles):
        now = 10.0 + 0.1 * c
        s = rng.uniform(0.1, 3.0, (n, SECTOR_COUNT))
        s[rng.random(s.shape) < 0.5] = np.inf
        s[rng.random(n) < 0.3] = np.inf
        blocked = rng.random(n) < (0.6 if (c // 10) % 2 else 0.1)
        s[np.ix_(blocked, [34, 35, 0, 1, 2])] = 0.2
        robots = rng.random(s.shape) < 0.3  # echoes some neighbour's body explains
        walls = np.where(robots, np.inf, s)
        alone = rng.random(n) < 0.3  # no neighbour in reach: the walls are the sectors
        walls[alone] = s[alone]
        stalled = rng.random(n) < 0.05
        yaw = rng.uniform(-math.pi, math.pi, n)
        for b in ref:
            b.heading = None if rng.random() < 0.2 else float(rng.uniform(-4, 4))
        for a, b in zip(ref, vec, strict=True):
            b.heading = a.heading
        want = []
        for i, b in enumerate(ref):
            b.yaw = float(yaw[i])
            b.walls = ListSectors(walls[i].tolist())
            want.append(b.step(ListSectors(s[i].tolist()), now, bool(stalled[i])))
        st = VectorState.of(vec)
        st.yaw = yaw
        got = st.step(s, now, stalled, walls)
        st.write(vec)
        np.testing.assert_allclose(got, np.array(want), rtol=1e-12, atol=1e-12)
        for a, b in zip(ref, vec, strict=True):
            assert (b.state, b.escapes, b._escape_turn) == (a.state, a.escapes, a._escape_turn)
            seen.add(a.state)
        guarded += sum(1 for a, (v, w) in zip(ref, want, strict=True) if a.state in ("avoid", "escape") and w == 0.0)
    assert {"escape", "avoid", "wallfollow", "disperse", "command"} <= seen <= set(STATES)
    assert guarded > 50  # the turn guard and the lane behind acted, many times


# ---------------------------------------------------------------------------- ThesisStep on robots
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


def board(positions: np.ndarray, names: list[str]) -> RobotHub:
    """A hub's board of received broadcasts (what near() and received_positions() read), no network."""
    hub = RobotHub.__new__(RobotHub)
    hub.board_timeout = 5.0
    hub._index, hub._xy, hub._stamp = {}, np.zeros((0, 2)), np.zeros(0)
    for name, (x, y) in zip(names, positions.tolist(), strict=True):
        hub._remember(name, x, y)
    return hub


def crowd(fab: FakeFabric, n: int, hub: RobotHub):
    robots, calls = [], []
    for i in range(n):
        name = f"r{i}"
        pos = fab.device(Position2d, f"{name}:position2d:0", {"max_speed": [0.5, 1.0]})
        sonar = fab.device(Sonar, f"{name}:sonar:0", GEOMETRY)
        r = ThesisPioneer([pos, sonar], name=name, period=0.1, laser=False)
        r.set_wallfollow(True, side="left" if i % 2 else "right")
        r.behaviour.p = params_for_size(0.626, 0.505, r.behaviour.p)
        r.neighbour_radius = 0.36
        r.localize = fab.device(Position2d, f"{name}:position2d:2")
        r.localize.rpc_async = lambda op, _n=name, **a: calls.append((_n, op, a["pose"]))
        r.neighbours = lambda x, y, rr, _n=name: hub.near(x, y, rr, exclude=_n)
        robots.append(r)
    return robots, calls


def test_thesis_step_drives_thesis_pioneers_as_their_own_update(manual_clock):
    rng = np.random.default_rng(3)
    n = 16
    names = [f"r{i}" for i in range(n)] + ["other0", "other1"]
    true = np.column_stack([rng.uniform(0, 6, (n, 2)), rng.uniform(-3, 3, n)])
    odo = true.copy()
    hub = board(np.vstack([true[:, :2], [[3.0, 3.0], [4.0, 2.0]]]), names)
    fa, fb = FakeFabric(), FakeFabric()
    (ra, ca), (rb, cb) = crowd(fa, n, hub), crowd(fb, n, hub)
    step = ThesisStep(hub, lambda: manual_clock.t, ThesisPioneer)
    states = []
    for c in range(60):
        manual_clock.t += 0.1
        move = rng.uniform(-0.04, 0.04, (n, 3))
        true += move
        odo += move
        est = true + rng.normal(0, 0.05, (n, 3))
        est[rng.random(n) < 0.03, :2] += 2.0  # the filter leaps now and then: the guard re-seeds
        if c % 5 == 0:  # the broadcasts the host received (2 Hz)
            for name, (x, y) in zip(names, true[:, :2].tolist(), strict=False):
                hub._remember(name, x, y)
        stall = rng.random(n) < 0.05
        ranges = rng.uniform(0.05, 4.0, (n, len(RING)))
        ranges[rng.random(ranges.shape) < 0.4] = 5.0
        if 20 <= c < 45:
            ranges[: n // 2, 2:6] = 0.15  # half the crowd blocked for 3 s: escapes
        heading = rng.uniform(-3, 3, n)
        for robots, fab in ((ra, fa), (rb, fb)):
            for i, r in enumerate(robots):
                fab.push(r.position2d, Position2dData(0.0, tuple(odo[i]), (0.0, 0.0, 0.0), bool(stall[i])))
                fab.push(r.sonars[0], RangerData(0.0, ranges[i], 0.0, 0.0, 0.1, 5.0))
                if c or i % 3:  # a third of the robots have no localize pose in the first cycle
                    fab.push(r.localize, Position2dData(0.0, tuple(est[i]), (0.0, 0.0, 0.0), False))
                r.behaviour.heading = None if (c + i) % 3 else float(heading[i])
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
        assert [r.behaviour.yaw for r in rb] == [r.behaviour.yaw for r in ra]
    assert len(fb.velocities()) == len(fa.velocities()) > 20 * n  # every cycle's commands, in order
    np.testing.assert_allclose(fb.velocities(), fa.velocities(), atol=1.5e-3)  # both rounded to 1 mm/s
    assert [r.distance for r in rb] == pytest.approx([r.distance for r in ra])
    assert cb == ca and len(ca) > 5  # the same re-seeds, at the same poses
    assert [r.reseeds for r in rb] == [r.reseeds for r in ra]
    assert step.stepped == 59 * n
    assert sum(r.behaviour.escapes for r in ra) >= n // 4
    assert {"escape", "avoid", "wallfollow", "disperse"} <= {s for row in states for s in row}


def test_thesis_step_leaves_robots_without_a_localize_pose_to_their_own_cycle(manual_clock):
    hub = board(np.zeros((0, 2)), [])
    fab = FakeFabric()
    robots, _ = crowd(fab, 3, hub)
    step = ThesisStep(hub, lambda: manual_clock.t, ThesisPioneer)
    for r in robots:
        fab.push(r.position2d, Position2dData(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False))
        fab.push(r.sonars[0], RangerData(0.0, np.full(len(RING), 5.0), 0.0, 0.0, 0.1, 5.0))
        r.update()  # learns its beam geometry
    fab.push(robots[1].localize, Position2dData(0.0, (1.0, 1.0, 0.5), (0.0, 0.0, 0.0), False))
    robots[2].neighbours = None
    assert step(robots) == [robots[0], robots[2]]
    assert step.stepped == 1 and robots[1].behaviour.yaw == 0.5  # steers by its localize pose
