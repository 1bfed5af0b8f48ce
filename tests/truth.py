"""Ground truth for scenario tests: the simulator's true robot poses, pushed by ``rsal sim --truth``.

``rsal sim --truth`` serves each robot's true pose as ``<robot>:position2d:3`` (frame ``gps``, the
world frame, every simulation step; docs/simulator.md). :class:`Truth` holds one proxy per robot on
an open session and answers from the latest sample without a round trip, so a test can read where
the robots really are *at the moment* an agent reports an outcome (from inside an agent's
callback, too) instead of trusting what the agents believe or broadcast. The design's rule:
verdicts come from ground truth, never from a message any peer could have sent.
"""

from __future__ import annotations

import math

from rsal.client import Fabric
from rsal.data import Position

TRUTH_INDEX = 3  # mrs_bridge.cli.TRUTH_INDEX: rsal sim --truth's position2d index


class Truth:
    """The true poses of ``robots`` (latest sample each) on ``session``."""

    def __init__(self, session, robots):
        self.fabric = Fabric(session, own_session=False)
        self.devices = {r: self.fabric.device(f"{r}:position2d:{TRUTH_INDEX}") for r in robots}

    def ready(self) -> bool:
        """Every robot's true pose has arrived at least once."""
        return all(d.latest is not None for d in self.devices.values())

    def pose(self, robot: str) -> Position:
        p = self.devices[robot].position
        if p is None:
            raise AssertionError(f"no ground truth for {robot} yet (is the simulator running with --truth?)")
        return p

    def poses(self) -> dict[str, Position]:
        return {r: self.pose(r) for r in self.devices}

    def dist(self, a: str, b: str) -> float:
        p, q = self.pose(a), self.pose(b)
        return math.hypot(p.x - q.x, p.y - q.y)

    def to(self, robot: str, x: float, y: float) -> float:
        """True distance of ``robot`` to the point (``x``, ``y``), metres in the world frame."""
        p = self.pose(robot)
        return math.hypot(p.x - x, p.y - y)

    def close(self) -> None:
        self.fabric.close()
