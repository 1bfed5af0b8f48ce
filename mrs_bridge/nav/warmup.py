"""Compile the navigation drivers' numba kernels before they are served.

AMCL's likelihood field and tempering (:mod:`mrs_bridge.nav.amcl`), its sonar cone beam model
(:mod:`mrs_bridge.nav.conebeam`, with neighbours as landmarks: :mod:`mrs_bridge.nav.landmarks`) and
Wavefront's search (:mod:`mrs_bridge.nav.wavefront`) are
compiled by numba on first use and cached on disk. The ``amcl`` and ``wavefront`` drivers call
:func:`warm_up` in their set-up, before their devices are announced, so that a robot's first scan
or first goal never waits for a compiler (and never holds up the other drivers of the same
server); the project's set-up calls it once ahead of time.

:func:`warm_up` runs one filter update (laser and sonar cone) and one plan on a small room, which
compiles every kernel for the argument types the drivers use; with a warm cache it only loads them.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["kernels", "warm_up"]


def kernels() -> list:
    """The navigation's compiled functions (numba dispatchers)."""
    from . import amcl, conebeam, landmarks, wavefront

    return [
        amcl._ess_fraction,
        amcl.likelihood_field_jit,
        conebeam.cone_beam_jit,
        conebeam.cone_expected_jit,
        landmarks.landmark_beam_jit,
        wavefront._search,
        wavefront._trace,
        wavefront._visible,
        wavefront._simplify,
    ]


def warm_up() -> None:
    """Compile (first run) or load (every later run) every navigation kernel."""
    from .amcl import Amcl, AmclParams, tempering_exponent
    from .grid import NavGrid
    from .wavefront import Wavefront

    n = 80  # a 4 m room at 0.05 m/cell, walls on the border and a pillar
    occ = np.zeros((n, n), dtype=bool)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = True
    occ[30:50, 38:42] = True
    grid = NavGrid.from_occupancy(occ, 0.05, (0.0, 0.0))
    pf = Amcl(
        grid,
        AmclParams(pf_min_samples=50, pf_max_samples=200, laser_unmodeled_margin=0.5, known_obstacle_sigma=0.3),
    )
    pf.init_pose((1.0, 1.0, 0.0), np.diag([0.01, 0.01, 0.01]))
    pf.odometry((0.0, 0.0, 0.0))
    bearings = np.linspace(-math.pi / 2, math.pi / 2, 31)
    for width in (0.0, math.radians(15.0)):  # a laser ray, a sonar cone
        pf._due = True
        ranges = np.full(bearings.shape, 1.0, dtype=np.float32)
        pf.sensor(ranges, bearings, np.zeros((bearings.size, 2)), 0.02, 4.0, beam_width=width)
    pf.set_obstacles([[2.2, 1.0, 0.3]])  # a neighbour 1 m ahead: the sonar's landmark kernel
    pf._due = True
    pf.sensor(ranges, bearings, np.zeros((bearings.size, 2)), 0.02, 4.0, beam_width=math.radians(15.0))
    pf.estimate()
    tempering_exponent(np.zeros(8), np.linspace(-3.0, 0.0, 8), 0.5)
    planner = Wavefront(grid, robot_radius=0.2, safety_dist=0.05)
    planner.plan((0.6, 0.6), (3.4, 3.4))
    planner.plan((0.2, 0.6), (3.4, 3.4))  # a start in the forbidden band is snapped (line of sight)
