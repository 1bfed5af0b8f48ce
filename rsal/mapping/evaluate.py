"""Judging a built map against ground truth (for tests, benchmarks and a lab's own checks).

- :func:`trajectory_error`: the position error of estimated poses against true ones (RMS, max),
  as in Kümmerle et al., "On measuring the accuracy of SLAM algorithms" (2009), absolute form;
- :func:`wall_agreement`: how the built map's occupied cells agree with a true occupancy bitmap:
  the fraction of built occupied cells within ``tol`` of a true wall (precision), and the fraction
  of true wall cells the robot saw (a built free cell within ``tol`` + one cell) that have a built
  occupied cell within ``tol`` (coverage). Distances by ``scipy.ndimage.distance_transform_edt``.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["trajectory_error", "wall_agreement"]


def trajectory_error(est: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """RMS and max of the position error (m) of ``est`` against ``truth`` (both (N, >=2))."""
    e = np.hypot(est[:, 0] - truth[:, 0], est[:, 1] - truth[:, 1])
    return float(np.sqrt(np.mean(e**2))), float(e.max())


def _dist_to(mask: np.ndarray, res: float) -> np.ndarray:
    if not mask.any():
        return np.full(mask.shape, np.inf)
    return ndimage.distance_transform_edt(~mask) * res


def _sample(field: np.ndarray, res: float, origin, x: np.ndarray, y: np.ndarray, outside: float) -> np.ndarray:
    ix = np.floor((x - origin[0]) / res).astype(int)
    iy = np.floor((y - origin[1]) / res).astype(int)
    ok = (ix >= 0) & (ix < field.shape[1]) & (iy >= 0) & (iy < field.shape[0])
    out = np.full(x.shape, outside, dtype=float)
    out[ok] = field[iy[ok], ix[ok]]
    return out


def wall_agreement(
    built: np.ndarray,
    built_res: float,
    built_origin,
    true_occ: np.ndarray,
    true_res: float,
    true_origin,
    tol: float = 0.10,
    occupied: float = 0.65,
    free: float = 0.196,
):
    """``(precision, coverage)`` of a built map against the truth. ``built``: occupancy with row 0
    at the *bottom* (-1 unknown, else 0..1); ``true_occ``: boolean, row 0 at the bottom; origins are
    the lower-left corners (m)."""
    b_occ = built > occupied
    b_free = (built >= 0) & (built < free)
    # precision: each built occupied cell's centre, its distance to the nearest true wall cell
    t_dist = _dist_to(true_occ, true_res)
    iy, ix = np.nonzero(b_occ)
    bx = built_origin[0] + (ix + 0.5) * built_res
    by = built_origin[1] + (iy + 0.5) * built_res
    d = _sample(t_dist, true_res, true_origin, bx, by, np.inf)
    precision = float(np.mean(d <= tol + 0.5 * true_res)) if len(d) else 0.0
    # coverage: true wall cells next to true free space that the robot saw free
    boundary = true_occ & ndimage.binary_dilation(~true_occ)
    ty, tx = np.nonzero(boundary)
    wx = true_origin[0] + (tx + 0.5) * true_res
    wy = true_origin[1] + (ty + 0.5) * true_res
    seen = _sample(_dist_to(b_free, built_res), built_res, built_origin, wx, wy, np.inf) <= tol + built_res
    hit = _sample(_dist_to(b_occ, built_res), built_res, built_origin, wx, wy, np.inf) <= tol + 0.5 * built_res
    coverage = float(np.mean(hit[seen])) if seen.any() else 0.0
    return precision, coverage
