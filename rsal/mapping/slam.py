"""Graph SLAM for ``rsal map``: scan matching, keyframes, loop closure, pose-graph optimisation.

The front end (in the spirit of Karto / slam_toolbox, Konolige et al., "Efficient sparse pose
adjustment for 2D mapping", IROS 2010; Hess et al., "Real-time loop closure in 2D LIDAR SLAM",
ICRA 2016):

1. the odometry predicts each scan's pose from the previous one; a scan is *used* once the
   robot moved ``min_move`` m or turned ``min_turn`` rad since the last used one;
2. each used scan is matched by point-to-line ICP (:func:`rsal.mapping.scanmatch.icp`) against the
   local map: the points of the last ``submap`` keyframes at their current estimates;
3. every ``kf_move`` m / ``kf_turn`` rad the scan becomes a keyframe, a node of the pose graph
   (:mod:`rsal.mapping.posegraph`) joined to the previous keyframe by the matched relative pose;
4. loop closure: keyframes within ``loop_radius`` m of the new one's estimate but at least
   ``loop_gap`` keyframes back are candidates; the nearest is tried by a correlative search
   (:func:`rsal.mapping.scanmatch.correlative`) over a window against its neighbourhood, refined
   by ICP, and accepted when enough points fit (``loop_inliers``); the graph is then optimised
   and every later estimate moves with its keyframe.

The back end optimises the whole graph once more at the end; non-keyframe scans keep their pose
relative to their keyframe.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .posegraph import PoseGraph, between, compose
from .reader import Scans
from .scanmatch import Reference, correlative, icp, normals, scan_points, transform

__all__ = ["SlamParams", "SlamResult", "run_slam"]


@dataclass
class SlamParams:
    min_move: float = 0.10  # m between used scans
    min_turn: float = 0.10  # rad
    kf_move: float = 0.30  # m between keyframes
    kf_turn: float = 0.25  # rad
    submap: int = 12  # keyframes in the local map
    loop_radius: float = 2.5  # m
    loop_gap: int = 25  # keyframes back
    loop_travel: float = 10.0  # m driven since the candidate, at least
    loop_constraint: float = 0.08  # the match must pin the translation down every way (scanmatch)
    loop_window: float = 0.4  # m, +- of the correlative search
    loop_yaw: float = 0.12  # rad, +-
    loop_inliers: float = 0.6  # fraction of the scan's points within 5 cm after ICP
    loop_every: int = 3  # try a loop closure at most every this many keyframes
    icp_prior: tuple = (0.05, 0.05)  # m, rad: how far the odometry's prediction may be off
    icp_gate: float = 0.2  # m: the farthest first association of a point
    floor_sigma: tuple = (0.01, 0.01, 0.005)  # m, m, rad: no match is trusted more than this
    odom_frac: float = 0.05  # the odometry's error, as a fraction of the motion (m/m, rad/rad)
    loop_floor_sigma: tuple = (0.03, 0.03, 0.015)
    loop_prior: tuple = (0.1, 0.05)  # m, rad: how far the estimate may be off where a loop is tried


@dataclass
class SlamResult:
    poses: np.ndarray  # (U, 3) robot pose of each used scan, in the map frame
    used: np.ndarray  # (U,) indices of the used scans
    keyframes: np.ndarray  # indices (into used) of the keyframes
    loops: list = field(default_factory=list)  # (keyframe i, keyframe j) of each accepted loop
    loop_tries: int = 0
    cost: tuple = (0.0, 0.0)  # pose graph cost before / after the final optimisation
    residual: float = 0.0  # m: RMS translation error of the graph's edges at the end
    wall: float = 0.0
    graph: PoseGraph | None = None


def run_slam(
    sc: Scans,
    initial_pose=(0.0, 0.0, 0.0),
    params: SlamParams | None = None,
    progress=None,
    progress_every: float = 0.5,
) -> SlamResult:
    """Run the front and back end over the scans; ``initial_pose`` is the robot's pose at the first
    scan in the map frame; ``progress(i, n, keyframes, loops)`` every ``progress_every`` s."""
    p = params or SlamParams()
    t_start = time.perf_counter()
    n = len(sc.t)
    # the map frame: the initial pose given to the first odometry reading
    T = compose(np.asarray(initial_pose, float), between(sc.odom[0], np.zeros(3)))
    odom_map = compose(np.broadcast_to(T, sc.odom.shape), sc.odom)

    local_pts, local_nrm = [], []  # per used scan, robot frame
    used, est = [], []
    kf_of = []  # keyframe (graph node) each used scan hangs from
    rel = []  # the used scan's pose relative to its keyframe
    graph = PoseGraph()
    kf_scan: list[int] = []  # used-scan index of each keyframe
    loops, tries = [], 0
    ref: Reference | None = None
    last_loop_try = -(10**9)
    next_report = time.monotonic() + progress_every

    def kf_world(k: int):
        u = kf_scan[k]
        return transform(graph.poses[k], local_pts[u]), _rot(graph.poses[k][2], local_nrm[u])

    def rebuild_ref():
        ks = range(max(0, len(kf_scan) - p.submap), len(kf_scan))
        P, N = zip(*(kf_world(k) for k in ks), strict=True)
        return Reference(np.vstack(P), np.vstack(N))

    for i in range(n):
        if used:
            last = used[-1]
            d = between(odom_map[last], odom_map[i])
            if np.hypot(d[0], d[1]) < p.min_move and abs(d[2]) < p.min_turn and i != n - 1:
                continue
            guess = compose(est[-1], d)
        else:
            guess = odom_map[i]
        pts, beams = scan_points(sc.ranges[i], sc.angles, sc.mount, sc.range_min, sc.range_max)
        nrm, ok = normals(pts, beams, sc.mount)
        if ok.sum() < 20:
            continue
        info = None
        if ref is not None:
            m = icp(ref, pts[ok][::2], guess, nrm=nrm[ok][::2], prior=p.icp_prior, max_dist=p.icp_gate)
            pose = m.pose if m.inliers > 0.3 else guess
            info = m.info if m.inliers > 0.3 else None
        else:
            pose = np.asarray(guess, float)
        u = len(used)
        used.append(i)
        est.append(np.asarray(pose, float))
        local_pts.append(pts[ok])
        local_nrm.append(nrm[ok])
        new_kf = not kf_scan
        if kf_scan:
            dk = between(graph.poses[-1], pose)
            new_kf = np.hypot(dk[0], dk[1]) >= p.kf_move or abs(dk[2]) >= p.kf_turn
        if new_kf:
            k = graph.add_node(pose)
            if k > 0:
                z = between(graph.poses[k - 1], pose)
                graph.add_edge(k - 1, k, z, info=_edge_info(info, graph.poses[k - 1][2], p.floor_sigma, z, p))
            kf_scan.append(u)
            kf_of.append(k)
            rel.append(np.zeros(3))
            if k - last_loop_try >= p.loop_every and k >= p.loop_gap:
                tries_here = _try_loop(graph, kf_scan, local_pts, local_nrm, k, p, kf_world)
                if tries_here is not None:
                    tries += 1
                    last_loop_try = k
                    if tries_here:
                        loops.append(tries_here)
                        graph.optimize(max_nfev=20)
                        for v in range(len(est)):
                            est[v] = compose(graph.poses[kf_of[v]], rel[v])
            ref = rebuild_ref()
        else:
            kf_of.append(len(kf_scan) - 1)
            rel.append(between(graph.poses[-1], pose))
        if progress is not None and time.monotonic() >= next_report:
            next_report = time.monotonic() + progress_every
            progress(i + 1, n, len(kf_scan), len(loops))
    cost = graph.optimize(max_nfev=100)
    final = np.array([compose(graph.poses[kf_of[v]], rel[v]) for v in range(len(used))])
    chi = graph.chi2() if graph.edges_i else np.zeros(1)
    P = np.asarray(graph.poses)
    if graph.edges_i:
        e = between(P[graph.edges_i], P[graph.edges_j]) - np.asarray(graph.edges_z)
        residual = float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
    else:
        residual = 0.0
    del chi
    if progress is not None:
        progress(n, n, len(kf_scan), len(loops))
    return SlamResult(
        final, np.asarray(used), np.asarray(kf_scan), loops, tries, cost, residual, time.perf_counter() - t_start, graph
    )


def _edge_info(info_world, yaw_i: float, floor, z, p: SlamParams, odom: bool = True) -> np.ndarray:
    """A match's information (world frame) as an edge's, in the frame of the node at ``yaw_i``:
    its covariance plus a floor, and (sequential edges) the odometry's information added."""
    A = np.eye(3)
    c, s = np.cos(yaw_i), np.sin(yaw_i)
    A[:2, :2] = [[c, s], [-s, c]]
    cov = np.diag(np.square(floor))
    if info_world is not None:
        try:
            cov = cov + A @ np.linalg.pinv(info_world + np.eye(3) * 1e-6, hermitian=True) @ A.T
        except np.linalg.LinAlgError:
            cov = cov + np.eye(3) * 1e3
    else:
        cov = cov + np.eye(3) * 1e3
    out = np.linalg.inv(cov)
    if odom:
        d = float(np.hypot(z[0], z[1]))
        so = p.odom_frac * d + 0.005
        sy = p.odom_frac * abs(float(z[2])) + 0.01 * d + 0.002
        out = out + np.diag([1 / so**2, 1 / so**2, 1 / sy**2])
    return out


def _rot(yaw, v):
    c, s = np.cos(yaw), np.sin(yaw)
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])


def _try_loop(graph: PoseGraph, kf_scan, local_pts, local_nrm, k: int, p: SlamParams, kf_world):
    """Look for a loop closure of keyframe ``k``: None if there was no candidate, False if the
    candidate did not match, else ``(j, k)`` with the edge added to the graph."""
    P = np.asarray(graph.poses)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(P[:, :2], axis=0).T))])
    old = P[: k - p.loop_gap + 1]
    if len(old) == 0:
        return None
    d = np.hypot(old[:, 0] - P[k, 0], old[:, 1] - P[k, 1])
    d[travel[k] - travel[: len(old)] < p.loop_travel] = np.inf
    j = int(np.argmin(d))
    if d[j] > p.loop_radius:
        return None
    lo, hi = max(0, j - 4), min(k - p.loop_gap + 1, j + 5)
    pts_w, nrm_w = zip(*(kf_world(q) for q in range(lo, hi)), strict=True)
    ref_pts, ref_nrm = np.vstack(pts_w), np.vstack(nrm_w)
    scan = local_pts[kf_scan[k]]
    if len(scan) < 30 or len(ref_pts) < 30:
        return False
    sub = scan[:: max(1, len(scan) // 150)]
    coarse, score = correlative(ref_pts, sub, P[k], win_xy=p.loop_window, win_yaw=p.loop_yaw)
    m = icp(Reference(ref_pts, ref_nrm), scan, coarse, nrm=local_nrm[kf_scan[k]], prior=p.loop_prior, center=P[k])
    if m.inliers < p.loop_inliers or m.constraint < p.loop_constraint or np.hypot(*(m.pose[:2] - coarse[:2])) > 0.15:
        return False
    z = between(P[j], m.pose)
    graph.add_edge(j, k, z, loop=True, info=_edge_info(m.info, P[j][2], p.loop_floor_sigma, z, p, odom=False))
    return (j, k)
