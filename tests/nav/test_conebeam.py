"""The cone beam model (mrs_bridge.nav.conebeam): a sonar cone's expected range is the least range
across the cone, and the compiled kernel agrees with the marching reference."""

from __future__ import annotations

import math

import numpy as np

from mrs_bridge.nav.conebeam import (
    CONE_RAYS,
    CUTOFF_SIGMAS,
    ConeMap,
    cone_beam_jit,
    cone_expected_jit,
    cone_expected_numpy,
)

RES = 0.05
ORIGIN = (-1.0, -2.0)


def _cone(bearings, width):
    return (np.asarray(bearings, dtype=float)[:, None] + width * np.linspace(-0.5, 0.5, CONE_RAYS)).reshape(-1)


def _wall_map() -> ConeMap:
    """A wall along x = 4 m (cells from x = 4.0 on), open elsewhere."""
    b = np.zeros((200, 200), dtype=bool)
    ix = int(round((4.0 - ORIGIN[0]) / RES))
    b[:, ix:] = True
    return ConeMap(b, RES, ORIGIN)


def test_oblique_wall_reads_the_distance_along_the_cones_most_perpendicular_ray():
    """A 15 deg cone whose axis is 45 deg off a wall 2 m away reads 2 / cos(37.5 deg), not 2 / cos(45)."""
    cm = _wall_map()
    width = math.radians(15.0)
    bearings = np.radians([0.0, 45.0, -45.0, 60.0])
    z = cone_expected_jit(
        2.0, 1.0, 0.0, np.zeros(4), np.zeros(4), _cone(bearings, width), CONE_RAYS,
        cm.blocked, cm.clear, RES, *ORIGIN, 5.0,
    )  # fmt: skip
    near = np.maximum(np.abs(bearings) - width / 2, 0.0)  # a cone across the normal reads the normal
    np.testing.assert_allclose(z, 2.0 / np.cos(near), atol=1e-6)


def test_a_cone_that_sees_nothing_within_range_predicts_range_max():
    cm = _wall_map()
    z = cone_expected_jit(
        2.0, 1.0, math.pi, np.zeros(1), np.zeros(1), _cone([0.0], math.radians(15.0)), CONE_RAYS,
        cm.blocked, cm.clear, RES, *ORIGIN, 2.5,
    )  # fmt: skip
    assert z[0] == 2.5


def test_beam_model_prefers_the_true_distance_to_an_oblique_wall_over_nearer_poses():
    """The bias the likelihood field had: a pose nearer the wall must score worse than the truth."""
    cm = _wall_map()
    bearings = np.radians([45.0, -45.0, 0.0])
    bang = _cone(bearings, math.radians(15.0))
    zero = np.zeros(3)
    truth = cone_expected_jit(2.0, 1.0, 0.0, zero, zero, bang, CONE_RAYS, cm.blocked, cm.clear, RES, *ORIGIN, 5.0)
    xs = np.linspace(1.5, 2.5, 21)
    ll = cone_beam_jit(
        xs, np.full(21, 1.0), np.zeros(21), zero, zero, bang, truth, CONE_RAYS,
        cm.blocked, cm.clear, RES, *ORIGIN, 5.0, 0.8, 0.2, 0.2,
    )  # fmt: skip
    assert xs[np.argmax(ll)] == 2.0
    assert ll[xs < 1.99].max() < ll[10] - 0.1


def test_compiled_kernel_matches_the_marching_reference():
    rng = np.random.default_rng(3)
    b = np.zeros((160, 240), dtype=bool)
    b[0, :] = b[-1, :] = b[:, 0] = b[:, -1] = True
    for _ in range(25):  # rectangular obstacles
        x, y = rng.integers(0, 220), rng.integers(0, 140)
        b[y : y + rng.integers(3, 20), x : x + rng.integers(3, 20)] = True
    cm = ConeMap(b, RES, ORIGIN)
    n, k = 40, 6
    px, py, pth = rng.uniform(-0.5, 10.5, n), rng.uniform(-1.5, 5.5, n), rng.uniform(-4, 4, n)
    bx, by = rng.uniform(-0.2, 0.2, k), rng.uniform(-0.2, 0.2, k)
    bang = _cone(rng.uniform(-3, 3, k), math.radians(15.0))
    jit = np.array([
        cone_expected_jit(px[i], py[i], pth[i], bx, by, bang, CONE_RAYS, cm.blocked, cm.clear, RES, *ORIGIN, 5.0)
        for i in range(n)
    ])  # fmt: skip
    poses = zip(px, py, pth, strict=True)
    ref = np.array([cone_expected_numpy(b, RES, ORIGIN, q, bx, by, bang, CONE_RAYS, 5.0, 1e-3) for q in poses])
    # The reference marches in 1 mm steps and may step over a corner the exact walk clips.
    assert (jit <= ref + 2e-3).all()
    assert np.mean(np.abs(jit - ref) <= 2e-3) >= 0.99
    z = rng.uniform(0.2, 5.0, k)
    a = cone_beam_jit(px, py, pth, bx, by, bang, z, CONE_RAYS, cm.blocked, cm.clear, RES, *ORIGIN, 5.0, 0.8, 0.2, 0.2)
    e = (z - jit) / 0.2
    expected = np.log(0.8 * np.exp(-0.5 * e * e) / (0.2 * math.sqrt(2.0 * math.pi)) + 0.2 / 5.0).sum(axis=1)
    np.testing.assert_allclose(a, expected, rtol=1e-9)


def test_casting_stops_past_the_reading_without_changing_any_score():
    # Short readings (a crowd's neighbours) with a wall 3-5 m away: the casts stop 1 m past the
    # reading (CUTOFF_SIGMAS x 0.1 m), and the scores are those of the full casts to the wall.
    cm = _wall_map()
    rng = np.random.default_rng(5)
    n, k = 30, 8
    px, py, pth = rng.uniform(-0.5, 1.0, n), rng.uniform(-1.0, 5.0, n), rng.uniform(-0.3, 0.3, n)
    bx, by = np.zeros(k), np.zeros(k)
    bang = _cone(np.linspace(-0.6, 0.6, k), math.radians(15.0))
    z = rng.uniform(0.3, 1.2, k)
    full = np.array([
        cone_expected_jit(px[i], py[i], pth[i], bx, by, bang, CONE_RAYS, cm.blocked, cm.clear, RES, *ORIGIN, 5.0)
        for i in range(n)
    ])  # fmt: skip
    assert (full > z + CUTOFF_SIGMAS * 0.1).all()  # every cast is cut short
    for z_rand in (0.2, 0.0):  # without a random term nothing is cut
        got = cone_beam_jit(
            px, py, pth, bx, by, bang, z, CONE_RAYS, cm.blocked, cm.clear, RES, *ORIGIN, 5.0, 0.8, z_rand, 0.1
        )
        e = (z - full) / 0.1
        with np.errstate(divide="ignore"):
            want = np.log(0.8 * np.exp(-0.5 * e * e) / (0.1 * math.sqrt(2.0 * math.pi)) + z_rand / 5.0).sum(axis=1)
        np.testing.assert_allclose(got, want, rtol=1e-12)  # the same up to the order of operations
