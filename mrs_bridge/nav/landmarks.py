"""Neighbours as landmarks: the cone beam model (:mod:`.conebeam`) with known discs in the scene.

Collaborative localization (Fox, Burgard, Kruppa and Thrun, "A probabilistic approach to
collaborative multi-robot localization", Autonomous Robots 8, 2000): a robot that senses another
whose position is known (here: broadcast) gains evidence about its own pose. Instead of leaving out
an echo a declared neighbour explains (:mod:`.knownobstacles`), the filter scores it with the beam
model (Probabilistic Robotics, ch. 6.3) against a scene holding both the map and the neighbours'
bodies: for each particle, the expected range ``z*`` of the beam is the nearer of the map's (the
least of the cone's rays, as in :func:`.conebeam.cone_beam_jit`) and the nearest crossing of any of
those rays with a circle of the neighbour's body radius around its broadcast position. When a
neighbour is the nearer, the hit's standard deviation widens to ``sqrt(sigma_hit^2 + sigma_nb^2)``:
``sigma_nb`` covers the neighbour's own uncertainty (its broadcast is an estimate, and stale by up
to a broadcast period). Readings the neighbours do not explain are scored by the map alone, exactly
as :func:`.conebeam.cone_beam_jit` scores them. One compiled pass over particles x beams x rays x
discs; :func:`landmark_beam_numpy` is the per-particle reference the kernel is tested against.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .conebeam import CUTOFF_SIGMAS, _cast, cone_expected_numpy

__all__ = ["landmark_beam_jit", "landmark_beam_numpy"]


@nb.njit(cache=True, inline="always")
def _ray_circle(px, py, c, s, cx, cy, r):  # pragma: no cover - compiled
    """Distance along ``(c, s)`` from ``(px, py)`` to a circle's boundary (0 from inside; inf: missed)."""
    vx = cx - px
    vy = cy - py
    tca = vx * c + vy * s
    d2 = vx * vx + vy * vy - tca * tca
    if d2 > r * r:
        return math.inf
    thc = math.sqrt(r * r - d2)
    if tca - thc >= 0.0:
        return tca - thc
    if tca + thc >= 0.0:
        return 0.0
    return math.inf


@nb.njit(cache=True)
def landmark_beam_jit(
    px,
    py,
    pth,
    bx,
    by,
    bang,
    z,
    rays,
    use,
    dx,
    dy,
    dr,
    blocked,
    clear,
    res,
    ox0,
    oy0,
    rmax,
    z_hit,
    z_rand,
    sigma,
    sigma_nb,
):  # pragma: no cover - compiled
    """Log-likelihood of a sonar scan for every particle, the map plus discs ``(dx, dy, dr)`` (map
    frame) in the scene for the beams with ``use[j]``; the other arguments as
    :func:`.conebeam.cone_beam_jit`'s."""  # fmt: skip
    n = px.shape[0]
    k = z.shape[0]
    m = dx.shape[0]
    out = np.empty(n)
    norm = math.log(sigma * math.sqrt(2.0 * math.pi))
    wide = math.sqrt(sigma * sigma + sigma_nb * sigma_nb)
    norm_w = math.log(wide * math.sqrt(2.0 * math.pi))
    rand = z_rand / rmax
    far = CUTOFF_SIGMAS * sigma if rand > 0.0 else math.inf
    far_w = CUTOFF_SIGMAS * wide if rand > 0.0 else math.inf
    for i in range(n):
        ct = math.cos(pth[i])
        st = math.sin(pth[i])
        acc = 0.0
        for j in range(k):
            sx = px[i] + ct * bx[j] - st * by[j]
            sy = py[i] + st * bx[j] + ct * by[j]
            if use[j]:
                best = min(rmax, z[j] + far_w)
                disc = math.inf
                for r in range(j * rays, (j + 1) * rays):
                    a = pth[i] + bang[r]
                    ca = math.cos(a)
                    sa = math.sin(a)
                    for q in range(m):
                        disc = min(disc, _ray_circle(sx, sy, ca, sa, dx[q], dy[q], dr[q]))
                    best = min(best, _cast(blocked, clear, res, ox0, oy0, sx, sy, ca, sa, min(best, disc)))
                if disc <= best:  # the cast stops at the disc: a neighbour nearer than the map
                    e = (z[j] - disc) / wide
                    acc += math.log(z_hit * math.exp(-0.5 * e * e - norm_w) + rand)
                else:
                    e = (z[j] - best) / sigma
                    acc += math.log(z_hit * math.exp(-0.5 * e * e - norm) + rand)
                continue
            best = min(rmax, z[j] + far)
            for r in range(j * rays, (j + 1) * rays):
                a = pth[i] + bang[r]
                best = min(best, _cast(blocked, clear, res, ox0, oy0, sx, sy, math.cos(a), math.sin(a), best))
            e = (z[j] - best) / sigma
            acc += math.log(z_hit * math.exp(-0.5 * e * e - norm) + rand)
        out[i] = acc
    return out


def landmark_beam_numpy(
    blocked, res, origin, poses, bx, by, bang, z, rays, use, discs, rmax, z_hit, z_rand, sigma, sigma_nb
) -> np.ndarray:
    """The reference for :func:`landmark_beam_jit`: one pose at a time, the map's ``z*`` by fine
    marching (:func:`.conebeam.cone_expected_numpy`), the discs' by solving ray-circle crossings
    for all rays and discs at once."""
    discs = np.asarray(discs, dtype=float).reshape(-1, 3)
    bang = np.asarray(bang, dtype=float)
    z = np.asarray(z, dtype=float)
    wide = math.hypot(sigma, sigma_nb)
    out = []
    for pose in poses:
        x, y, th = (float(v) for v in pose)
        zmap = cone_expected_numpy(blocked, res, origin, pose, bx, by, bang, rays, rmax)
        c, s = math.cos(th), math.sin(th)
        sx = np.repeat(x + c * np.asarray(bx) - s * np.asarray(by), rays)[:, None]
        sy = np.repeat(y + s * np.asarray(bx) + c * np.asarray(by), rays)[:, None]
        a = th + bang
        ca, sa = np.cos(a)[:, None], np.sin(a)[:, None]
        vx, vy, r = discs[None, :, 0] - sx, discs[None, :, 1] - sy, discs[None, :, 2]
        tca = vx * ca + vy * sa
        d2 = vx * vx + vy * vy - tca * tca
        thc = np.sqrt(np.maximum(r * r - d2, 0.0))
        t = np.where(tca - thc >= 0, tca - thc, np.where(tca + thc >= 0, 0.0, np.inf))
        t = np.where(d2 > r * r, np.inf, t)
        zdisc = t.min(axis=1).reshape(-1, rays).min(axis=1) if discs.shape[0] else np.full(len(z), np.inf)
        near = np.asarray(use, dtype=bool) & (zdisc < zmap)
        exp = np.where(near, zdisc, zmap)
        sg = np.where(near, wide, sigma)
        p = z_hit * np.exp(-0.5 * ((z - exp) / sg) ** 2) / (sg * math.sqrt(2 * math.pi)) + z_rand / rmax
        out.append(np.log(p).sum())
    return np.array(out)
