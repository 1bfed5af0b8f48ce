"""Mixed reality (thesis 4.2.1, 4.3): the ViewAgent, the ``virtual_ranger`` driver and Hunt and Prey
across a "real" and a virtual simulator.

Unit tests: :func:`merge_discs` against a beam-by-beam reference and hand-made cases; the
``virtual_ranger`` driver against an in-memory fake server (polls, merge, geometry); the ViewAgent's
``set_pose`` calls against a fake simulation (filter, frame, one call in flight, retry); ``rsal sim
--node``'s configuration. Integration: for each direction, a second simulator on node ``real``
stands in for reality and ``rsal run deploy/scenarios/mixed_hunt.yaml --app ... --connect EP`` runs
the virtual world and the agents on the same fabric. The prey must be caught, and while hunter and
prey are near each other the real robot's merged laser (``laser:1``) must show the virtual robot at
the range its true pose gives -- where the real laser shows nothing -- and the virtual robot's laser
must show the real robot's proxy. Last, the real prey's own obstacle avoidance steers around a
virtual robot parked in its way.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from concurrent.futures import Future

import numpy as np
import pytest

from agents.registry import resolve
from agents.runtime import AgentHost
from agents.scenario import load_scenario
from agents.scenarios.hunt import EscapeAgent
from agents.scenarios.mixed import ViewAgent
from agents.services import Message, SendPosition
from mrs_bridge.cli import sim_config
from mrs_bridge.config import ConfigError, parse_config
from mrs_bridge.drivers.virtual_ranger import VirtualRanger, merge_discs
from rsal.data import Position
from rsal.msgs import ErrorCode, Position2dData, RangerData, RpcError
from rsal.robot import Robot
from rsal.testing import FakeServer
from rsal.transport import TransportArgs, open_session
from simulator.loader import load_world
from simulator.world import World
from tests.conftest import MAPS, ROOT, free_port, rsal_cmd, wait_until

PIONEER_RADIUS = 0.22  # m: a Pioneer 2DX as the simulator's rangers see it
LASER_X = 0.13  # m: laser240's mount ahead of the robot's centre in the mixed worlds


# ---------------------------------------------------------------------------- merge_discs
def _reference(ranges, origins, bearings, pose, centres, radius, range_min=0.0):
    """Beam by beam, disc by disc, in the world frame: the merge as a person would do it."""
    x, y, a = pose
    out = []
    for r, (ox, oy), b in zip(ranges, origins, bearings, strict=True):
        wx, wy = x + math.cos(a) * ox - math.sin(a) * oy, y + math.sin(a) * ox + math.cos(a) * oy
        dx, dy = math.cos(a + b), math.sin(a + b)
        best = float(r)
        for cx, cy in centres:
            fx, fy = cx - wx, cy - wy
            if fx * fx + fy * fy <= radius * radius:
                best = min(best, range_min)
                continue
            tc = fx * dx + fy * dy
            h = radius * radius - (fx * fx + fy * fy - tc * tc)
            if h >= 0 and tc - math.sqrt(h) >= 0:
                best = min(best, tc - math.sqrt(h))
        out.append(best)
    return np.array(out)


def test_merge_discs_matches_a_beam_by_beam_reference():
    rng = np.random.default_rng(7)
    n = 181
    bearings = np.linspace(-2.0, 2.0, n)
    origins = np.tile([0.13, 0.0], (n, 1))
    for _ in range(20):
        pose = (rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-math.pi, math.pi))
        centres = rng.uniform(-6, 6, (4, 2))
        ranges = rng.uniform(0.5, 8.0, n).astype(np.float32)
        got = merge_discs(ranges, origins, bearings, pose, centres, 0.3, 0.02)
        want = _reference(ranges, origins, bearings, pose, centres, 0.3, 0.02)
        assert got.dtype == np.float32 and got.shape == (n,)
        np.testing.assert_allclose(got, want, atol=1e-5)
        assert np.all(got <= ranges)


def test_merge_discs_hand_made_cases():
    bearings = np.array([0.0, math.pi / 2, math.pi, -0.3])
    origins = np.zeros((4, 2))
    ranges = np.full(4, 5.0)
    # robot at (1, 1) facing +y: beam 0 points +y, beam 1 points -x, beam 2 -y
    pose = (1.0, 1.0, math.pi / 2)
    got = merge_discs(ranges, origins, bearings, pose, np.array([[1.0, 3.0]]), 0.25)
    assert got[0] == pytest.approx(2.0 - 0.25)  # straight at the disc
    assert got[1] == 5.0 and got[2] == 5.0  # sideways and behind: no hit
    assert got[3] == 5.0  # 0.3 rad off: passes 0.59 m beside the centre
    # a real reading nearer than the disc is kept
    near = merge_discs(np.array([1.0, 5.0, 5.0, 5.0]), origins, bearings, pose, np.array([[1.0, 3.0]]), 0.25)
    assert near[0] == 1.0
    # the beam's origin inside a disc reads range_min; no discs: unchanged copy
    inside = merge_discs(ranges, origins, bearings, pose, np.array([[1.1, 1.0]]), 0.25, range_min=0.02)
    assert np.all(inside == 0.02)
    same = merge_discs(ranges, origins, bearings, pose, np.zeros((0, 2)), 0.25)
    assert np.array_equal(same, ranges) and same is not ranges
    # an invalid (NaN) reading takes the disc's range; a disc out of every beam's reach changes nothing
    nan = merge_discs(np.array([np.nan, 5.0, 5.0, 5.0]), origins, bearings, pose, np.array([[1.0, 3.0]]), 0.25)
    assert (
        nan[0] == pytest.approx(1.75)
        and np.isnan(merge_discs(np.full(4, np.nan), origins, bearings, pose, [[9, 9]], 0.2)).all()
    )
    far = merge_discs(ranges, origins, bearings, pose, np.array([[1.0, 7.0], [1.0, 2.0]]), 0.25)
    assert far[0] == pytest.approx(0.75)


# ---------------------------------------------------------------------------- the driver
DRIVER = """
[[driver]]
name = "virtual_ranger"
provides = ["r0:laser:1"]
requires = ["r0:laser:0", "r0:position2d:0"]
simulation = "sim:simulation:0"
radius = 0.25
"""

LASER_GEOMETRY = {
    "kind": "laser",
    "pose": [0.13, 0.0, 0.0],
    "sensors": [{"pose": [0.0, 0.0, 0.0], "fov": math.pi, "samples": 181, "range_min": 0.02, "range_max": 5.6}],
}


def _scan(t: float = 1.0) -> dict:
    return RangerData(t, np.full(181, 5.6, np.float32), -math.pi / 2, math.pi / 180, 0.02, 5.6).to_dict()


def test_virtual_ranger_polls_the_virtual_robots_and_merges_them_into_the_scan():
    cfg = parse_config(DRIVER, source="vr.toml").drivers[0]
    srv = FakeServer()
    drv = VirtualRanger(cfg, srv)
    laser, pos = cfg.requires
    sim = drv.sim
    drv.setup()
    assert srv.requests == [("r0:laser:0", "describe", None)]
    with pytest.raises(RpcError) as e:  # no beamless description before the source's geometry is known
        drv.geometry(cfg.provides[0])
    assert e.value.code == ErrorCode.UNAVAILABLE

    # before geometry and pose are known, scans pass through
    drv.on_input(laser, "data", _scan())
    assert srv.published[-1][0] == "r0:laser:1" and np.all(srv.published[-1][1].ranges == 5.6)

    drv.on_reply(laser, "describe", {"geometry": LASER_GEOMETRY}, None)
    drv.update(0.0)
    assert srv.requests[-1] == ("sim:simulation:0", "models", None)
    # r0 is this robot's own proxy in the virtual world: excluded by default
    drv.on_reply(sim, "models", {"robots": ["r1", "r2"], "objects": ["r0", "puck"]}, None)
    drv.update(0.1)
    polls = [a["name"] for s, op, a in srv.requests if op == "get_pose"]
    assert polls == ["r1", "r2"]
    drv.update(0.2)  # the round is not answered yet: no second round
    assert len([r for r in srv.requests if r[1] == "get_pose"]) == 2
    drv.on_reply(sim, "get_pose", {"name": "r1", "pose": [3.0, 0.0, 1.0]}, None)
    drv.on_reply(sim, "get_pose", None, RpcError(ErrorCode.TIMEOUT, "no reply"))
    drv.update(0.3)  # both answered (one failed): the next round goes out
    assert len([r for r in srv.requests if r[1] == "get_pose"]) == 4

    drv.on_input(pos, "data", Position2dData(1.0, (0.0, 0.0, 0.0), (0, 0, 0)).to_dict())
    drv.on_input(laser, "data", _scan(2.0))
    out = srv.published[-1][1]
    assert out.ranges.dtype == np.float32 and out.t == 2.0
    # beam 90 points straight ahead from x = 0.13: the disc of r1 at x = 3 starts at 3 - 0.25
    assert out.ranges[90] == pytest.approx(3.0 - 0.13 - 0.25, abs=1e-4)
    assert np.sum(out.ranges < 5.6) >= 5 and out.ranges[0] == pytest.approx(5.6)
    assert drv.merged == 1
    g = drv.geometry(cfg.provides[0])
    assert g["sensors"] == LASER_GEOMETRY["sensors"] and g["virtual"] == ["r1"] and g["source"] == "r0:laser:0"

    # a stale virtual pose is no longer merged
    drv.virtual["r1"] = (drv.virtual["r1"][0], time.monotonic() - 5.0)
    drv.on_input(laser, "data", _scan(3.0))
    assert np.all(srv.published[-1][1].ranges == pytest.approx(5.6))

    # the virtual world goes away: nothing more to poll until it answers models again
    drv._next_models = 0.0
    drv.update(0.4)
    assert srv.requests[-1][1] == "models"
    drv.on_reply(sim, "models", None, RpcError(ErrorCode.TIMEOUT, "no reply"))
    assert drv.names == []
    n = len(srv.requests)
    drv._outstanding = 0
    drv.update(0.5)
    assert len(srv.requests) == n


def test_virtual_ranger_config_errors_are_one_clear_line():
    with pytest.raises(ConfigError, match="requires the real robot's laser"):
        VirtualRanger(parse_config(DRIVER.replace(', "r0:position2d:0"', ""), source="vr.toml").drivers[0], None)
    with pytest.raises(ConfigError, match="radius"):
        VirtualRanger(parse_config(DRIVER.replace("0.25", "-1"), source="vr.toml").drivers[0], None)
    with pytest.raises(ConfigError, match="exclude"):
        VirtualRanger(parse_config(DRIVER + "exclude = [1]\n", source="vr.toml").drivers[0], None)
    with pytest.raises(ConfigError, match="must be a simulation device"):
        VirtualRanger(parse_config(DRIVER.replace("sim:simulation:0", "sim:map:0"), source="vr.toml").drivers[0], None)
    # the simulation may be required instead (then the server waits for it)
    required = DRIVER.replace('"r0:position2d:0"]', '"r0:position2d:0", "v:simulation:0"]')
    assert str(VirtualRanger(parse_config(required, source="vr.toml").drivers[0], None).sim) == "v:simulation:0"


# ---------------------------------------------------------------------------- the ViewAgent
class FakeSimulation:
    """Answers set_pose calls by hand: each call's future stays open until resolved."""

    def __init__(self):
        self.calls: list[tuple[str, dict, Future]] = []

    def rpc(self, op, args=None, timeout=2.0) -> Future:
        f: Future = Future()
        self.calls.append((op, args, f))
        return f


def _position(agent: ViewAgent, robot: str, x: float, y: float, yaw: float = 0.0, frame: str = "map") -> None:
    agent._on_position(Message("send_position", f"agent-{robot}", "c", 0.0, SendPosition(robot, x, y, yaw, frame)))


def test_view_agent_mirrors_only_the_real_robots_map_poses_onto_their_proxies():
    agent = ViewAgent("view", robots=["r0", "r5"], proxies={"r5": "ghost5"})
    sim = FakeSimulation()
    agent.rpc = sim.rpc
    step = lambda: asyncio.run(agent.step())  # noqa: E731

    _position(agent, "r1", 1.0, 2.0)  # a virtual robot: not mirrored
    _position(agent, "r0", 9.0, 9.0, frame="odom")  # not in the map frame: not mirrored
    step()
    assert sim.calls == []

    _position(agent, "r0", 1.0, 2.0, 0.5)
    _position(agent, "r5", -1.0, 0.0)
    step()
    assert [(op, a["name"], a["pose"]) for op, a, _ in sim.calls] == [
        ("set_pose", "r0", [1.0, 2.0, 0.5]),
        ("set_pose", "ghost5", [-1.0, 0.0, 0.0]),
    ]
    # a call in flight: the next pose waits for its answer, then goes out (the latest one only)
    _position(agent, "r0", 1.1, 2.0, 0.5)
    _position(agent, "r0", 1.2, 2.0, 0.5)
    step()
    assert len(sim.calls) == 2
    sim.calls[0][2].set_result({"name": "r0", "pose": [1.0, 2.0, 0.5]})
    sim.calls[1][2].set_result({})
    step()
    assert len(sim.calls) == 3 and sim.calls[2][1] == {"name": "r0", "pose": [1.2, 2.0, 0.5]}
    assert agent.updates == {"r0": 1, "r5": 1}
    # an unchanged pose is not sent again; a failed call is retried with the latest pose
    sim.calls[2][2].set_exception(RpcError(ErrorCode.TIMEOUT, "no reply"))
    step()
    assert len(sim.calls) == 4 and sim.calls[3][1]["pose"] == [1.2, 2.0, 0.5] and agent.errors == 1
    sim.calls[3][2].set_result({})
    step()
    step()
    assert len(sim.calls) == 4 and agent.updates["r0"] == 2
    assert "r0->r0 (1.20, 2.00, 29 deg) x2" in agent.status() and "ghost5" in agent.status()


def test_view_agent_arguments_are_checked():
    assert resolve("ViewAgent") is ViewAgent
    for kw, what in [
        ({}, "robots"),
        ({"robots": "r0", "proxies": {"r9": "x"}}, "not in robots"),
        ({"robots": ["r0"], "simulation": "sim:map:0"}, "simulation device"),
        ({"robots": ["r0"], "simulation": "a/b"}, "device address"),
        ({"robots": ["r0"], "rate": 0}, "rate"),
    ]:
        with pytest.raises(ValueError, match=what):
            ViewAgent("view", **kw)
    with pytest.raises(TypeError):
        ViewAgent("view", robots=["r0"], speed=1.0)


class FakeFabric:
    def __init__(self, models):
        self.models = models

    def node(self, *templates):
        return self

    def wait_for(self, template, n, timeout):
        return [template]

    def rpc_async(self, addr, op, args=None, *, timeout=5.0):
        f: Future = Future()
        f.set_result(self.models)
        return f


def test_view_agent_names_a_missing_proxy_with_a_fix():
    agent = ViewAgent("view", robots=["r0", "r7"])
    agent.fabric = FakeFabric({"robots": ["r1"], "objects": ["r0"]})
    with pytest.raises(ValueError, match=r"has no model r7 to mirror a real robot into; add a plain model"):
        agent._check_world()
    agent.fabric = FakeFabric({"robots": ["r1", "r7"], "objects": ["r0"]})
    agent._check_world()  # a robot as a proxy: allowed (warned)


# ---------------------------------------------------------------------------- rsal sim --node
def test_sim_node_names_the_simulation_and_map_devices():
    world = World(load_world(str(MAPS / "mixed_real_hunter.world")))
    cfg = sim_config(world, node="real", nav="vfh")
    provided = {str(a) for d in cfg.drivers for a in d.provides}
    assert {"real:simulation:0", "real:map:0", "r1:laser:0", "r1:planner:0"} <= provided
    assert not any(p.startswith("sim:") for p in provided)
    required = {str(r.without_key()) for d in cfg.drivers for r in d.requires}
    assert "real:map:0" in required and "sim:map:0" not in required
    assert cfg.node == "real"
    default = {str(a) for d in sim_config(world).drivers for a in d.provides}
    assert {"sim:simulation:0", "sim:map:0"} <= default


def test_scenario_file_parses_and_its_worlds_load():
    sc = load_scenario(ROOT / "deploy/scenarios/mixed_hunt.yaml")
    assert set(sc.applications) == {"real_prey", "real_hunter"}
    for app in sc.applications.values():
        assert {a.cls for a in app.agents} >= {"EscapeAgent", "FollowAgent", "ViewAgent"}
        w = World(load_world(str(app.simulator.world)))
        view = next(a for a in app.agents if a.cls == "ViewAgent")
        for r in view.args["robots"]:
            assert r in w.model_names and r not in w.robot_names, f"{r}: the proxy is a plain model"


# ---------------------------------------------------------------------------- integration
class Sampler(threading.Thread):
    """While the hunt runs: with every merged scan of the real robot, the true poses of both robots
    (each simulator's ``get_pose``), the real and merged scans, the virtual robot's own scan and the
    proxy's pose in the virtual world."""

    def __init__(self, fabric, node, real: str, virtual: str):
        super().__init__(daemon=True)
        self.real, self.virtual = real, virtual
        self.merged = fabric.device(f"{real}:laser:1")
        self.raw = fabric.device(f"{real}:laser:0")
        self.vscan = fabric.device(f"{virtual}:laser:0")
        self.real_sim = fabric.device("real:simulation:0")
        self.virt_sim = fabric.device("sim:simulation:0")
        # the robot as an agent builds it from its node's devices: it picks up the merged laser too
        self.robot = Robot([fabric.device(a) for a in node.search(node=real)], name=real)
        self.samples: list[dict] = []
        self.stop = threading.Event()

    def run(self) -> None:
        n = 0
        while not self.stop.is_set():
            try:
                self.merged.wait_for_data(1.0, newer_than=n)
                n = self.merged.count
                merged, raw, vscan = self.merged.latest, self.raw.latest, self.vscan.latest
                real = self.real_sim.get_pose(self.real)
                virt = self.virt_sim.get_pose(self.virtual)
                proxy = self.virt_sim.get_pose(self.real)
            except (TimeoutError, RpcError):
                continue
            pts = self.robot.obstacle_points()
            pts = np.concatenate(pts) if pts else np.zeros((0, 2))
            self.samples.append(dict(merged=merged, raw=raw, vscan=vscan, real=real, virt=virt, proxy=proxy, pts=pts))


def _beam_to(scan: RangerData, me, other) -> tuple[int, float] | None:
    """The beam of ``scan`` (laser 0.13 m ahead of pose ``me``) towards the disc around ``other``'s
    centre, and the range it should read; None when outside the field of view."""
    lx, ly = me.x + LASER_X * math.cos(me.yaw), me.y + LASER_X * math.sin(me.yaw)
    bearing = math.remainder(math.atan2(other.y - ly, other.x - lx) - me.yaw, math.tau)
    i = round((bearing - scan.angle_min) / scan.angle_step)
    if not 0 <= i < scan.ranges.shape[0]:
        return None
    return i, math.hypot(other.x - lx, other.y - ly) - PIONEER_RADIUS


def _shows(scan: RangerData, me, other, tol: float = 0.3) -> bool | None:
    b = _beam_to(scan, me, other)
    if b is None:
        return None
    i, want = b
    near = scan.ranges[max(0, i - 2) : i + 3]
    return bool(np.min(np.abs(near - want)) < tol)


def _run_mixed(procs, real_world: str, real_config: str, app: str, real: str, virtual: str, devices: set[str]):
    """The real side first (its simulator on node ``real`` and the real robot's server), then
    ``rsal run --app APP --connect EP``; returns the sampler's samples and the run's duration."""
    from rsal.client import Fabric

    ep = f"tcp/127.0.0.1:{free_port()}"
    real_sim = procs(rsal_cmd("sim", str(MAPS / real_world), "--node", "real", "--listen", ep))
    fabric = Fabric.connect(TransportArgs(connect=[ep]))
    try:
        serve = procs(rsal_cmd("serve", f"deploy/scenarios/{real_config}", "--connect", ep))
        node = fabric.node(f"{real}:*:*", "real:*:*")
        wait_until(
            lambda: devices <= {str(a) for a in node.search()} or not (real_sim.alive() and serve.alive()),
            90,
            f"the real side's devices {', '.join(sorted(devices))}",
            interval=0.2,
        )
        assert real_sim.alive() and serve.alive(), real_sim.output()[-2000:] + serve.output()[-2000:]
        sampler = Sampler(fabric, node, real, virtual)
        sampler.start()
        t0 = time.monotonic()
        run = procs(rsal_cmd("run", "deploy/scenarios/mixed_hunt.yaml", "--app", app, "--connect", ep))
        wait_until(lambda: not run.alive(), 200, "rsal run to end", interval=0.5)
        took = time.monotonic() - t0
        sampler.stop.set()
        sampler.join(5)
        out = run.output()
        assert run.p.returncode == 0, out[-3000:]
        assert "[run] result: ok — prey r0 caught by r1 after " in out, out[-3000:]
        assert "outcomes: caught 1" in out, out[-3000:]
        # the real side outlives the run; without the virtual world the merged scan is the real one again
        assert real_sim.alive() and serve.alive()
        merged, raw = fabric.device(f"{real}:laser:1"), fabric.device(f"{real}:laser:0")

        def same_again():
            m, r = merged.latest, raw.latest
            return m is not None and r is not None and m.t == r.t and np.array_equal(m.ranges, r.ranges)

        wait_until(same_again, 30, f"{real}:laser:1 to equal {real}:laser:0 once the virtual world is gone")
        assert "virtual robots of sim:simulation:0: " in serve.output(), serve.output()[-2000:]
        return sampler.samples, took
    finally:
        fabric.close()


def _gap(pts: np.ndarray, me, other) -> float:
    """Distance from ``other``'s centre to the nearest obstacle point (robot frame of ``me``)."""
    if pts.shape[0] == 0:
        return math.inf
    dx, dy = other.x - me.x, other.y - me.y
    c, s = math.cos(me.yaw), math.sin(me.yaw)
    ox, oy = c * dx + s * dy, -s * dx + c * dy
    return float(np.min(np.hypot(pts[:, 0] - ox, pts[:, 1] - oy)))


def _check_mixed(samples: list[dict], real: str, virtual: str) -> str:
    near = [s for s in samples if math.hypot(s["real"].x - s["virt"].x, s["real"].y - s["virt"].y) < 3.0]
    assert near, f"no merged scan while {real} and {virtual} were within 3 m ({len(samples)} samples)"
    # real senses virtual: the merged scan shows the virtual robot where the real scan shows nothing
    seen = [_shows(s["merged"], s["real"], s["virt"]) for s in near]
    raw_seen = [_shows(s["raw"], s["real"], s["virt"]) for s in near]
    in_view = [i for i, v in enumerate(seen) if v is not None]
    assert in_view, f"{virtual} never in the field of view of {real}'s laser"
    hits = [i for i in in_view if seen[i]]
    assert len(hits) >= max(1, len(in_view) // 2), (
        f"{real}'s merged scan showed {virtual} in {len(hits)}/{len(in_view)}"
    )
    assert not any(raw_seen[i] for i in hits), f"{real}'s real laser saw the virtual {virtual}"
    # ... and so do the obstacle points the robot's behaviours work on (thesis 3.6.2.4)
    gaps = [_gap(near[i]["pts"], near[i]["real"], near[i]["virt"]) for i in in_view]
    close = sum(g < PIONEER_RADIUS + 0.3 for g in gaps)
    assert close >= max(1, len(gaps) // 2), f"{real}'s obstacle points near {virtual} in {close}/{len(gaps)}"
    # virtual senses real: the proxy follows the real robot, and the virtual laser sees it
    lag = [math.hypot(s["proxy"].x - s["real"].x, s["proxy"].y - s["real"].y) for s in samples]
    assert np.median(lag) < 0.3, f"the proxy of {real} lags its true pose by {np.median(lag):.2f} m (median)"
    vseen = [_shows(s["vscan"], s["virt"], s["real"]) for s in near if s["vscan"] is not None]
    vin = [v for v in vseen if v is not None]
    assert vin and sum(vin) >= max(1, len(vin) // 2), (
        f"{virtual}'s laser showed {real}'s proxy in {sum(vin)}/{len(vin)}"
    )
    return (
        f"{len(samples)} samples, {len(near)} within 3 m: merged scan showed {virtual} in {len(hits)}/{len(in_view)}, "
        f"obstacle points near {virtual} in {close}/{len(gaps)}, virtual laser showed {real} in {sum(vin)}/{len(vin)}, "
        f"proxy lag median {np.median(lag):.3f} m"
    )


@pytest.mark.timeout(240)
def test_virtual_hunter_catches_the_real_prey_and_the_prey_sees_it(procs):
    samples, took = _run_mixed(
        procs, "mixed_real_prey.world", "mixed_real_prey.toml", "real_prey", "r0", "r1", {"r0:laser:1"}
    )
    print(f"real prey: rsal run {took:.1f} s; {_check_mixed(samples, 'r0', 'r1')}")


@pytest.mark.timeout(240)
def test_real_hunter_catches_the_virtual_prey_and_sees_it(procs):
    samples, took = _run_mixed(
        procs,
        "mixed_real_hunter.world",
        "mixed_real_hunter.toml",
        "real_hunter",
        "r1",
        "r0",
        {"r1:laser:1", "r1:planner:0"},
    )
    print(f"real hunter: rsal run {took:.1f} s; {_check_mixed(samples, 'r1', 'r0')}")


@pytest.mark.timeout(180)
def test_the_real_prey_steers_around_a_virtual_robot_in_its_way(procs):
    """The prey's own obstacle avoidance (thesis 3.6.2.4) works on the merged laser: a parked
    virtual robot on its path is avoided, not driven through (without virtual_ranger the prey
    passes within 0.05 m of its centre: nothing real is there)."""
    from rsal.client import Fabric

    ob = (-0.9, 1.15)  # on the prey's way from its start towards the corridor's south wall
    ep = f"tcp/127.0.0.1:{free_port()}"
    procs(rsal_cmd("sim", str(MAPS / "mixed_real_prey.world"), "--node", "real", "--listen", ep))
    procs(rsal_cmd("sim", str(MAPS / "mixed_virtual_hunter.world"), "--connect", ep))
    procs(rsal_cmd("serve", "deploy/scenarios/mixed_real_prey.toml", "--connect", ep))
    fabric = Fabric.connect(TransportArgs(connect=[ep]))
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()

    def run(coro, timeout: float = 90.0):
        return asyncio.run_coroutine_threadsafe(coro, loop).result(timeout)

    session = host = None
    try:
        node = fabric.node("**")
        for dev in ("real:simulation:0", "sim:simulation:0", "r0:laser:1"):
            node.wait_for(dev, 1, 60)
        real_sim, virt_sim = fabric.device("real:simulation:0"), fabric.device("sim:simulation:0")
        virt_sim.set_pose("r1", Position(ob[0], ob[1], math.pi))  # nobody drives r1: it stays parked
        session = open_session(TransportArgs(connect=[ep]))
        host = AgentHost(session)
        run(host.__aenter__())
        prey = EscapeAgent("prey0", robot="r0", speed=0.2, pose=[-2.0, 1.75, 0], startup_timeout=60)
        run(host.start(prey))
        assert {str(d.addr) for d in prey.pioneer.lasers} == {"r0:laser:0", "r0:laser:1"}
        states: list[str] = []  # the behaviour's states on the way (wall-following alone may steer around)
        prey.pioneer.on_state(states.append)
        closest = [math.inf]

        def past() -> bool:
            p = real_sim.get_pose("r0")
            closest[0] = min(closest[0], math.hypot(p.x - ob[0], p.y - ob[1]))
            return p.x > ob[0] + 0.4

        wait_until(past, 90, "the real prey to get past the virtual robot", interval=0.1)
        print(f"closest approach to the virtual robot's centre {closest[0]:.2f} m; states {states}")
        assert closest[0] > 0.4, f"the prey came within {closest[0]:.2f} m of the virtual robot's centre"
    finally:
        if host is not None:
            run(host.stop())
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
        if session is not None:
            session.close()
        fabric.close()
