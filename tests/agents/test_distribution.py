"""The Distribution scenario (thesis 4.2.4): target points from the map, their assignment, the
DispersionAgent with navigating agents, and the loss of an agent mid-run.

Unit tests check :func:`target_points` on the floor map against an independent distance field and
flood fill (reachable, clearance, spacing, rooms and corridor, the doorless server room never
chosen) and :func:`assign` against brute force. The agent tests run the DispersionAgent on one
AgentHost (a real Zenoh session on loopback) with stand-in navigating agents that move in a
straight line and report ``arrived``: goals only to the navigating class, distinct targets, and a
killed agent dropped with its target re-assigned. The last test runs the ``three`` application of
``deploy/scenarios/distribution.yaml`` end to end with ``rsal run``: the simulator with the full
navigation stack (AMCL, Wavefront, VFH) per robot, three NavAgents and the DispersionAgent; the last
kills the real NavAgent holding target 0 while it drives: it is dropped and a live one takes target 0.
Both end-to-end runs judge arrival on ground truth, not on the agents' own reports: ``rsal run``
confirms the verdict with the simulator's poses (:mod:`agents.verdict`), and the in-process run reads
the true poses (``rsal sim --truth``) at the verdict: every robot within
:data:`agents.verdict.ARRIVE_TOLERANCE` of its assigned target.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import re
import time

import numpy as np
import pytest
from scipy import ndimage

from agents.runtime import Agent, AgentHost
from agents.scenarios.distribution import DispersionAgent, assign, target_points
from agents.services import Message, Outcome, SendPosition, match
from agents.verdict import ARRIVE_TOLERANCE  # Wavefront's goal tolerance + the 0.30 m localization bound
from rsal.msgs import MapData
from rsal.transport import TransportArgs
from simulator.loader import load_world
from simulator.world import World
from tests.conftest import MAPS, ROOT, SPEEDUP_NAV, free_port, rsal_cmd, wait_until
from tests.truth import Truth

STARTS = [(-20.5, 5.0), (-14.0, 5.5), (-21.0, 8.0)]  # r0..r2 of maps/distribution.world


@pytest.fixture(scope="module")
def floor() -> MapData:
    g = World(load_world(str(MAPS / "distribution.world"))).grid
    return MapData(g.width, g.height, g.resolution, g.origin, np.where(g.occupied, 1, -1).astype(np.int8))


def _cell(m: MapData, x: float, y: float) -> tuple[int, int]:
    return int((y - m.origin[1]) / m.resolution), int((x - m.origin[0]) / m.resolution)


# ---------------------------------------------------------------------------- targets
@pytest.mark.parametrize("n", [3, 8, 20])
def test_targets_are_reachable_clear_of_walls_and_spread(floor, n):
    t = target_points(floor, STARTS, n, clearance=0.6, spacing=2.0)
    assert len(t.xy) == n
    # independent check: clearance by brute-force distance to the occupied cells nearby
    occ_y, occ_x = np.nonzero(floor.cells > 0)
    ox = floor.origin[0] + (occ_x + 0.5) * floor.resolution
    oy = floor.origin[1] + (occ_y + 0.5) * floor.resolution
    for x, y in t.xy:
        d = np.hypot(ox - x, oy - y).min()
        assert d >= 0.6 - floor.resolution, f"target ({x:.2f}, {y:.2f}) only {d:.2f} m from a wall"
    # independent reachability: flood fill from the first robot over cells 0.3 m clear of walls
    clear = ndimage.distance_transform_edt(floor.cells < 0) * floor.resolution >= 0.3
    lab, _ = ndimage.label(clear, structure=np.ones((3, 3)))
    start = lab[_cell(floor, *STARTS[0])]
    assert start > 0
    assert all(lab[_cell(floor, x, y)] == start for x, y in t.xy)
    assert t.min_spacing() >= 2.0


def test_targets_reach_rooms_and_the_corridor_but_not_the_doorless_room(floor):
    t = target_points(floor, STARTS, 20, clearance=0.6, spacing=2.0)
    y = t.xy[:, 1]
    corridor = (y > 0.5) & (y < 3.0)
    assert corridor.any(), "some targets lie in the corridor"
    assert (y > 3.2).sum() >= 4 and (y < 0.3).sum() >= 4, "targets in the rooms north and south"
    # the server room N5 (x -2.8 .. 0.2, north of the corridor) has no door
    assert not ((t.xy[:, 0] > -2.8) & (t.xy[:, 0] < 0.2) & (y > 3.2)).any()
    n5 = _cell(floor, -1.3, 6.0)
    assert floor.cells[n5] < 0 and not t.reachable[n5], "N5 is free space but unreachable"
    # the spread of the first 8 is at least as wide as of all 20 (nested farthest-point order)
    assert target_points(floor, STARTS, 8).min_spacing() >= t.min_spacing()


def test_targets_within_a_box_spacing_limit_and_errors(floor):
    t = target_points(floor, STARTS, 3, within=[-31, -8, -8, 12])
    assert len(t.xy) == 3 and (t.xy[:, 0] <= -8).all()
    few = target_points(floor, STARTS, 50, spacing=15.0)
    assert 1 < len(few.xy) < 50 and few.min_spacing() >= 15.0
    with pytest.raises(ValueError, match="drivable"):
        target_points(floor, [(500.0, 500.0)], 3)
    with pytest.raises(ValueError, match="at least 1"):
        target_points(floor, STARTS, 0)


def test_assignment_minimises_total_distance():
    rng = np.random.default_rng(0)
    for _ in range(20):
        robots, targets = rng.uniform(-10, 10, (4, 2)), rng.uniform(-10, 10, (4, 2))
        pairs = assign(robots, targets)
        cost = sum(np.hypot(*(robots[r] - targets[t])) for r, t in pairs)
        best = min(
            sum(np.hypot(*(robots[i] - targets[p[i]])) for i in range(4)) for p in itertools.permutations(range(4))
        )
        assert cost == pytest.approx(best)
    assert len(assign(rng.uniform(0, 1, (3, 2)), rng.uniform(0, 1, (2, 2)))) == 2


def test_constructor_errors_are_clear():
    with pytest.raises(TypeError):
        DispersionAgent("d", colour="red")
    with pytest.raises(ValueError, match="within"):
        DispersionAgent("d", within=[1, 2, 0, 3])
    with pytest.raises(ValueError, match="targets"):
        DispersionAgent("d", targets=[[1, "x"]])
    with pytest.raises(ValueError, match="expect"):
        DispersionAgent("d", expect=-1)


# ---------------------------------------------------------------------------- with stand-in agents
class FakeNav(Agent):
    """Stands in for a NavAgent: drives straight to each new goal at ``speed`` m/s, broadcasts its
    map position and reports ``arrived``."""

    def __init__(self, agent_id: str, *, robot: str, start: tuple[float, float], speed: float = 4.0):
        super().__init__(agent_id, period=0.1, robot=robot)
        self.x, self.y = start
        self.speed = speed
        self.goal: tuple[float, float] | None = None
        self.goals: list[tuple[float, float]] = []

    async def created(self) -> None:
        self.subscribe("new_goal", self.on_goal, filter=match(to=self.id))

    def on_goal(self, msg: Message) -> None:
        self.goal = (msg.body.x, msg.body.y)
        self.goals.append(self.goal)

    async def step(self) -> None:
        if self.goal is not None:
            dx, dy = self.goal[0] - self.x, self.goal[1] - self.y
            d = math.hypot(dx, dy)
            s = min(d, self.speed * self.period)
            if d > 0:
                self.x, self.y = self.x + dx / d * s, self.y + dy / d * s
            if d <= s + 1e-9:
                self.goal = None
                self.publish("outcome", Outcome("arrived", self.robot, f"{self.robot} arrived"))
        self.publish("send_position", SendPosition(self.robot, self.x, self.y, 0.0, "map"))


class Bystander(FakeNav):
    """An agent of another class (not to be given goals)."""


class MapDispersion(DispersionAgent):
    def __init__(self, agent_id: str, grid: MapData, **kw):
        super().__init__(agent_id, classes=["FakeNav"], **kw)
        self._grid = grid

    async def load_map(self) -> MapData:
        return self._grid


async def _until(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(0.05)


def test_dispersion_sends_distinct_targets_to_navigating_agents_only(floor):
    async def main():
        ep = f"tcp/127.0.0.1:{free_port()}"
        async with AgentHost.connect(TransportArgs(listen=[ep])) as host:
            # stand-ins at 16 m/s: the farthest target is 49 m away on the floor map
            navs = [FakeNav(f"nav{i}", robot=f"r{i}", start=s, speed=16.0) for i, s in enumerate(STARTS)]
            other = Bystander("other", robot="r9", start=(-5.0, 1.75))
            for a in [*navs, other]:
                await host.start(a)
            verdicts: list[Outcome] = []
            watch = Agent("watch")
            await host.start(watch)
            watch.subscribe("outcome", lambda m: verdicts.append(m.body), filter=match(event="verdict"))
            disp = MapDispersion("disp", floor, expect=3, spacing=3.0, clearance=0.7)
            await host.start(disp)
            await _until(lambda: verdicts, 120, "the dispersion verdict")
            return navs, other, disp, verdicts[0]

    navs, other, disp, v = asyncio.run(main())
    assert v.ok and v.final and v.subject == "distribution", v.text
    assert re.match(r"3 robots reached 3 distinct targets, min spacing \d+\.\d m", v.text)
    assert other.goals == [], "an agent of another class gets no goal"
    ends = np.array([n.goals[-1] for n in navs])
    assert len({tuple(e) for e in ends}) == 3
    spacing = min(np.hypot(*(a - b)) for a, b in itertools.combinations(ends, 2))
    assert spacing >= 3.0 and f"min spacing {spacing:.1f} m" in v.text
    assert {tuple(e) for e in ends} == {tuple(t) for t in disp.targets}


def test_killed_agent_is_dropped_and_its_target_reassigned(floor):
    async def main():
        ep = f"tcp/127.0.0.1:{free_port()}"
        async with AgentHost.connect(TransportArgs(listen=[ep])) as host:
            # 4 m/s: every target is 8 m or more away, so the victim is killed seconds before it could arrive
            navs = [FakeNav(f"nav{i}", robot=f"r{i}", start=s, speed=4.0) for i, s in enumerate(STARTS)]
            for a in navs:
                await host.start(a)
            verdicts: list[Outcome] = []
            watch = Agent("watch")
            await host.start(watch)
            watch.subscribe("outcome", lambda m: verdicts.append(m.body), filter=match(event="verdict"))
            disp = MapDispersion("disp", floor, expect=3, within=[-31, -8, -8, 12], spacing=3.0)
            await host.start(disp)
            await _until(lambda: len(disp.assignment) == 3 and all(n.goals for n in navs), 30, "three assignments")
            # kill the agent holding target 0 (the first, most important one) before it arrives
            victim = next(n for n in navs if disp.assignment[n.id] == 0)
            first_goal = tuple(disp.targets[0])
            await host.kill(victim)
            await _until(lambda: victim.id in disp.dropped, 10, "the killed agent to be dropped")
            await _until(lambda: verdicts, 120, "the dispersion verdict")
            return navs, victim, first_goal, disp, verdicts[0], dict(disp.assignment), list(disp.dropped)

    navs, victim, first_goal, disp, v, assignment, dropped = asyncio.run(main())
    live = [n for n in navs if n is not victim]
    assert victim.id not in assignment and dropped == [victim.id]
    assert any(tuple(n.goals[-1]) == pytest.approx(first_goal) for n in live), "target 0 re-assigned"
    assert sorted(assignment.values()) == [0, 1], "the live agents hold the first two targets"
    assert v.ok, v.text
    assert v.text.startswith("2 robots reached 2 distinct targets") and f"dropped {victim.robot}" in v.text


# ---------------------------------------------------------------------------- end to end
@pytest.mark.timeout(900)
def test_three_navagents_reach_distinct_targets_with_rsal_run(procs):
    ep = f"tcp/127.0.0.1:{free_port()}"
    scenario = str(ROOT / "deploy" / "scenarios" / "distribution.yaml")
    args = ("--app", "three", "--listen", ep, "--set", "within=[-31, -8, 2, 12]", "--speedup", SPEEDUP_NAV)
    run = procs(rsal_cmd("run", scenario, *args))
    wait_until(lambda: not run.alive(), 600, "the distribution run to end")
    out = run.output()
    print(out[-3000:])
    assert run.p.returncode == 0, out[-3000:]
    m = re.search(r"3 robots reached 3 distinct targets, min spacing (\d+\.\d) m", out)
    assert m and float(m.group(1)) >= 3.0, out[-3000:]
    # the verdict was confirmed on ground truth: every robot truly at its assigned target
    m = re.search(r"\[run\] ground truth: r0 ([\d.]+) m, r1 ([\d.]+) m, r2 ([\d.]+) m from the assigned targets", out)
    assert m and all(float(d) <= ARRIVE_TOLERANCE for d in m.groups()), out[-3000:]
    assert "not confirmed" not in out, out[-3000:]


@pytest.mark.timeout(900)
def test_killed_navagent_is_dropped_and_its_target_reached_by_another(procs, sim_time):
    """Three real NavAgents (AMCL + Wavefront + VFH in ``rsal sim`` at the speed-up, the agents on its
    clock) in this process; the one holding target 0 is killed once all are driving: it is dropped
    and a live one drives to target 0."""
    from agents.navigation import NavAgent

    ep = f"tcp/127.0.0.1:{free_port()}"
    world = str(MAPS / "distribution.world")
    nav = ["--nav", "vfh", "--nav-robots", "r0,r1,r2"]
    procs(rsal_cmd("sim", world, "--listen", ep, *nav, "--speedup", SPEEDUP_NAV, "--truth"))

    async def main():
        async with AgentHost.connect(TransportArgs(connect=[ep])) as host:
            await asyncio.to_thread(sim_time, host.session)
            truth = Truth(host.session, ["r0", "r1", "r2"])
            navs = [NavAgent(f"nav{i}", robot=f"r{i}", startup_timeout=120) for i in range(3)]
            await asyncio.gather(*(host.start(a) for a in navs))
            disp = DispersionAgent(
                "disp", expect=3, within=[-31, -8, 2, 12], spacing=3.0, clearance=0.7, startup_timeout=120
            )
            await host.start(disp)
            await _until(lambda: len(disp.assignment) == 3 and all(n.goal for n in navs), 120, "three goals")
            victim = next(n for n in navs if disp.assignment[n.id] == 0)
            target0 = tuple(disp.targets[0])
            await host.kill(victim)
            await _until(lambda: victim.id in disp.dropped, 15, "the killed agent to be dropped")
            await _until(lambda: disp.verdict is not None, 600, "the dispersion verdict")
            # where the robots truly are at the verdict, against their assigned targets
            off = {
                disp.participants[a]: truth.to(disp.participants[a], *disp.targets[i])
                for a, i in disp.assignment.items()
            }
            truth.close()
            live = [n for n in navs if n is not victim]
            return victim, target0, live, disp.verdict, dict(disp.assignment), [n.reached for n in live], off

    victim, target0, live, v, assignment, reached, off = asyncio.run(main())
    print(f"true distances to the assigned targets at the verdict: {off}")
    assert len(off) == 2 and all(d <= ARRIVE_TOLERANCE for d in off.values()), off
    print(v.text)
    assert victim.id not in assignment and sorted(assignment.values()) == [0, 1]
    taker = next(n for n in live if assignment[n.id] == 0)
    assert (taker.goal.x, taker.goal.y) == pytest.approx(target0), "target 0 went to a live agent"
    assert v.ok and v.text.startswith("2 robots reached 2 distinct targets") and f"dropped {victim.robot}" in v.text
    assert all(r >= 1 for r in reached)
