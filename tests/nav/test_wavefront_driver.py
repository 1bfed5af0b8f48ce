"""The ``wavefront`` driver against an in-memory fake server: goals, hand-over and rejected goals.

The driver is fed what the fabric would give it (the map's ``rpc/get`` reply, the local planner's
``rpc/describe``, localized and odometry poses) and the test reads what it sends, publishes and
announces. Map: a 6 m x 4 m room (0.1 m cells) with walls on its border and origin (0, 0).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrs_bridge.config import parse_config
from mrs_bridge.drivers.wavefront import WavefrontDriver
from rsal.msgs import ErrorCode, MapData, Position2dData, RpcError, VelocityCmd
from rsal.testing import FakeServer

CONFIG = """
[[driver]]
name = "wavefront"
provides = ["r0:planner:0"]
requires = ["output::r0:position2d:1", "input::r0:position2d:2", "r0:map:0"]
safety_dist = 0.1
distance_epsilon = 0.4
angle_epsilon = 10
"""


def room() -> dict:
    cells = np.full((40, 60), -1, dtype=np.int8)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 1
    return MapData(60, 40, 0.1, (0.0, 0.0), cells).to_dict()


@pytest.fixture
def driver():
    cfg = parse_config(CONFIG, source="wavefront.toml").drivers[0]
    srv = FakeServer()
    drv = WavefrontDriver(cfg, srv)
    drv.setup()
    assert ("r0:map:0", "get") in srv.requested() and ("r0:position2d:1", "describe") in srv.requested()
    addr = cfg.requires[0]
    drv.on_reply(cfg.requires[2], "get", room(), None)
    drv.on_reply(addr, "describe", {"geometry": {"robot_radius": 0.25, "frame": "odom"}}, None)
    assert drv.exec is not None
    # localized pose (map) and odometry: odometry is the map shifted by (-1, -1)
    drv.on_input(cfg.requires[1], "data", Position2dData(1.0, (1.0, 1.0, 0.0), (0, 0, 0)).to_dict())
    drv.on_input(cfg.requires[0], "data", Position2dData(1.0, (0.0, 0.0, 0.0), (0, 0, 0)).to_dict())
    return drv, srv


def goals(srv) -> list[tuple[float, float, float]]:
    return [tuple(m["goal"]) for a, m in srv.sent if a == "r0:position2d:1" and isinstance(m, dict)]


def test_a_goal_is_handed_over_in_the_odometry_frame(driver):
    drv, srv = driver
    r = drv.on_rpc(drv.cfg.provides[0], "set_goal", {"goal": [5.0, 3.0, math.pi / 2]})
    assert r["goal_id"] == 1 and r["waypoints"] >= 2 and r["length"] > 0
    # the straight line is free: the one target is the goal, moved into the odometry frame
    x, y, yaw = goals(srv)[-1]
    assert (x, y, yaw) == pytest.approx((4.0, 2.0, math.pi / 2))
    assert srv.published[-1][1].status == "driving"


def test_an_invalid_goal_while_driving_changes_nothing(driver):
    drv, srv = driver
    drv.on_rpc(drv.cfg.provides[0], "set_goal", {"goal": [5.0, 3.0, 0.0]})
    sent = len(srv.sent)
    with pytest.raises(RpcError) as e:
        drv.on_rpc(drv.cfg.provides[0], "set_goal", {"goal": [50.0, 3.0, 0.0]})
    assert e.value.code == ErrorCode.NOT_FOUND and "outside the map" in e.value.message
    # no stop, no event: the first goal goes on and is still handed over
    assert not any(isinstance(m, VelocityCmd) for _, m in srv.sent[sent:]) and srv.events == []
    drv.update(1e9)
    assert srv.published[-1][1].status == "driving" and srv.published[-1][1].goal == (5.0, 3.0, 0.0)
    assert drv.on_rpc(drv.cfg.provides[0], "waypoints", {})["waypoints"]


def test_an_invalid_goal_when_idle_is_reported_invalid(driver):
    drv, srv = driver
    with pytest.raises(RpcError) as e:
        drv.on_rpc(drv.cfg.provides[0], "set_goal", {"goal": [0.05, 0.05, 0.0]})
    assert e.value.code == ErrorCode.NOT_FOUND and e.value.message.startswith("invalid goal: goal (0.05, 0.05)")
    drv.update(1.0)
    last = srv.published[-1][1]
    assert last.status == "invalid" and "obstacle" in last.message
    assert drv.on_rpc(drv.cfg.provides[0], "waypoints", {}) == {"waypoints": []}


def test_every_goal_ends_with_one_event(driver):
    """A goal replaced by another (from any client) ends as aborted, so no waiter waits for ever."""
    drv, srv = driver
    planner = drv.cfg.provides[0]
    assert drv.on_rpc(planner, "set_goal", {"goal": [5.0, 3.0, 0.0]})["goal_id"] == 1
    assert drv.on_rpc(planner, "set_goal", {"goal": [5.0, 1.0, 0.0]})["goal_id"] == 2
    assert srv.events == [{"event": "aborted", "goal_id": 1, "message": "superseded by goal 2"}]
    # the second goal is reached: done, once
    drv.on_input(drv.cfg.requires[1], "data", Position2dData(2.0, (5.0, 1.0, 0.0), (0, 0, 0)).to_dict())
    drv.update(1e9)
    drv.update(1e9 + 1)
    assert srv.events[1:] == [{"event": "done", "goal_id": 2, "message": ""}]
    assert isinstance(srv.sent[-1][1], VelocityCmd)  # the local planner's goal is cancelled
    # a goal set after a done goal supersedes nothing
    drv.on_rpc(planner, "set_goal", {"goal": [1.0, 1.0, 0.0]})
    assert len(srv.events) == 2


def test_plan_answers_a_path_without_driving_it(driver):
    drv, srv = driver
    planner = drv.cfg.provides[0]
    drv.on_rpc(planner, "set_goal", {"goal": [5.0, 3.0, 0.0]})
    sent, driving = len(srv.sent), drv.exec.plan
    r = drv.on_rpc(planner, "plan", {"start": [1.0, 3.0], "goal": [5.0, 1.0]})
    assert r["length"] == pytest.approx(math.hypot(4.0, 2.0), rel=1e-6) and r["waypoints"][0] == [1.0, 3.0]
    assert drv.on_rpc(planner, "plan", {"goal": [5.0, 1.0]})["waypoints"][0] == [1.0, 1.0]  # from the pose
    # the goal being driven is untouched: same plan, nothing sent, still driving
    assert drv.exec.plan is driving and len(srv.sent) == sent and drv.exec.status == "driving"
    with pytest.raises(RpcError) as e:
        drv.on_rpc(planner, "plan", {"start": [1.0, 1.0], "goal": [50.0, 1.0]})
    assert e.value.code == ErrorCode.NOT_FOUND and "outside the map" in e.value.message
    assert "plan" in drv.ops(planner)


def test_plan_before_the_map_is_unavailable():
    cfg = parse_config(CONFIG, source="wavefront.toml").drivers[0]
    drv = WavefrontDriver(cfg, FakeServer())
    drv.setup()
    with pytest.raises(RpcError) as e:
        drv.on_rpc(cfg.provides[0], "plan", {"start": [1.0, 1.0], "goal": [2.0, 1.0]})
    assert e.value.code == ErrorCode.UNAVAILABLE and "no map yet" in e.value.message
