"""SE(2) once (rsal/geometry.py): wrap range, compose with inverse, scalar and vector forms agree,
and the simulator's private copies (it depends on nothing of ours) agree with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rsal.geometry import (
    TWO_PI,
    compose,
    compose_array,
    invert,
    invert_array,
    relative,
    relative_array,
    to_frame,
    transform_point,
    transform_points,
    wrap,
)

PI = math.pi
RNG = np.random.default_rng(20)
POSES = np.column_stack([RNG.uniform(-50, 50, 200), RNG.uniform(-50, 50, 200), RNG.uniform(-20, 20, 200)])
# values where (a + pi) % 2pi rounds to 2pi, plus the ends and multiples of pi
EDGES = [-PI, PI, -PI - 1e-20, PI - 1e-16, -1e-20, 1e-300, 3 * PI, -3 * PI, 1e9, -1e9, 7.0, -7.0, 0.0]


def _same_angle(a, b, tol=1e-9) -> bool:
    return bool(np.all(np.abs(wrap(np.asarray(a) - np.asarray(b))) <= tol))


# ---------------------------------------------------------------------------- wrap
@pytest.mark.parametrize("a", EDGES)
def test_wrap_is_in_minus_pi_to_pi_and_keeps_the_direction(a):
    r = wrap(a)
    assert isinstance(r, float)
    assert -PI <= r < PI
    assert math.cos(r) == pytest.approx(math.cos(a), abs=1e-6) and math.sin(r) == pytest.approx(math.sin(a), abs=1e-6)


def test_wrap_maps_pi_to_minus_pi_and_keeps_values_in_range_unchanged():
    assert wrap(PI) == -PI and wrap(-PI) == -PI
    assert wrap(PI - 1e-12) == PI - 1e-12
    assert wrap(0.5) == 0.5


def test_wrap_of_an_array_is_the_wrap_of_each_element():
    a = np.concatenate([np.array(EDGES), RNG.uniform(-100, 100, 1000)])
    v = wrap(a)
    assert isinstance(v, np.ndarray) and v.shape == a.shape
    assert np.all(v >= -PI) and np.all(v < PI)
    assert v.tolist() == [wrap(float(x)) for x in a]
    assert wrap(np.float64(7.0)) == wrap(7.0)


def test_wrap_of_non_finite_is_nan():
    assert math.isnan(wrap(math.inf)) and math.isnan(wrap(math.nan))
    assert np.isnan(wrap(np.array([math.inf, -math.inf]))).all()


# ---------------------------------------------------------------------------- compose, invert, relative
@pytest.mark.parametrize("i", range(0, 200, 13))
def test_compose_with_the_inverse_is_the_identity(i):
    a = tuple(POSES[i])
    assert compose(a, invert(a)) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert compose(invert(a), a) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    b = tuple(POSES[i + 1])
    assert relative(a, compose(a, b))[:2] == pytest.approx(b[:2], abs=1e-9)
    assert _same_angle(relative(a, compose(a, b))[2], b[2])
    assert relative(a, b) == pytest.approx(compose(invert(a), b), abs=1e-9)


def test_compose_is_associative_and_wraps_the_yaw():
    a, b, c = (tuple(p) for p in POSES[:3])
    left, right = compose(compose(a, b), c), compose(a, compose(b, c))
    assert left[:2] == pytest.approx(right[:2], abs=1e-9) and _same_angle(left[2], right[2])
    for p in (left, right, invert(a), relative(a, b)):
        assert -PI <= p[2] < PI


def test_compose_moves_a_pose_given_in_a_frame_into_the_parent_frame():
    # a robot at (1, 2) facing +y: a point 1 m ahead of it is at (1, 3)
    assert compose((1.0, 2.0, PI / 2), (1.0, 0.0, 0.0)) == pytest.approx((1.0, 3.0, PI / 2))
    assert relative((1.0, 2.0, PI / 2), (1.0, 3.0, 0.0)) == pytest.approx((1.0, 0.0, -PI / 2))
    assert transform_point((1.0, 2.0, PI / 2), 0.0, 1.0) == pytest.approx((0.0, 2.0))


def test_the_vector_forms_give_the_scalar_numbers():
    a, b = POSES[:100], POSES[100:]
    np.testing.assert_allclose(compose_array(a, b), [compose(p, q) for p, q in zip(a, b, strict=True)], atol=1e-9)
    np.testing.assert_allclose(invert_array(a), [invert(p) for p in a], atol=1e-9)
    np.testing.assert_allclose(relative_array(a, b), [relative(p, q) for p, q in zip(a, b, strict=True)], atol=1e-9)
    # one pose against many (broadcast), and many against one
    np.testing.assert_allclose(compose_array(a[0], b), [compose(a[0], q) for q in b], atol=1e-9)
    np.testing.assert_allclose(compose_array(a, b[0]), [compose(p, b[0]) for p in a], atol=1e-9)
    assert compose_array(a[0], b[0]).shape == (3,)
    pts = b[:, :2]
    np.testing.assert_allclose(transform_points(a[0], pts), [transform_point(a[0], *q) for q in pts], atol=1e-9)
    np.testing.assert_allclose(
        transform_points(a, pts), [transform_point(p, *q) for p, q in zip(a, pts, strict=True)], atol=1e-9
    )
    np.testing.assert_allclose(to_frame(a[0], transform_points(a[0], pts)), pts, atol=1e-9)
    np.testing.assert_allclose(to_frame(a[0], pts), relative_array(a[0], b)[:, :2], atol=1e-9)


def test_compose_and_inverse_are_planar_pose_algebra():
    """Moved with the pose algebra from rsal/watch.py (it uses the vector forms)."""
    a = np.array([1.0, 2.0, math.pi / 2])
    assert np.allclose(compose_array(a, [1.0, 0.0, 0.0]), [1.0, 3.0, math.pi / 2])
    assert np.allclose(compose_array(a, invert_array(a)), [0.0, 0.0, 0.0])
    many = compose_array(a, np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    assert np.allclose(many[:, :2], [[1.0, 3.0], [0.0, 2.0]])


def test_scalar_forms_return_plain_floats():
    for p in (compose(POSES[0], POSES[1]), invert(POSES[0]), relative(POSES[0], POSES[1])):
        assert all(type(v) is float for v in p)
    assert TWO_PI == 2 * PI


# ---------------------------------------------------------------------------- the simulator's copies
def test_the_simulators_private_helpers_agree():
    """The simulator imports nothing of ours, so it keeps a wrap and a (yaw-unwrapped) compose."""
    from simulator.stage.values import compose as _compose
    from simulator.world import _wrap

    a = np.concatenate([np.array(EDGES[:-4]), RNG.uniform(-100, 100, 500)])
    assert _same_angle(_wrap(a), wrap(a), tol=1e-12)
    for p, q in zip(POSES[:50], POSES[50:100], strict=True):
        got, want = _compose(tuple(p), tuple(q)), compose(p, q)
        assert got[:2] == pytest.approx(want[:2], abs=1e-9) and _same_angle(got[2], want[2])
