"""Hunt and Prey (thesis 4.2.1): NavAgent, FollowAgent and the prey's EscapeAgent against a real
``rsal sim maps/hunt*.world --nav vfh`` process on a free loopback port.

The agents run on an :class:`~agents.runtime.AgentHost` in this process (an asyncio loop on a
background thread); an observer agent records every ``outcome``. (a) NavAgent drives to a goal sent
on ``new_goal`` and reports ``arrived``; a superseded goal is not reported; an unreachable goal gives
``arrived`` with ``ok`` false. (b) Two hunters catch one prey within 180 s, after which the prey turns
on the spot. (c) Four hunters share two prey out by contract net and catch both. Every catch is
judged on the simulator's ground truth (``rsal sim --truth``, :class:`tests.truth.Truth`): the
catcher's true pose within the catch distance of the prey's at the moment of the ``caught`` outcome
(plus the localization and broadcast slack), and in (c) every award of the contract net went to the
truly nearest hunter still free. The scenario file
runs under ``rsal run`` in tests/fabric/test_multihost.py (across hosts) and in the control page's
browser test. Plus argument checks without a network. Every wait has a deadline; there are no fixed sleeps.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from agents.navigation import NavAgent
from agents.registry import resolve
from agents.runtime import Agent, AgentHost
from agents.scenarios.hunt import EscapeAgent, FollowAgent
from agents.services import Message, NewGoal, Outcome, SendPosition
from agents.verdict import CATCH_SLACK  # how far a true catch may lie beyond the capture distance
from rsal.clock import Clock, set_clock
from rsal.data import Position
from rsal.robot import RobotError
from rsal.transport import TransportArgs, open_session
from tests.conftest import MAPS, ROOT, SPEEDUP, SPEEDUP_NAV, LoopThread, free_port, rsal_cmd, wait_until
from tests.truth import Truth

# How much nearer than an award's winner a losing hunter may truly be: both bids are AMCL poses
# against one broadcast prey position (2 x 0.30 m localization error).
AWARD_SLACK = 0.6


class Observer(Agent):
    """Records every ``outcome`` and can send ``new_goal`` messages."""

    def __init__(self, agent_id: str = "observer", truth: Truth | None = None):
        super().__init__(agent_id, period=1.0)
        self.outcomes: list[tuple[str, Outcome]] = []
        self.truth = truth
        self.truth_at: dict[tuple[str, str, str], dict[str, Position]] = {}  # (sender, event, subject) -> poses
        self._lock = threading.Lock()

    async def created(self):
        self.subscribe(Outcome.SERVICE, self._on_outcome)

    def _on_outcome(self, msg):
        # where every robot truly is as the outcome arrives (the latest truth samples, no round trip)
        poses = self.truth.poses() if self.truth is not None else {}
        with self._lock:
            self.outcomes.append((msg.sender, msg.body))
            self.truth_at.setdefault((msg.sender, msg.body.event, msg.body.subject), poses)

    def events(self, event: str) -> list[tuple[str, Outcome]]:
        with self._lock:
            return [(s, o) for s, o in self.outcomes if o.event == event]

    def caught(self) -> set[str]:
        return {o.subject for _, o in self.events("caught")}


@pytest.fixture
def hunt(procs, sim_time):
    """Start ``rsal sim WORLD --nav vfh --nav-robots ... --truth``; yields ``start(world, nav_robots,
    robots, speedup=SPEEDUP)`` which returns an agent host connected to it, its observer and the
    ground truth of ``robots``."""
    state: dict = {}

    def start(world: str, nav_robots: str, robots: list[str], speedup: str = SPEEDUP):
        ep = f"tcp/127.0.0.1:{free_port()}"
        sim = procs(
            rsal_cmd(
                "sim",
                str(MAPS / world),
                "--listen",
                ep,
                "--nav",
                "vfh",
                "--nav-robots",
                nav_robots,
                "--speedup",
                speedup,
                "--truth",
            )
        )
        lt = LoopThread(90.0)
        session = open_session(TransportArgs(connect=[ep]))
        sim_time(session)
        truth = Truth(session, robots)
        wait_until(truth.ready, 30, f"the true poses of {', '.join(robots)}")
        host = AgentHost(session)
        lt.run(host.__aenter__())
        obs = Observer(truth=truth)
        lt.run(host.start(obs))
        state.update(lt=lt, session=session, host=host, sim=sim, truth=truth)
        return sim, lt, host, obs, truth

    yield start
    if state:
        state["lt"].run(state["host"].stop())
        state["lt"].close()
        state["truth"].close()
        state["session"].close()


def _start_all(lt: LoopThread, host: AgentHost, agents: list) -> None:
    async def go():
        await asyncio.gather(*(host.start(a) for a in agents))

    lt.run(go(), timeout=120.0)


# ---------------------------------------------------------------------------- without a network
def test_registry_resolves_the_hunt_classes():
    assert resolve("NavAgent") is NavAgent
    assert resolve("FollowAgent") is FollowAgent


class _FakeClock(Clock):
    def __init__(self):
        self.t = 100.0

    def now(self) -> float:
        return self.t


def test_hunter_plans_for_where_the_prey_is_now_between_its_broadcasts():
    """The hunter's goal is the prey's tracked pose at the step's time, not its last broadcast."""
    c = _FakeClock()
    old = set_clock(c)
    try:
        h = FollowAgent("h1", robot="r1", prey="r0", replan_interval=0.1)
        h.pioneer = SimpleNamespace(position=Position(0.0, 0.0, 0.0))  # the nav robot, as far as step needs
        h._next_report = math.inf  # no broadcast of its own: no host here
        goals: list[Position] = []
        h.start_goal = lambda goal, report=True: goals.append(goal)
        for i in range(6):  # the prey drives +x at 0.5 m/s, broadcasting at 2 Hz
            c.t = 100.0 + 0.5 * i
            h._on_position(
                Message("send_position", "prey0", f"p{i}", c.t, SendPosition("r0", 3.0 + 0.25 * i, 1.0, 0.0))
            )
        c.t += 0.4  # between two broadcasts: the last said x = 4.25, the prey is at 4.45 now
        asyncio.run(h.step())
        assert len(goals) == 1
        assert goals[0].x == pytest.approx(4.45, abs=0.03) and goals[0].y == pytest.approx(1.0, abs=0.03)
        assert h.positions["r0"].x == 4.25  # the last broadcast is still kept as it came
    finally:
        set_clock(old)


def test_a_hunter_unsure_where_it_is_does_not_claim_a_catch():
    """Within the capture distance of the prey, a hunter claims the catch only while its localizer's
    position standard deviation (the larger axis) is at most max_pose_sd; until then it chases on."""
    c = _FakeClock()
    old = set_clock(c)
    try:
        h = FollowAgent("h1", robot="r1", prey="r0", max_pose_sd=0.3)
        cov = np.diag([0.05**2, 0.6**2, 0.01])  # 0.6 m across y: unsure
        loc = SimpleNamespace(covariance=lambda: cov)
        h.pioneer = SimpleNamespace(position=Position(0.0, 0.0, 0.0), localize=loc)
        h._next_report = math.inf
        published: list[Outcome] = []
        h.publish = lambda service, body, **kw: published.append(body)
        h.host = SimpleNamespace(spawn=lambda coro, name: coro.close())
        h.start_goal = lambda goal, report=True: None
        h._on_position(Message("send_position", "prey0", "p0", c.t, SendPosition("r0", 0.8, 0.0, 0.0)))
        asyncio.run(h.step())
        assert published == [] and h.prey == "r0" and h.pose_sd() == pytest.approx(0.6)
        cov = np.diag([0.1**2, 0.2**2, 0.01])  # settled
        c.t += 1.0
        asyncio.run(h.step())
        assert [(o.event, o.subject) for o in published] == [("caught", "r0")] and h.catches == 1
    finally:
        set_clock(old)


def test_bad_arguments_are_clear_errors():
    with pytest.raises(TypeError):
        NavAgent("nav1", robot="r1", bogus=1)
    with pytest.raises(ValueError, match="a prey robot id is required"):
        FollowAgent("h1", robot="r1")
    with pytest.raises(ValueError, match="allocation 'auction' must be 'fixed' or 'contract_net'"):
        FollowAgent("h1", robot="r1", prey="r0", allocation="auction")
    with pytest.raises(ValueError, match="capture_distance"):
        FollowAgent("h1", robot="r1", prey="r0", capture_distance=-1)
    with pytest.raises(ValueError, match="max_pose_sd"):
        FollowAgent("h1", robot="r1", prey="r0", max_pose_sd=-1)
    with pytest.raises(ValueError, match="goal_timeout"):
        NavAgent("nav1", robot="r1", goal_timeout=0)
    with pytest.raises(ValueError, match="speed"):
        EscapeAgent("p0", robot="r0", speed=5)
    with pytest.raises(ValueError, match=r"pose \[1\] must be \[x, y, degrees\]"):
        EscapeAgent("p0", robot="r0", pose=[1])
    FollowAgent("h1", robot="r1", allocation="contract_net")  # no fixed prey needed


def test_scenario_file_parses_and_matches_the_classes():
    from agents.scenario import check_classes, load_scenario

    sc = load_scenario(ROOT / "deploy/scenarios/hunt_prey.yaml")
    assert set(sc.applications) == {"virtual", "advanced", "energy", "fleet"}
    for app in sc.applications.values():
        check_classes(sc, app)
    v, a = sc.applications["virtual"], sc.applications["advanced"]
    assert (v.end.event, v.end.count) == ("caught", 1) and (a.end.event, a.end.count) == ("caught", 2)
    assert sorted(x.robot for x in v.agents if x.type == "hunter") == list(v.simulator.nav_robots) == ["r1", "r2"]
    assert all(x.args.get("allocation") == "contract_net" for x in a.agents if x.type == "hunter")


# ---------------------------------------------------------------------------- with the simulator
@pytest.mark.timeout(240)
def test_nav_agent_goes_to_new_goal_reports_arrived_and_unreachable(hunt):
    # only r1's navigation stack, in the simulator's process, drives: at SPEEDUP_NAV
    sim, lt, host, obs, truth = hunt("hunt.world", "r1,r2", ["r1"], speedup=SPEEDUP_NAV)
    nav = NavAgent("nav1", robot="r1", startup_timeout=60)
    _start_all(lt, host, [nav])

    def send(x, y):
        lt.loop.call_soon_threadsafe(obs.publish, NewGoal.SERVICE, NewGoal("nav1", x, y, 0.0))

    def arrived():
        return [o for s, o in obs.events("arrived") if s == "nav1"]

    # a first goal, superseded at once by a second: only the second one is reported
    send(-5.0, 1.75)
    wait_until(lambda: nav.goal is not None and nav.goal.x == -5.0, 10, "nav1 to take the first goal")
    send(-11.5, 1.75)
    wait_until(lambda: arrived(), 120, "nav1's arrived outcome")
    first = arrived()[0]
    assert first.ok and first.subject == "r1" and "(-11.50, 1.75)" in first.text, first
    p = nav.nav.position
    assert math.hypot(p.x + 11.5, p.y - 1.75) < 0.6, p
    # and it truly is there: the simulator's pose as the outcome came in
    t = obs.truth_at[("nav1", "arrived", "r1")]["r1"]
    assert math.hypot(t.x + 11.5, t.y - 1.75) < 0.6, t
    assert nav.reached == 1 and nav.failed == 0
    assert "goal (-11.50, 1.75) done" in nav.status() and "reached 1" in nav.status()

    # an unreachable goal: inside the server room N5, which has no door
    send(-1.3, 6.0)
    wait_until(lambda: len(arrived()) >= 2, 30, "nav1's outcome for the unreachable goal")
    bad = arrived()[1]
    assert not bad.ok and "unreachable" in bad.text and "no path" in bad.text, bad

    # a robot without the navigation stack (r0, the prey) is a clear error
    with pytest.raises(RobotError, match=r"robot 'r0': no planner or localize device appeared within 3 s"):
        lt.run(host.start(NavAgent("nav0", robot="r0", startup_timeout=3)))
    assert sim.alive()


@pytest.mark.timeout(300)
def test_two_hunters_catch_the_prey_which_then_spins(hunt):
    sim, lt, host, obs, truth = hunt("hunt.world", "r1,r2", ["r0", "r1", "r2"])
    prey = EscapeAgent("prey0", robot="r0", speed=0.2, simulation=True, startup_timeout=60)
    hunters = [FollowAgent(f"hunter{i}", robot=f"r{i}", prey="r0", startup_timeout=60) for i in (1, 2)]
    t0 = time.monotonic()
    _start_all(lt, host, [prey, *hunters])
    wait_until(lambda: obs.caught(), 180, "a hunter to catch the prey r0")
    took = time.monotonic() - t0
    (sender, out), *more = obs.events("caught")
    assert out.subject == "r0" and sender in ("hunter1", "hunter2") and not more
    catcher = next(h for h in hunters if h.id == sender)
    assert out.text.startswith(f"prey r0 caught by {catcher.robot} after ") and out.text.endswith(" s")
    print(f"caught after {took:.1f} s wall: {out.text}")

    # the catch was honest: the catcher's localized pose is near the prey's broadcast one
    me, them = catcher.nav.position, catcher.positions["r0"]
    assert math.hypot(me.x - them.x, me.y - them.y) <= catcher.capture_distance + 0.5
    # ... and true: the simulator's poses at the moment the outcome arrived
    at = obs.truth_at[(sender, "caught", "r0")]
    d_true = math.hypot(at[catcher.robot].x - at["r0"].x, at[catcher.robot].y - at["r0"].y)
    print(f"true distance at the catch: {d_true:.2f} m (capture distance {catcher.capture_distance:g} m)")
    assert d_true <= catcher.capture_distance + CATCH_SLACK, (d_true, at)

    # the prey spins: turning on the spot, not translating
    wait_until(lambda: prey.caught_by == sender, 10, "the prey to hear of its catch")
    base = prey.pioneer.position2d

    def spinning():
        v, w = base.velocity
        return abs(w) > 0.4 and abs(v) < 0.05

    wait_until(spinning, 15, "the prey's position2d to report turning without translating")
    p0 = base.position
    turned = [0.0]
    last = [p0.yaw]

    def turned_half():
        y = base.position.yaw
        turned[0] += abs(math.remainder(y - last[0], math.tau))
        last[0] = y
        return turned[0] > math.pi / 2

    wait_until(turned_half, 15, "the prey to turn 90 degrees", interval=0.1)
    p1 = base.position
    assert math.hypot(p1.x - p0.x, p1.y - p0.y) < 0.1, (p0, p1)
    assert "spinning" in prey.status()
    # both hunters stop chasing
    wait_until(lambda: all(not h.prey for h in hunters), 10, "both hunters to end the chase")
    assert sim.alive()


@pytest.mark.timeout(330)
def test_advanced_hunters_share_two_prey_by_contract_net_and_catch_both(hunt):
    sim, lt, host, obs, truth = hunt("hunt_advanced.world", "r2,r3,r4,r5", [f"r{i}" for i in range(6)])
    prey = [EscapeAgent(f"prey{i}", robot=f"r{i}", speed=0.2, simulation=True, startup_timeout=60) for i in (0, 1)]
    hunters = [
        FollowAgent(f"hunter{i}", robot=f"r{i}", allocation="contract_net", startup_timeout=60) for i in (2, 3, 4, 5)
    ]
    t0 = time.monotonic()
    _start_all(lt, host, [*prey, *hunters])

    # the allocation: every prey gets hunters, every hunter a prey (two each: ceil(4 / 2)); each
    # award is recorded with the true poses and the hunters free just before and just after it
    awards: list[tuple[str, str, dict[str, Position], set[str], set[str]]] = []
    before = {h.id: h.prey for h in hunters}

    def allocated() -> bool:
        poses = truth.poses()
        now = {h.id: h.prey for h in hunters}
        free_before = {k for k, v in before.items() if not v}
        free_after = {k for k, v in now.items() if not v}
        awards.extend((k, now[k], poses, free_before, free_after) for k in now if now[k] and not before[k])
        before.update(now)
        return all(now.values())

    wait_until(allocated, 30, "every hunter to be given a prey", interval=0.005)
    first = {h.id: h.prey for h in hunters}
    assert sorted(first.values()) == ["r0", "r0", "r1", "r1"], first
    # nearest first, on true distances at the award: the auctioneer (lowest id) takes its nearest
    # prey; every other award went to the hunter truly nearest the prey among those still free
    robot = {h.id: h.robot for h in hunters}

    def d(poses, a, b):
        return math.hypot(poses[a].x - poses[b].x, poses[a].y - poses[b].y)

    auctioneer = min(robot)
    for who, got, poses, free_before, free_after in awards:
        if who == auctioneer:
            nearest = min(d(poses, robot[who], p) for p in ("r0", "r1"))
            assert d(poses, robot[who], got) <= nearest + AWARD_SLACK, (who, got, poses)
            continue
        rivals = (free_before & free_after) - {who}
        for r in rivals:
            assert d(poses, robot[who], got) <= d(poses, robot[r], got) + AWARD_SLACK, (who, got, r, poses)
    print("awards (hunter, prey, true distance m):", [(w, g, round(d(p, robot[w], g), 1)) for w, g, p, _, _ in awards])

    wait_until(lambda: obs.caught() == {"r0", "r1"}, 240, "the hunters to catch both prey")
    print(f"both caught after {time.monotonic() - t0:.1f} s wall: {[o.text for _, o in obs.events('caught')]}")
    # every catch true: the catcher within its capture distance of the prey in the simulator
    for sender, o in obs.events("caught"):
        catcher = next(h for h in hunters if h.id == sender)
        at = obs.truth_at[(sender, "caught", o.subject)]
        d_true = d(at, catcher.robot, o.subject)
        assert d_true <= catcher.capture_distance + CATCH_SLACK, (sender, o.subject, d_true, at)
    wait_until(lambda: all(p.caught_by for p in prey), 10, "both prey to hear of their catch")
    # nobody chases a caught prey
    wait_until(lambda: all(not h.prey for h in hunters), 10, "every hunter to end its chase")
    assert all(set(h.caught) == {"r0", "r1"} for h in hunters)
    assert sim.alive()
