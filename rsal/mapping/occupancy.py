"""Occupancy grid mapping with known poses by log-odds ray casting (Thrun, Burgard and Fox,
*Probabilistic Robotics*, ch. 9, "occupancy grid mapping"; Moravec and Elfes 1985).

Each beam lowers the log odds of the cells it passes (Bresenham's line from the sensor to the
return) and raises the one it ends in; a beam at ``range_max`` (no return) only frees. The hot
loop is one numba kernel over every beam of every scan (compiled once, cached on disk as the
simulator's kernels are). The result is the occupied probability per cell, -1 where no beam came.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["occupancy_grid", "L_OCC", "L_FREE"]

L_OCC = 2.0  # log odds added by a return (a wall seen at a grazing angle is also passed by beams)
L_FREE = -0.3  # log odds added by a beam passing
L_MIN, L_MAX = -4.0, 4.0


@njit(cache=True, nogil=True)
def _cast(logodds, hits, sx, sy, ex, ey, ret, l_occ, l_free, lmin, lmax):  # pragma: no cover - numba
    h, w = logodds.shape
    for k in range(sx.shape[0]):
        x0, y0, x1, y1 = sx[k], sy[k], ex[k], ey[k]
        dx, dy = abs(x1 - x0), -abs(y1 - y0)
        stx = 1 if x0 < x1 else -1
        sty = 1 if y0 < y1 else -1
        err = dx + dy
        x, y = x0, y0
        while not (x == x1 and y == y1):
            if 0 <= x < w and 0 <= y < h:
                v = logodds[y, x] + l_free
                logodds[y, x] = lmin if v < lmin else v
                hits[y, x] = True
            e2 = 2 * err
            if e2 >= dy:
                err += dy
                x += stx
            if e2 <= dx:
                err += dx
                y += sty
        if 0 <= x1 < w and 0 <= y1 < h:
            if ret[k]:
                v = logodds[y1, x1] + l_occ
                logodds[y1, x1] = lmax if v > lmax else v
            else:
                v = logodds[y1, x1] + l_free
                logodds[y1, x1] = lmin if v < lmin else v
            hits[y1, x1] = True


def occupancy_grid(
    sensor_poses: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    range_min: float,
    range_max: float,
    resolution: float,
    margin: float = 1.0,
):
    """Build the grid from scans taken at ``sensor_poses`` (S, 3, the laser's pose in the map).
    Returns ``(occupancy, origin)``: occupancy (H, W) with row 0 at the *bottom* (y up), values
    0..1 (occupied probability) or -1 (unknown); origin (x, y) of cell (0, 0)'s lower-left corner."""
    r = np.asarray(ranges, dtype=float)
    valid = np.isfinite(r) & (r > max(range_min, 0.05))
    ret = valid & (r < range_max * 0.98)
    rr = np.where(valid, np.minimum(r, range_max), 0.0)
    a = sensor_poses[:, 2, None] + angles[None, :]
    ex = sensor_poses[:, 0, None] + rr * np.cos(a)
    ey = sensor_poses[:, 1, None] + rr * np.sin(a)
    pts_x = np.concatenate([ex[valid], sensor_poses[:, 0]])
    pts_y = np.concatenate([ey[valid], sensor_poses[:, 1]])
    x0 = np.floor((pts_x.min() - margin) / resolution) * resolution
    y0 = np.floor((pts_y.min() - margin) / resolution) * resolution
    w = int(np.ceil((pts_x.max() + margin - x0) / resolution)) + 1
    h = int(np.ceil((pts_y.max() + margin - y0) / resolution)) + 1
    logodds = np.zeros((h, w), np.float32)
    seen = np.zeros((h, w), np.bool_)
    m = valid.ravel()
    sx = np.repeat(np.floor((sensor_poses[:, 0] - x0) / resolution).astype(np.int64), r.shape[1])[m]
    sy = np.repeat(np.floor((sensor_poses[:, 1] - y0) / resolution).astype(np.int64), r.shape[1])[m]
    cx = np.floor((ex.ravel()[m] - x0) / resolution).astype(np.int64)
    cy = np.floor((ey.ravel()[m] - y0) / resolution).astype(np.int64)
    _cast(
        logodds,
        seen,
        sx,
        sy,
        cx,
        cy,
        ret.ravel()[m],
        np.float32(L_OCC),
        np.float32(L_FREE),
        np.float32(L_MIN),
        np.float32(L_MAX),
    )
    occ = 1.0 - 1.0 / (1.0 + np.exp(logodds.astype(float)))
    occ[~seen] = -1.0
    return occ, (float(x0), float(y0))
