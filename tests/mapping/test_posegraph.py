"""The pose graph's Jacobian and optimiser (rsal.mapping.posegraph) on synthetic graphs."""

from __future__ import annotations

import numpy as np

from rsal.mapping.posegraph import PoseGraph, between, compose


def _circle(n: int = 200):
    true = [np.zeros(3)]
    for _ in range(n):
        true.append(compose(true[-1], [0.3, 0.0, 2 * np.pi / n]))
    return np.array(true)


def test_analytic_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    g = PoseGraph()
    for _ in range(6):
        g.add_node(rng.normal(size=3))
    for i in range(5):
        g.add_edge(i, i + 1, rng.normal(size=3), (0.1, 0.2, 0.05))
    a = rng.normal(size=(3, 3))
    g.add_edge(0, 4, rng.normal(size=3), info=a @ a.T + np.eye(3), loop=True)
    args = (np.array(g.edges_i), np.array(g.edges_j), np.array(g.edges_z), np.array(g.edges_w), g.poses[0].copy())
    x = np.asarray(g.poses).ravel()
    ja = g._jacobian(x, *args).toarray()
    jn = np.zeros_like(ja)
    for c in range(x.size):
        h = np.zeros_like(x)
        h[c] = 1e-6
        jn[:, c] = (g._residual(x + h, *args) - g._residual(x - h, *args)) / 2e-6
    assert np.abs(ja - jn).max() < 1e-4


def test_a_loop_edge_pulls_a_drifted_chain_back_onto_the_truth():
    true = _circle()
    rng = np.random.default_rng(1)
    g = PoseGraph()
    odo = [true[0]]
    for i in range(len(true) - 1):  # relative measurements with a yaw bias, integrated: the chain drifts
        z = between(true[i], true[i + 1]) + [0.0, 0.0, 0.004] + rng.normal(0, [0.005, 0.005, 0.001])
        odo.append(compose(odo[-1], z))
    for p in odo:
        g.add_node(p)
    for i in range(len(true) - 1):
        g.add_edge(i, i + 1, between(odo[i], odo[i + 1]), (0.01, 0.01, 0.005))
    drift = np.hypot(*(np.asarray(odo)[:, :2] - true[:, :2]).T).max()
    g.add_edge(0, len(true) - 1, between(true[0], true[-1]), (0.01, 0.01, 0.002), loop=True)
    before, after = g.optimize()
    err = np.hypot(*(np.asarray(g.poses)[:, :2] - true[:, :2]).T).max()
    assert drift > 1.0 and err < drift / 5, (drift, err)
    assert after < before
