"""Built-in demo controllers for headless runs and benchmarks (no RSAL, no network).

``wander``: each robot drives forward and, when its first laser (or, without a laser, its first
ranger) sees something closer than ``stop_dist`` in the front third of its field, slows down and
turns towards the more open side. It is the classic Stage "wander" example controller in spirit,
written for many robots.
"""

from __future__ import annotations

__all__ = ["wander"]


def wander(world, *, speed: float = 0.5, turn: float = 0.8, stop_dist: float = 0.8) -> None:
    """Set every robot's velocity from the latest scan of its first laser (its first ranger if it
    has no laser; a robot without rangers just drives ahead)."""
    for name in world.robot_names:
        specs = world.rangers(name)
        r = None
        if specs:
            index = next((i for i, s in enumerate(specs) if s.kind == "laser"), 0)
            r = world.ranger(name, index)
        if r is None:
            world.set_velocity(name, speed, 0.0)
            continue
        z = r.ranges
        n = z.shape[0]
        if n >= 3:
            front = float(z[n // 3 : max(n // 3 + 1, 2 * n // 3)].min())
        else:
            front = float(z.min())
        if front < stop_dist:
            left = float(z[n // 2 :].mean())
            right = float(z[: n // 2].mean())
            world.set_velocity(name, 0.05, turn if left > right else -turn)
        else:
            world.set_velocity(name, speed, 0.0)
