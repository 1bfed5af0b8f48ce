"""Ray caster against analytic geometry, and against the numpy reference implementation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulator.gridmap import GridMap
from simulator.raycast import CircleIndex, cast_fans, cast_fans_numpy

RES = 0.05


def room() -> GridMap:
    """10 x 8 m room at 0.05 m/px with 3-cell walls; inner faces at x = -4.85, 4.85, y = -3.85, 3.85.
    A 1 x 1 m box occupies x in [1, 2], y in [-1, 0]."""
    occ = np.zeros((160, 200), dtype=bool)
    occ[:3, :] = occ[-3:, :] = True
    occ[:, :3] = occ[:, -3:] = True
    occ[60:80, 120:140] = True
    return GridMap(occ, RES, (-5.0, -4.0))


def fan(x, y, th0, n=1, dth=0.0, rmax=10.0, owner=-1):
    return {
        "x": np.array([x], float),
        "y": np.array([y], float),
        "th0": np.array([th0], float),
        "dth": np.array([dth], float),
        "n": np.array([n]),
        "rmax": np.array([rmax], float),
        "owner": np.array([owner]),
    }


@pytest.mark.parametrize(
    "x, y, th, expect",
    [
        (0.0, 0.5, 0.0, 4.85),  # east wall
        (0.0, 0.5, math.pi, 4.85),  # west wall
        (0.3, 0.2, math.pi / 2, 3.65),  # north wall
        (0.3, 0.2, -math.pi / 2, 4.05),  # south wall
        (0.0, -0.5, 0.0, 1.0),  # box west face at x = 1
        (1.5, 1.0, -math.pi / 2, 1.0),  # box north face at y = 0
    ],
)
def test_axis_rays_hit_walls_exactly(x, y, th, expect):
    assert cast_fans(room(), fan(x, y, th))[0] == pytest.approx(expect, abs=1e-9)


def test_oblique_ray_hits_wall_at_analytic_distance():
    # From (0, 0.5) at 30 degrees the east face x = 4.85 is reached after 4.85 / cos(30deg),
    # but the north face y = 3.85 first: 3.35 / sin(30deg) = 6.7 > 5.6 -> east at 5.6003.
    g = room()
    th = math.radians(30)
    assert cast_fans(g, fan(0.0, 0.5, th))[0] == pytest.approx(min(4.85 / math.cos(th), 3.35 / math.sin(th)), abs=1e-9)


def test_max_range_when_nothing_is_hit():
    assert cast_fans(room(), fan(0.0, 0.5, 0.0, rmax=2.0))[0] == 2.0


def test_circle_occludes_wall_and_owner_is_ignored():
    g = room()
    circles = CircleIndex(np.array([2.0, 0.0]), np.array([2.0, 2.0]), np.array([0.25, 0.25]), np.array([7, 3]))
    # Ray from the owner's centre (owner 3 at (0, 2)) east: its own circle is ignored, the other
    # circle at x = 2 with r = 0.25 is hit at 1.75.
    assert cast_fans(g, fan(0.0, 2.0, 0.0, owner=3), circles)[0] == pytest.approx(1.75, abs=1e-9)
    # Tangent rays miss; a ray just above the circle reaches the wall.
    up = math.atan2(0.26, 2.0)
    assert cast_fans(g, fan(0.0, 2.0, up, owner=3), circles)[0] == pytest.approx(4.85 / math.cos(up), abs=1e-9)


def test_fan_wrapping_past_pi_sees_circles_behind():
    # A 360-degree fan starting at +170 degrees must still see a circle straight ahead (0 deg).
    circles = CircleIndex(np.array([1.0]), np.array([0.0]), np.array([0.2]), np.array([1]))
    n = 361
    out = cast_fans(None, fan(0.0, 0.0, math.radians(170), n=n, dth=math.radians(1), rmax=5.0), circles)
    i0 = (360 - 170) % 360  # index of the 0-degree ray
    assert out[i0] == pytest.approx(0.8, abs=1e-9)
    assert out[(i0 + 90) % n] == 5.0


def test_matches_numpy_reference_on_random_fans():
    g = room()
    rng = np.random.default_rng(3)
    k = 12
    fans = {
        "x": rng.uniform(-4.5, 4.5, k),
        "y": rng.uniform(-3.5, 3.5, k),
        "th0": rng.uniform(-math.pi, math.pi, k),
        "dth": np.full(k, math.radians(240) / 681),
        "n": np.full(k, 682),
        "rmax": np.full(k, 5.6),
        "owner": np.arange(k),
    }
    # Keep origins out of the box (ray casting from inside an obstacle is undefined).
    inside = (fans["x"] > 0.9) & (fans["x"] < 2.1) & (fans["y"] > -1.1) & (fans["y"] < 0.1)
    fans["x"][inside] = -3.0
    circles = CircleIndex(fans["x"], fans["y"], np.full(k, 0.22), np.arange(k))
    fast = cast_fans(g, fans, circles)
    ref = cast_fans_numpy(g, fans, circles, step=0.002)
    # The reference marches in 2 mm steps: it overshoots a hit by at most one step, except where a
    # ray only grazes a cell corner and the reference steps over it (the exact walk does not).
    assert np.all(ref - fast >= -1e-9)
    close = (ref - fast) <= 0.002 + 1e-9
    assert close.mean() > 0.995


def test_sonar_cones_among_a_crowd_match_the_reference_for_both_fan_sizes():
    # A crowd's sonar cones (5 rays each: the direct ray-by-circle test) and 12-ray fans (the
    # angular window) against the same dense circles: both match the analytic reference.
    rng = np.random.default_rng(11)
    m = 300
    cx, cy = rng.uniform(-15, 15, m), rng.uniform(-15, 15, m)
    circles = CircleIndex(cx, cy, np.full(m, 0.3), np.arange(m))
    for n in (5, 12):
        k = 8 * m
        robot = np.repeat(np.arange(m), 8)
        fans = {
            "x": cx[robot] + 0.2 * np.cos(np.tile(np.arange(8), m)),
            "y": cy[robot] + 0.2 * np.sin(np.tile(np.arange(8), m)),
            "th0": rng.uniform(-math.pi, math.pi, k),
            "dth": np.full(k, math.radians(15) / (n - 1)),
            "n": np.full(k, n),
            "rmax": np.full(k, 5.0),
            "owner": robot,
        }
        fast = cast_fans(None, fans, circles)
        ref = cast_fans_numpy(None, fans, circles)
        assert (fast < 5.0).mean() > 0.3  # the crowd is dense: many rays hit a neighbour
        np.testing.assert_allclose(fast, ref, atol=1e-9)


def test_circle_index_finds_circles_spanning_many_cells():
    circles = CircleIndex(np.array([0.0, 30.0]), np.array([0.0, 0.0]), np.array([3.0, 0.5]), np.array([1, 2]), cell=1.0)
    out = cast_fans(None, fan(-10.0, 2.5, 0.0, rmax=50.0), circles)
    assert out[0] == pytest.approx(10.0 - math.sqrt(9 - 2.5**2), abs=1e-9)


def test_one_thread_casts_the_same_ranges_as_every_core_and_restores_the_count():
    import numba

    g = room()
    rng = np.random.default_rng(5)
    k = 40
    fans = {
        "x": rng.uniform(-4.5, -0.5, k),
        "y": rng.uniform(-3.5, 3.5, k),
        "th0": rng.uniform(-math.pi, math.pi, k),
        "dth": np.full(k, math.radians(15) / 4),
        "n": np.full(k, 5),
        "rmax": np.full(k, 5.0),
        "owner": np.arange(k),
        "noise": np.full(k, 0.01),
    }
    circles = CircleIndex(fans["x"], fans["y"], np.full(k, 0.2), np.arange(k))
    before = numba.get_num_threads()
    every = cast_fans(g, fans, circles, seed=3, step=7)
    one = cast_fans(g, fans, circles, seed=3, step=7, threads=1)
    assert numba.get_num_threads() == before
    np.testing.assert_array_equal(one, every)  # noise depends on (seed, step, ray), not the thread
