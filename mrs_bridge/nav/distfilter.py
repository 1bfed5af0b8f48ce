"""The distance filter of Fox, Burgard and Thrun: range readings that an object not on the map cut
short are left out of the measurement update.

D. Fox, W. Burgard, S. Thrun, "Markov localization for mobile robots in dynamic environments",
*Journal of Artificial Intelligence Research* 11 (1999), sec. 4.2 ("distance filter"): a reading
much *shorter* than the map predicts from where the robot is was most likely caused by something
the map does not hold (a person, another robot), and scoring it against the map drags the estimate
towards poses that explain it with a wall. The paper weighs "shorter than expected" under the whole
belief; here, as the belief is unimodal whenever the filter is used for tracking, it is judged at
the filter's mean pose and only while the belief is tight enough (position standard deviation at
most the margin) for the map's prediction to mean something: during global localization or after
a kidnapping every reading counts. If most readings look cut short, the estimate is more likely
wrong than the world crowded, and every reading counts too (as ROS amcl's beam skipping gives up
when most beams disagree).

:func:`expected_ranges` marches every beam through the occupancy grid at half a cell per step, all
beams at once (numpy, no per-beam loop); :func:`unmodeled` returns the readings to leave out.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MAX_SHARE", "expected_ranges", "unmodeled"]

#: the largest share of a scan's readings the filter may leave out; above it, none is
MAX_SHARE = 0.5


def expected_ranges(blocked, resolution, origin, pose, bearings, origins, range_max: float) -> np.ndarray:
    """Ranges (m) at which the beams from ``pose`` ``(x, y, yaw)`` meet the first blocked cell of
    ``blocked`` (``(height, width)`` booleans, row 0 at ``origin[1]``); off the map counts as
    blocked; ``inf`` where no cell within ``range_max`` is. ``bearings (k,)`` and ``origins (k, 2)``
    are the beams in the robot frame."""
    x, y, th = (float(v) for v in pose)
    c, s = math.cos(th), math.sin(th)
    o = np.asarray(origins, dtype=np.float64)
    ox = x + c * o[:, 0] - s * o[:, 1]
    oy = y + s * o[:, 0] + c * o[:, 1]
    ang = th + np.asarray(bearings, dtype=np.float64)
    step = 0.5 * resolution
    t = np.arange(1, int(math.ceil(range_max / step)) + 1) * step
    inv = 1.0 / resolution
    iu = np.floor((ox[:, None] + np.cos(ang)[:, None] * t - origin[0]) * inv).astype(np.intp)
    iv = np.floor((oy[:, None] + np.sin(ang)[:, None] * t - origin[1]) * inv).astype(np.intp)
    h, w = blocked.shape
    inside = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
    hit = ~inside
    hit[inside] = blocked[iv[inside], iu[inside]]
    first = hit.argmax(axis=1)
    return np.where(hit[np.arange(hit.shape[0]), first], t[first], np.inf)


def unmodeled(ranges, expected, margin: float) -> np.ndarray:
    """Readings at least ``margin`` metres shorter than ``expected``: booleans, all False when more
    than :data:`MAX_SHARE` of them are (a wrong estimate rather than a crowd)."""
    short = np.asarray(ranges, dtype=np.float64) < np.asarray(expected, dtype=np.float64) - margin
    if short.sum() > MAX_SHARE * short.shape[0]:
        return np.zeros_like(short)
    return short
