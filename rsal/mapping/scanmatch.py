"""Scan matching for ``rsal map``: point-to-line ICP and a correlative search (SE(2)).

- :func:`icp`: point-to-line ICP (Censi, "An ICP variant using a point-to-line metric", ICRA
  2008) of a scan's points against reference points with normals, nearest neighbours from
  ``scipy.spatial.cKDTree``, Huber weights, and a weak prior towards the initial guess (the
  odometry's prediction) that keeps a featureless corridor from sliding along its axis. Each
  iteration is one vectorised 3x3 Gauss-Newton step.
- :func:`correlative`: an exhaustive search over a window of poses on a likelihood field (Olson,
  "Real-Time Correlative Scan Matching", ICRA 2009), vectorised over translations for each
  rotation; used to verify loop closures, whose initial guess is too far off for ICP alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

__all__ = ["scan_points", "normals", "transform", "Reference", "icp", "correlative", "MatchResult"]


def transform(pose, pts: np.ndarray) -> np.ndarray:
    """Points (N, 2) in a frame at ``pose`` (x, y, yaw) to the parent frame."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.column_stack([pose[0] + c * pts[:, 0] - s * pts[:, 1], pose[1] + s * pts[:, 0] + c * pts[:, 1]])


def rotate(yaw: float, v: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])


def scan_points(ranges: np.ndarray, angles: np.ndarray, mount, range_min: float, range_max: float):
    """A scan's returns in the robot frame (N, 2) and which beams they came from."""
    r = np.asarray(ranges, dtype=float)
    ok = np.isfinite(r) & (r > max(range_min, 0.05)) & (r < range_max * 0.98)
    a = angles[ok] + mount[2]
    pts = np.column_stack([mount[0] + r[ok] * np.cos(a), mount[1] + r[ok] * np.sin(a)])
    return pts, np.nonzero(ok)[0]


def normals(pts: np.ndarray, beams: np.ndarray, origin=(0.0, 0.0), max_gap: float = 0.15):
    """Unit normals of the surface at each point from its neighbours along the scan, turned
    towards the sensor at ``origin`` (so the two faces of a thin wall have opposite normals), and
    whether a point has both neighbours close (on a surface, not an edge or a lone return)."""
    n = len(pts)
    if n < 3:
        return np.zeros((n, 2)), np.zeros(n, bool)
    prev = np.vstack([pts[:1], pts[:-1]])
    nxt = np.vstack([pts[1:], pts[-1:]])
    d = nxt - prev
    ok = (np.linalg.norm(pts - prev, axis=1) < max_gap) & (np.linalg.norm(nxt - pts, axis=1) < max_gap)
    ok[0] = ok[-1] = False
    adj = np.concatenate([[False], np.diff(beams) <= 2])
    ok &= adj & np.concatenate([adj[1:], [False]])
    nrm = np.column_stack([-d[:, 1], d[:, 0]])
    ln = np.linalg.norm(nrm, axis=1)
    ok &= ln > 1e-9
    nrm[ok] /= ln[ok, None]
    flip = np.einsum("ij,ij->i", nrm, np.asarray(origin, float)[None, :2] - pts) < 0
    nrm[flip] *= -1
    return nrm, ok


class Reference:
    """Reference points with normals (world frame) and their KD-tree."""

    def __init__(self, pts: np.ndarray, nrm: np.ndarray):
        self.pts = pts
        self.nrm = nrm
        self.tree = cKDTree(pts)


@dataclass
class MatchResult:
    pose: np.ndarray
    inliers: float  # fraction of the scan's points within ``inlier`` of the reference surface
    rms: float  # m, of the inliers' point-to-line distances
    n: int
    #: how well the inliers pin the translation down: the smaller eigenvalue of the mean of their
    #: normals' outer products (0: a corridor, free along its axis; 0.5: walls every way)
    constraint: float = 0.0
    #: the scan's information about the pose (3x3, world frame, x y yaw): J^T J / sigma^2 of the
    #: inliers' point-to-line distances, divided by ``SAMPLES_PER_INDEPENDENT`` (neighbouring
    #: points' errors are not independent)
    info: np.ndarray | None = None


def _associate(ref: Reference, w: np.ndarray, wn: np.ndarray | None, gate: float):
    """Each point's nearest reference point within ``gate`` whose normal faces the same way
    (one of the 4 nearest); returns the mask of associated points and their reference indices."""
    d, j = ref.tree.query(w, k=4, distance_upper_bound=gate)
    ok = np.isfinite(d)
    if wn is not None:
        jj = np.where(ok, j, 0)
        ok &= np.einsum("nkc,nc->nk", ref.nrm[jj], wn) > 0.5
    first = np.argmax(ok, axis=1)
    rows = np.arange(len(w))
    m = ok[rows, first]
    return m, j[rows, first][m], d[rows, first][m]


SIGMA = 0.02  # m: the expected point-to-line noise
SAMPLES_PER_INDEPENDENT = 10.0


def icp(
    ref: Reference,
    pts: np.ndarray,
    guess,
    *,
    nrm: np.ndarray | None = None,
    iters: int = 25,
    max_dist: float = 0.5,
    prior: tuple[float, float] = (0.05, 0.05),
    inlier: float = 0.05,
    center=None,
) -> MatchResult:
    """Point-to-line ICP of ``pts`` (robot frame; ``nrm`` their normals towards the sensor, which
    keeps points from pairing with the far face of a thin wall) against ``ref``, from ``guess``;
    ``prior`` is the standard deviation (m, rad) of the guess (a weak pull that only matters where
    the scan does not constrain the pose), centred on ``center`` (default: the guess)."""
    x = np.asarray(guess, dtype=float).copy()
    g = x.copy() if center is None else np.asarray(center, dtype=float)
    lam = np.diag([1 / prior[0] ** 2, 1 / prior[0] ** 2, 1 / prior[1] ** 2])
    sigma = SIGMA
    gate = max_dist
    for _ in range(iters):
        w = transform(x, pts)
        m, jm, _ = _associate(ref, w, None if nrm is None else rotate(x[2], nrm), gate)
        if m.sum() < 10:
            break
        q, nq = ref.pts[jm], ref.nrm[jm]
        p = w[m]
        r = np.einsum("ij,ij->i", nq, p - q)
        # d(p)/d(yaw) = (-(py - y), px - x)
        dp = np.column_stack([-(p[:, 1] - x[1]), p[:, 0] - x[0]])
        J = np.column_stack([nq[:, 0], nq[:, 1], np.einsum("ij,ij->i", nq, dp)])
        k = 0.05
        wt = np.where(np.abs(r) < k, 1.0, k / np.maximum(np.abs(r), 1e-12)) / sigma**2  # Huber
        H = (J * wt[:, None]).T @ J + lam
        b = (J * wt[:, None]).T @ r + lam @ _diff(x, g)
        dx = -np.linalg.solve(H, b)
        x += dx
        x[2] = _wrap(x[2])
        gate = max(0.15, gate * 0.7)
        if abs(dx[0]) < 1e-4 and abs(dx[1]) < 1e-4 and abs(dx[2]) < 1e-4:
            break
    w = transform(x, pts)
    m, jm, dm = _associate(ref, w, None if nrm is None else rotate(x[2], nrm), 0.3)
    if m.any():
        r = np.abs(np.einsum("ij,ij->i", ref.nrm[jm], w[m] - ref.pts[jm]))
        r = np.minimum(r, dm)
        good = r < inlier
        frac = float(good.sum()) / len(pts)
        rms = float(np.sqrt(np.mean(r[good] ** 2))) if good.any() else np.inf
        ng = ref.nrm[jm][good]
        con = float(np.linalg.eigvalsh(ng.T @ ng / len(ng))[0]) if len(ng) else 0.0
        pg = w[m][good]
        dp = np.column_stack([-(pg[:, 1] - x[1]), pg[:, 0] - x[0]])
        J = np.column_stack([ng, np.einsum("ij,ij->i", ng, dp)])
        info = J.T @ J / (SIGMA**2 * SAMPLES_PER_INDEPENDENT)
    else:
        frac, rms, con, info = 0.0, np.inf, 0.0, np.zeros((3, 3))
    return MatchResult(x, frac, rms, len(pts), con, info)


def _diff(a, b) -> np.ndarray:
    d = np.asarray(a, float) - np.asarray(b, float)
    d[2] = _wrap(d[2])
    return d


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def correlative(
    ref_pts: np.ndarray,
    pts: np.ndarray,
    guess,
    *,
    win_xy: float = 0.5,
    win_yaw: float = 0.2,
    res: float = 0.05,
    yaw_step: float = 0.01,
    sigma: float = 0.05,
    prior: float = 0.3,
) -> tuple[np.ndarray, float]:
    """The pose in a window around ``guess`` whose points best fit a likelihood field of
    ``ref_pts`` (world frame), each score weighted by a Gaussian of the offset (``prior`` m) so
    that where the fit is flat (a corridor) the guess wins; returns the pose and its mean
    likelihood (0..1)."""
    guess = np.asarray(guess, dtype=float)
    lo = ref_pts.min(axis=0) - win_xy - 1.0
    hi = ref_pts.max(axis=0) + win_xy + 1.0
    shape = np.ceil((hi - lo) / res).astype(int) + 1
    occ = np.zeros((shape[1], shape[0]), bool)
    ij = np.floor((ref_pts - lo) / res).astype(int)
    occ[ij[:, 1], ij[:, 0]] = True
    dist = ndimage.distance_transform_edt(~occ) * res
    field = np.exp(-0.5 * (dist / sigma) ** 2).astype(np.float32)
    nt = int(round(win_xy / res))
    offs = np.arange(-nt, nt + 1)
    best, best_pose = -1.0, guess
    pen = np.exp(-0.5 * (offs[:, None] ** 2 + offs[None, :] ** 2) * (res / prior) ** 2)
    for dyaw in np.arange(-win_yaw, win_yaw + 1e-9, yaw_step):
        w = transform((guess[0], guess[1], guess[2] + dyaw), pts)
        c = np.floor((w - lo) / res).astype(int)
        cx = c[:, 0, None, None] + offs[None, :, None]
        cy = c[:, 1, None, None] + offs[None, None, :]
        inside = (cx >= 0) & (cx < shape[0]) & (cy >= 0) & (cy < shape[1])
        sc = np.where(inside, field[np.clip(cy, 0, shape[1] - 1), np.clip(cx, 0, shape[0] - 1)], 0.0).mean(axis=0) * pen
        k = int(np.argmax(sc))
        if sc.flat[k] > best:
            ix, iy = np.unravel_index(k, sc.shape)
            best = float(sc.flat[k])
            best_pose = np.array([guess[0] + offs[ix] * res, guess[1] + offs[iy] * res, _wrap(guess[2] + dyaw)])
    return best_pose, best
