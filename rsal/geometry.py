"""Planar rigid-body geometry, SE(2), owned once for the whole platform.

A pose is ``(x, y, yaw)``: metres and radians, the yaw counter-clockwise from the parent frame's
x axis. The operators are those of Smith, Self and Cheeseman, "Estimating uncertain spatial
relationships in robotics" (1990), the thesis's equations (3.1)-(3.2) and Player/Stage's
``pose_add``/``pose_sub``:

- :func:`wrap` maps angles to ``[-pi, pi)`` (pi itself maps to -pi, as the thesis's
  ``getRelativeAngle`` does); scalars stay Python floats, arrays stay arrays.
- :func:`compose` is ``a ⊕ b``: pose ``b`` given in frame ``a``, expressed in ``a``'s parent frame.
- :func:`invert` is ``a⁻¹`` (the parent's origin seen from ``a``), :func:`relative` is
  ``a⁻¹ ⊕ b`` (``b`` seen from ``a``, both in the same frame).
- :func:`transform_points` takes points given in a pose's frame into the parent frame,
  :func:`to_frame` is its inverse.

Every operator has a scalar form on plain tuples (fast for one pose: no array is built) and a
numpy form (``*_array``, or array arguments) that broadcasts over leading axes ``(..., 3)`` and
``(..., 2)`` with no Python loop; both give the same numbers (tests/rsal/test_geometry.py checks it).
Composed yaws are wrapped.

The module imports only :mod:`math` and numpy. The ``simulator`` package keeps its own two
private helpers (a wrap and an unwrapped compose for Stage's nested model poses): it depends on
nothing of ours (docs/concepts.md, "Layers"), and the test above checks they agree with this
module. numba kernels inline the wrap where numba cannot call a Python function.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "TWO_PI",
    "Pose",
    "compose",
    "compose_array",
    "invert",
    "invert_array",
    "relative",
    "relative_array",
    "to_frame",
    "transform_point",
    "transform_points",
    "wrap",
]

TWO_PI = 2.0 * math.pi

Pose = tuple[float, float, float]
"""``(x, y, yaw)`` in metres and radians."""

_PI = math.pi


def wrap(a):
    """``a`` (radians) mapped to ``[-pi, pi)``: a float for a Python/numpy scalar, else an array.

    Non-finite values give nan (validate where data enters, see :func:`rsal.data.normalize_angle`).
    """
    if isinstance(a, float | int):
        a = float(a)
        if -_PI <= a < _PI:
            return a
        r = (a + _PI) % TWO_PI - _PI
        # Rounding can land exactly on pi (e.g. a = -pi - 1e-20): that is -pi.
        return r - TWO_PI if r >= _PI else r
    a = np.asarray(a, dtype=np.float64)
    with np.errstate(invalid="ignore"):  # inf -> nan, as for scalars
        r = np.mod(a + _PI, TWO_PI) - _PI
    r = np.where(r >= _PI, r - TWO_PI, r)
    return np.where((a >= -_PI) & (a < _PI), a, r)  # values in range stay exact, as for scalars


def compose(a: Sequence[float], b: Sequence[float]) -> Pose:
    """``a ⊕ b`` of two poses: ``b`` given in frame ``a``, expressed in ``a``'s parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    bx, by = b[0], b[1]
    return (
        float(a[0] + c * bx - s * by),
        float(a[1] + s * bx + c * by),
        wrap(float(a[2]) + float(b[2])),
    )


def invert(a: Sequence[float]) -> Pose:
    """``a⁻¹``: the parent frame's origin seen from frame ``a``; ``compose(a, invert(a)) == (0, 0, 0)``."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (float(-c * a[0] - s * a[1]), float(s * a[0] - c * a[1]), wrap(-float(a[2])))


def relative(a: Sequence[float], b: Sequence[float]) -> Pose:
    """``a⁻¹ ⊕ b``: pose ``b`` seen from pose ``a`` (both given in the same frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return (float(c * dx + s * dy), float(-s * dx + c * dy), wrap(float(b[2]) - float(a[2])))


def compose_array(a, b) -> np.ndarray:
    """:func:`compose` for arrays of poses ``(..., 3)``, broadcast against each other."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack(np.broadcast_arrays(x, y, wrap(a[..., 2] + b[..., 2])), axis=-1)


def invert_array(a) -> np.ndarray:
    """:func:`invert` for an array of poses ``(..., 3)``."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], wrap(-a[..., 2])], axis=-1)


def relative_array(a, b) -> np.ndarray:
    """:func:`relative` for arrays of poses ``(..., 3)``, broadcast against each other."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return np.stack(np.broadcast_arrays(c * dx + s * dy, -s * dx + c * dy, wrap(b[..., 2] - a[..., 2])), axis=-1)


def transform_point(pose: Sequence[float], x: float, y: float) -> tuple[float, float]:
    """The point ``(x, y)`` given in ``pose``'s frame, in the parent frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return (float(pose[0] + c * x - s * y), float(pose[1] + s * x + c * y))


def transform_points(pose, points) -> np.ndarray:
    """Points ``(..., 2)`` given in ``pose``'s frame, in the parent frame (``pose`` one ``(3,)``
    or one per point ``(..., 3)``)."""
    p = np.asarray(pose, dtype=np.float64)
    q = np.asarray(points, dtype=np.float64)
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    return np.stack([p[..., 0] + c * q[..., 0] - s * q[..., 1], p[..., 1] + s * q[..., 0] + c * q[..., 1]], axis=-1)


def to_frame(pose, points) -> np.ndarray:
    """Points ``(..., 2)`` given in the parent frame, in ``pose``'s frame (the inverse of
    :func:`transform_points`)."""
    p = np.asarray(pose, dtype=np.float64)
    q = np.asarray(points, dtype=np.float64)
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    dx, dy = q[..., 0] - p[..., 0], q[..., 1] - p[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)
