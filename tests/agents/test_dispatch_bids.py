"""Bids costed by the robot's planner (:class:`agents.dispatch.bidder.PathTravel`): a goal behind a
wall is costed by the planner's path around it, not the straight line; no path is no bid; a
planner that cannot plan without driving makes straight-line bids, said once.

The planner is the real ``wavefront`` driver fed a map in memory (:class:`rsal.testing.FakeServer`),
answering ``rpc/plan`` as it does on the fabric: a 6 m x 4 m room with a wall at x = 3 from the
floor up to y = 3 (the way round is over its top).
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from agents.dispatch.agent import FleetWorker
from agents.dispatch.bidder import PathTravel
from agents.dispatch.tasks import parse_task
from agents.runtime import Agent
from mrs_bridge.config import parse_config
from mrs_bridge.drivers.wavefront import WavefrontDriver
from rsal.msgs import ErrorCode, MapData, Position2dData, RpcError
from rsal.testing import FakeServer

CONFIG = """
[[driver]]
name = "wavefront"
provides = ["r0:planner:0"]
requires = ["output::r0:position2d:1", "input::r0:position2d:2", "r0:map:0"]
safety_dist = 0.1
"""
SPEED = 0.5


def walled_room() -> dict:
    cells = np.full((40, 60), -1, dtype=np.int8)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 1
    cells[:30, 29:31] = 1  # the wall: x 2.9..3.1, y 0..3
    return MapData(60, 40, 0.1, (0.0, 0.0), cells).to_dict()


@pytest.fixture(scope="module")
def planner():
    cfg = parse_config(CONFIG, source="wavefront.toml").drivers[0]
    drv = WavefrontDriver(cfg, FakeServer())
    drv.setup()
    drv.on_reply(cfg.requires[2], "get", walled_room(), None)
    drv.on_reply(cfg.requires[0], "describe", {"geometry": {"robot_radius": 0.25, "frame": "odom"}}, None)
    drv.on_input(cfg.requires[1], "data", Position2dData(1.0, (1.0, 1.0, 0.0), (0, 0, 0)).to_dict())
    addr = cfg.provides[0]
    return lambda a, b: drv.on_rpc(addr, "plan", {"start": list(a), "goal": list(b)})["length"]


class Robot(FleetWorker, Agent):
    """The robot side's bid, with the planner's travel."""

    def __init__(self, travel):
        Agent.__init__(self, "fleet0", robot="r0")
        self.init_worker(speed=SPEED, threshold=0.2, target=0.9, status_every=1.0, agent_id="fleet0")
        self._travel = travel

    def where(self):
        return (1.0, 1.0)

    def travel(self):
        return self._travel


def _bid(robot: Robot, x: float, y: float):
    task = parse_task({"id": "t1", "kind": "go_to", "args": {"x": x, "y": y}})
    return robot._cost(robot.where(), [], task, robot.places_left(), None, robot.travel())


def test_a_goal_behind_a_wall_is_costed_by_the_path_around_it(planner):
    path = PathTravel(planner, SPEED, "fleet0")
    b = _bid(Robot(path), 5.0, 1.0)
    straight = 4.0 / SPEED
    around = planner((1.0, 1.0), (5.0, 1.0))
    # over the wall's top (y > 3) and back down: at least the two legs to its top corner
    assert around > 2 * math.hypot(2.0, 2.0 + 0.35)
    assert b.cost == pytest.approx(around / SPEED) and b.cost > 1.5 * straight
    assert _bid(Robot(None), 5.0, 1.0).cost == pytest.approx(straight)  # no planner: the straight line
    # a goal in the open on this side: the planner's path is the straight line
    assert _bid(Robot(path), 2.0, 2.0).cost == pytest.approx(math.hypot(1.0, 1.0) / SPEED, rel=1e-6)
    asked = path.asked
    _bid(Robot(path), 5.0, 1.0)
    assert path.asked == asked  # the same leg again: from the cache


def test_no_path_is_no_bid(planner):
    assert _bid(Robot(PathTravel(planner, SPEED)), 2.95, 3.5) is not None  # over the wall's top: reachable
    assert _bid(Robot(PathTravel(planner, SPEED)), 5.0, 0.1) is None  # in the bottom wall: no path, refused
    assert _bid(Robot(None), 5.0, 0.1) is not None  # the straight line cannot tell


def test_a_planner_without_plan_gives_straight_lines_said_once(caplog):
    def old_planner(a, b):
        raise RpcError(ErrorCode.UNKNOWN_OP, "r0:planner:0 has no operation 'plan'")

    t = PathTravel(old_planner, SPEED, "fleet0")
    with caplog.at_level(logging.WARNING, logger="agents.dispatch.bidder"):
        assert t((0.0, 0.0), (3.0, 4.0)) == pytest.approx(10.0)
        assert t((0.0, 0.0), (6.0, 8.0)) == pytest.approx(20.0)
    assert t.straight and t.asked == 1
    said = [r.message for r in caplog.records if "straight lines" in r.message]
    assert len(said) == 1 and said[0].startswith("fleet0:")


def test_a_planner_not_ready_costs_that_leg_straight_and_asks_again():
    calls = []

    def busy(a, b):
        calls.append((a, b))
        raise RpcError(ErrorCode.UNAVAILABLE, "no map yet")

    t = PathTravel(busy, SPEED)
    assert t((0.0, 0.0), (3.0, 4.0)) == pytest.approx(10.0) and not t.straight
    t((0.0, 0.0), (3.0, 4.0))
    assert len(calls) == 2  # not cached: the planner is asked again once it can answer
