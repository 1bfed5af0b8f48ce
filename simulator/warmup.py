"""Compile the simulator's numba kernels before a world is served.

The ray caster (:mod:`simulator.raycast`) is compiled by numba on first use and cached on disk
(``cache=True``: next to the module in ``__pycache__``, or under ``NUMBA_CACHE_DIR``). The first
use on a fresh checkout therefore takes seconds; a device server calls :func:`warm_up` before it
announces any device, so that a device's liveliness token always means it answers (docs/protocol.md),
and the project's set-up calls it once so that the first run starts as fast as every later one.

:func:`warm_up` steps a tiny world with the sensor kinds the simulator has (laser, sonar ring,
blobfinder, gripper, a second robot, a blob), so every kernel is compiled for the argument types
the real worlds use; with a warm cache it only loads them (tens of milliseconds).
"""

from __future__ import annotations

import math

__all__ = ["kernels", "warm_up"]


def kernels() -> list:
    """The simulator's compiled functions (numba dispatchers)."""
    from . import raycast

    return [raycast._cast_fans, raycast._segment_min]


def warm_up() -> None:
    """Compile (first run) or load (every later run) every simulator kernel."""
    from .presets import blob, blobfinder, gripper, pioneer2dx, urg04lx
    from .spec import WorldSpec
    from .world import World

    r0 = pioneer2dx("warm0", (0.0, 0.0, 0.0))
    r0.rangers.append(urg04lx())
    r0.blobfinders.append(blobfinder())
    r0.grippers.append(gripper())
    r1 = pioneer2dx("warm1", (1.5, 0.0, math.pi))
    world = World(WorldSpec(models=[r0, r1, blob("warmblob", (0.8, 0.4, 0.0))], speedup=math.inf))
    world.set_velocity("warm0", 0.2, 0.1)
    for _ in range(2):
        world.step()
