"""NavGrid.shared / derived: one grid and one set of derived grids per map in a process, and a
filter on a shared grid computes exactly what one on its own grid computes."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from mrs_bridge.nav.amcl import Amcl, AmclParams
from mrs_bridge.nav.grid import FREE, OCCUPIED, NavGrid


def _map(shift: int = 0):
    cells = np.full((60, 80), FREE, dtype=np.int8)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = OCCUPIED
    cells[20 + shift : 40 + shift, 30:34] = OCCUPIED
    return SimpleNamespace(cells=cells, resolution=0.1, origin=(-4.0, -3.0))


def test_same_map_same_grid_other_map_other_grid():
    a, b = NavGrid.shared(_map()), NavGrid.shared(_map())
    assert a is b
    c = NavGrid.shared(_map(shift=5))
    assert c is not a
    assert NavGrid.shared(SimpleNamespace(**{**vars(_map()), "resolution": 0.05})) is not a
    assert a.derived("k", lambda: object()) is a.derived("k", lambda: object())


def test_filters_on_a_shared_grid_match_filters_on_their_own():
    params = AmclParams(init_pose=(-1.0, 0.0, 0.0), init_pose_var=(0.05, 0.05, 0.01), seed=3)
    k = 16
    ang = np.linspace(-math.pi, math.pi, k, endpoint=False)
    origins = np.stack([0.2 * np.cos(ang), 0.2 * np.sin(ang)], axis=1)
    ranges = np.full(k, 2.0)
    results = []
    for grid in (NavGrid.from_map(_map()), NavGrid.shared(_map()), NavGrid.shared(_map())):
        f = Amcl(grid, params)
        f.odometry((0.0, 0.0, 0.0))
        assert f.sensor(ranges, ang, origins, 0.1, 5.0, beam_width=math.radians(15))
        results.append((f.particles.copy(), f.weights.copy()))
    for p, w in results[1:]:
        np.testing.assert_array_equal(p, results[0][0])
        np.testing.assert_array_equal(w, results[0][1])
