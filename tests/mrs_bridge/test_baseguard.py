"""The bases' command timeout and emergency stop, without a network: :class:`BaseGuard` on a fake
clock, and the ``sim`` driver inside a device server whose Zenoh session is an in-memory fake."""

from __future__ import annotations

import logging

import pytest

import mrs_bridge.drivers.sim  # noqa: F401  (registers the sim drivers)
from mrs_bridge import baseguard
from mrs_bridge.baseguard import BaseGuard, Latched
from mrs_bridge.config import ConfigError, parse_config
from mrs_bridge.driver import Deferred
from mrs_bridge.server import DeviceServer
from rsal.keys import parse_device
from rsal.msgs import ErrorCode, Position2dData, RpcError, VelocityCmd, decode_map
from rsal.testing import FakeServer, FakeSession
from tests.conftest import MAPS


@pytest.fixture(autouse=True)
def _fresh_timeout_lines(monkeypatch):
    """A timeout line of an earlier test's base must not hold this test's first one back."""
    monkeypatch.setattr(baseguard, "_TIMEOUTS", baseguard._TimeoutLines())


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_a_moving_command_expires_once_and_a_new_one_clears_the_flag(caplog):
    clock = Clock()
    g = BaseGuard("test.toml:1", "r0", 0.5, clock=clock)
    g.command(0.3, 0.0)
    clock.t += 0.4
    assert not g.expired() and not g.timed_out
    clock.t += 0.2
    with caplog.at_level(logging.WARNING):
        assert g.expired()
        assert [g.expired() for _ in range(5)] == [False] * 5  # once, not every cycle
    assert g.timed_out
    assert sum("no velocity command" in r.message for r in caplog.records) == 1
    g.command(0.0, 0.2)
    assert not g.timed_out


def test_the_timeouts_of_many_bases_within_a_second_are_one_line_for_all(caplog):
    clock = Clock()
    guards = [BaseGuard(f"crowd.world: sim r{i}", f"r{i}", 0.5, clock=clock) for i in range(300)]
    for g in guards:
        g.command(0.3, 0.0)
    clock.t += 0.6
    with caplog.at_level(logging.WARNING):
        assert all(g.expired() for g in guards)  # every base stops at once; the lines wait
        first = [r.getMessage() for r in caplog.records]
        baseguard._TIMEOUTS.flush()  # what the timer does at the second's end
        lines = [r.getMessage() for r in caplog.records]
    assert len(first) == 1 and first[0].startswith("crowd.world: sim r0: no velocity command for 0.60 s")
    assert len(lines) == 2, lines
    assert "299 more base(s) without a velocity command" in lines[1] and "r1..r299" in lines[1], lines[1]
    assert all(g.timed_out for g in guards)


def test_a_held_stop_never_times_out_and_zero_disables_the_timeout():
    clock = Clock()
    g = BaseGuard("t", "r0", 0.5, clock=clock)
    g.command(0.0, 0.0)
    clock.t += 10
    assert not g.expired() and not g.timed_out
    off = BaseGuard("t", "r0", 0.0, clock=clock)
    off.command(0.3, 0.0)
    clock.t += 100
    assert not off.expired()


def test_the_latch_refuses_commands_until_released():
    g = BaseGuard("t", "r0", 0.5)
    g.press()
    with pytest.raises(Latched, match="rsal estop r0 --release"):
        g.check()
    with pytest.raises(RpcError) as e:
        g.check(rpc=True)
    assert e.value.code == ErrorCode.ESTOP
    g.release()
    g.check()
    g.check(rpc=True)


@pytest.mark.parametrize("bad", ["-1", '"fast"', "true", "inf"])
def test_cmd_timeout_is_checked_at_start(bad):
    cfg = parse_config(
        f"""
[[driver]]
name = "x"
provides = ["r0:position2d:0"]
cmd_timeout = {bad}
""",
        source="robot.toml",
    )
    with pytest.raises(ConfigError, match=r"robot.toml.*cmd_timeout"):
        BaseGuard.timeout_param(cfg.drivers[0])


# ---------------------------------------------------------------------------- the sim driver
@pytest.fixture
def sim():
    text = f"""
[server]
node = "sim"

[[driver]]
name = "simulation"
provides = ["simulation:0"]
worldfile = "{MAPS / "testroom.world"}"
speedup = 0

[[driver]]
name = "sim"
model = "r0"
provides = ["r0:position2d:0"]
cmd_timeout = 0.5
"""
    session = FakeSession()  # keeps the last payload per key
    server = DeviceServer(parse_config(text, source="sim.toml"), session)
    server.start()
    simulation = next(s.driver for s in server.slots if s.driver.cfg.name == "simulation")
    robot = next(s.driver for s in server.slots if s.driver.cfg.name == "sim")
    clock = Clock()
    robot.guard.clock = clock
    yield simulation, robot, clock, session
    server.stop()
    server.close()


def _data(session) -> Position2dData:
    return Position2dData.from_dict(decode_map(session.last["rsal/r0/position2d/0/data"]))


def _step(simulation, n: int = 5) -> None:
    """``rpc/step`` run to its end, as the server runs it (a long step comes back as slices)."""
    res = simulation.on_rpc(parse_device("sim:simulation:0"), "step", {"n": n})
    while isinstance(res, Deferred):
        res = res.step() or res


def test_sim_base_stops_when_commands_stop_and_says_so(sim):
    simulation, robot, clock, session = sim
    addr = parse_device("r0:position2d:0")
    robot.on_cmd(addr, VelocityCmd(0.4, 0.0))
    _step(simulation, 10)
    assert robot.world.velocity("r0")[0] == pytest.approx(0.4, abs=0.05)
    clock.t += 0.4  # refreshed in time: keeps driving
    _step(simulation)
    assert robot.world.velocity("r0")[0] > 0.3 and not _data(session).timed_out
    clock.t += 0.2  # 0.6 s since the command: stopped before the next step
    _step(simulation)
    assert robot.world.velocity("r0") == pytest.approx((0.0, 0.0), abs=1e-6)
    assert _data(session).timed_out
    robot.on_cmd(addr, VelocityCmd(0.2, 0.0))  # the next command moves it again and clears the flag
    _step(simulation)
    d = _data(session)
    assert not d.timed_out and d.vel[0] > 0.1
    assert robot.on_rpc(addr, "stop", {}) == {}  # an acknowledged stop holds nothing to time out
    clock.t += 5
    _step(simulation)
    assert not _data(session).timed_out


def test_sim_base_emergency_stop_latches_until_released(sim):
    simulation, robot, clock, session = sim
    addr = parse_device("r0:position2d:0")
    robot.on_rpc(addr, "set_velocity", {"v": 0.4, "w": 0.0})
    _step(simulation)
    assert robot.on_rpc(addr, "estop", {}) == {"estop": True}
    _step(simulation)
    assert robot.world.velocity("r0") == pytest.approx((0.0, 0.0), abs=1e-6)
    assert _data(session).estop
    with pytest.raises(Latched):
        robot.on_cmd(addr, VelocityCmd(0.4, 0.0))
    with pytest.raises(RpcError) as e:
        robot.on_rpc(addr, "set_velocity", {"v": 0.4, "w": 0.0})
    assert e.value.code == "estop"
    _step(simulation)
    assert robot.world.velocity("r0") == pytest.approx((0.0, 0.0), abs=1e-6)
    assert robot.on_rpc(addr, "release", {}) == {"estop": False}
    robot.on_cmd(addr, VelocityCmd(0.4, 0.0))
    _step(simulation, 10)
    d = _data(session)
    assert not d.estop and d.vel[0] > 0.3


# ---------------------------------------------------------------------------- a local planner's output
@pytest.fixture
def planner():
    from mrs_bridge.drivers.localplanner import VFHDriver

    cfg = parse_config(
        """
[[driver]]
name = "vfh"
provides = ["r0:position2d:1"]
requires = ["r0:position2d:0", "r0:laser:0"]
cmd_timeout = 0.5
""",
        source="nav.toml",
    ).drivers[0]
    srv = FakeServer()
    drv = VFHDriver(cfg, srv)
    clock = Clock()
    drv.guard.clock = clock
    drv.setup()
    return drv, srv, clock


def _base_cmds(srv) -> list[tuple[float, float]]:
    return [(m.v, m.w) for a, m in srv.sent if a == "r0:position2d:0"]


def test_a_passed_through_velocity_times_out_at_the_planner(planner):
    drv, srv, clock = planner
    out = parse_device("r0:position2d:1")
    drv.on_cmd(out, {"v": 0.3, "w": 0.0})
    assert _base_cmds(srv) == [(0.3, 0.0)]
    clock.t += 0.4
    drv.update(clock.t)
    assert _base_cmds(srv) == [(0.3, 0.0)]  # not yet
    clock.t += 0.2
    drv.update(clock.t)
    drv.update(clock.t)
    assert _base_cmds(srv) == [(0.3, 0.0), (0.0, 0.0)]  # zero, once
    drv.on_input(parse_device("r0:position2d:0"), "data", Position2dData(1.0, (0, 0, 0), (0, 0, 0)).to_dict())
    assert srv.published[-1][1].timed_out
    drv.on_cmd(out, {"v": 0.2, "w": 0.0})
    drv.on_input(parse_device("r0:position2d:0"), "data", Position2dData(1.1, (0, 0, 0), (0, 0, 0)).to_dict())
    assert not srv.published[-1][1].timed_out


def test_the_planner_output_latches_presses_its_base_and_refuses_goals(planner):
    drv, srv, clock = planner
    out = parse_device("r0:position2d:1")
    drv.on_rpc(out, "goto", {"goal": [2.0, 0.0, 0.0]})
    assert drv.on_rpc(out, "estop", {}) == {"estop": True}
    assert ("r0:position2d:0", "estop") in srv.requested()
    assert _base_cmds(srv)[-1] == (0.0, 0.0) and drv.planner.goal is None
    with pytest.raises(Latched):
        drv.on_cmd(out, {"goal": [2.0, 0.0, 0.0]})
    with pytest.raises(Latched):
        drv.on_cmd(out, {"v": 0.2, "w": 0.0})
    with pytest.raises(RpcError) as e:
        drv.on_rpc(out, "goto", {"goal": [2.0, 0.0, 0.0]})
    assert e.value.code == "estop"
    n = len(srv.sent)
    drv.on_input(parse_device("r0:position2d:0"), "data", Position2dData(1.0, (0, 0, 0), (0, 0, 0)).to_dict())
    assert len(srv.sent) == n and srv.published[-1][1].estop  # nothing commanded while latched
    drv.on_rpc(out, "release", {})
    drv.on_rpc(out, "goto", {"goal": [2.0, 0.0, 0.0]})
    assert drv.planner.goal is not None
