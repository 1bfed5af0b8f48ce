"""AMCL (:mod:`mrs_bridge.nav.amcl`): its parts in isolation, and the whole filter against the simulator.

The scenario tests run ``maps/floor.world`` with one Pioneer (the world's other robots removed)
wandering with the simulator's ``wander`` controller; the simulator's ground-truth pose is the
reference and its drifting odometry and noisy laser/sonar the filter's input. Each seed sets the
world (odometry bias and noise, sensor noise), the start pose and the filter's random numbers.

Tracking runs use odometry noise parameters matched to the simulated Pioneer (``TUNED``: its
odometry has a 3 %/5 % scale error, far below the 45 % standard deviation Player's default 0.2
assumes); global localization uses Player's defaults throughout.
"""

from __future__ import annotations

import math
from pathlib import Path

import numba
import numpy as np
import pytest
from scipy import stats

from mrs_bridge.nav.amcl import (
    CONE_RAYS,
    Amcl,
    AmclParams,
    kld_sample_count,
    likelihood_field_jit,
    likelihood_field_numpy,
    systematic_indices,
)
from mrs_bridge.nav.distfilter import expected_ranges, unmodeled
from mrs_bridge.nav.grid import NavGrid
from rsal.geometry import compose
from simulator import load_world
from simulator.controllers import wander
from simulator.presets import pioneer3at
from simulator.world import World

FLOOR = Path(__file__).resolve().parents[2] / "maps" / "floor.world"
SEEDS = range(10)
TUNED = {"odom_alpha1": 0.05, "odom_alpha2": 0.05, "odom_alpha3": 0.05, "odom_alpha4": 0.05}
LAB = (-23.5, -12.5, 3.5, 11.5)  # the laboratory of the floor map, x0 x1 y0 y1 (maps/README.md)
ROBOT = "r1"


@pytest.fixture(scope="module", autouse=True)
def _single_numba_thread():
    """The simulator's parallel ray caster runs one robot faster on one thread on this 2-core box."""
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(before)


@pytest.fixture(scope="module")
def floor_spec():
    return load_world(FLOOR)


# ---------------------------------------------------------------------- helpers
def _room(size: float = 20.0) -> NavGrid:
    """An empty square room (walls on the border), 0.05 m cells, origin at (0, 0)."""
    n = int(size / 0.05)
    occ = np.zeros((n, n), dtype=bool)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = True
    return NavGrid.from_occupancy(occ, 0.05, (0.0, 0.0))


def _ang(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _world(spec, seed: int, robot: str = "pioneer2dx") -> World:
    w = World(spec, seed=seed)
    for name in ("r0", "r2"):
        w.remove_model(name)
    if robot == "pioneer3at":
        w.remove_model(ROBOT)
        w.add_model(pioneer3at(ROBOT))
    return w


def _grid(w: World) -> NavGrid:
    g = w.grid
    return NavGrid.from_occupancy(g.occupied, g.resolution, g.origin)


def _place(w: World, grid: NavGrid, rng, region=None) -> np.ndarray:
    """Put the robot on a random free pose at least 0.7 m from walls (in ``region`` if given)."""
    x, y = grid.cell_to_world(*grid.free_cells(clearance=0.7))
    ok = np.ones(x.shape, dtype=bool)
    if region is not None:
        ok = (x > region[0]) & (x < region[1]) & (y > region[2]) & (y < region[3])
    i = rng.choice(np.flatnonzero(ok))
    w.set_pose(ROBOT, float(x[i]), float(y[i]), float(rng.uniform(-math.pi, math.pi)))
    return np.array(w.get_pose(ROBOT))


def _scan_geometry(spec):
    """Bearings, origins and cone widths of a simulator ranger in the robot frame, and its limits."""
    px, py, pa = spec.pose
    bearings, origins, widths = [], [], []
    for s in spec.sensors:
        sx, sy, sa = s.pose
        x = px + math.cos(pa) * sx - math.sin(pa) * sy
        y = py + math.sin(pa) * sx + math.cos(pa) * sy
        a = pa + sa
        if s.samples <= 1:  # one sonar transducer: a cone of width fov
            bearings.append([a])
            origins.append([[x, y]])
            widths.append([s.fov])
        else:
            bearings.append(a - s.fov / 2 + np.arange(s.samples) * s.fov / (s.samples - 1))
            origins.append(np.tile([x, y], (s.samples, 1)))
            widths.append(np.zeros(s.samples))
    s0 = spec.sensors[0]
    return np.concatenate(bearings), np.concatenate(origins), np.concatenate(widths), s0.range_min, s0.range_max


def _drive(w: World, amcl: Amcl, ranger: int, steps: int, until=None) -> tuple[np.ndarray, list[int]]:
    """Wander ``steps`` simulator steps feeding odometry and scans; position error after every step
    and the particle count after every applied update. ``until(errors)`` may stop early."""
    b, o, width, rmin, rmax = _scan_geometry(w.rangers(ROBOT)[ranger])
    errors, counts = [], []
    for _ in range(steps):
        wander(w)
        w.step()
        amcl.odometry(w.odometry(ROBOT))
        scan = w.ranger(ROBOT, ranger)
        if amcl.sensor(scan.ranges, b, o, rmin, rmax, beam_width=width):
            counts.append(amcl.particles.shape[0])
        mean, _ = amcl.estimate()
        x, y, _ = w.get_pose(ROBOT)
        errors.append(math.hypot(mean[0] - x, mean[1] - y))
        if until is not None and until(errors):
            break
    return np.array(errors), counts


def _track(spec, seed: int, ranger: int, robot: str = "pioneer2dx", seconds: float = 30.0):
    """Start 0.5 m and 20 deg off the true pose (the initial belief's standard deviations) and wander."""
    rng = np.random.default_rng(1000 + seed)
    w = _world(spec, seed, robot)
    grid = _grid(w)
    truth = _place(w, grid, rng)
    a = rng.uniform(0.0, 2.0 * math.pi)
    start = (
        truth[0] + 0.495 * math.cos(a),
        truth[1] + 0.495 * math.sin(a),
        truth[2] + math.radians(19.8) * rng.choice([-1.0, 1.0]),
    )
    params = AmclParams(seed=seed, init_pose=start, init_pose_var=(0.25, 0.25, math.radians(20.0) ** 2), **TUNED)
    amcl = Amcl(grid, params)
    return _drive(w, amcl, ranger, int(round(seconds / w.spec.interval_sim)))


# ---------------------------------------------------------------------- parameters
def test_from_dict_converts_lists_and_whole_floats():
    p = AmclParams.from_dict({"update_thresh": [0.1, 0.3], "pf_max_samples": 500.0, "init_pose": [1, 2, 0.5]})
    assert p.update_thresh == (0.1, 0.3)
    assert p.pf_max_samples == 500 and isinstance(p.pf_max_samples, int)
    assert p.init_pose == (1.0, 2.0, 0.5)


def test_from_dict_unknown_key_suggests_the_closest_name():
    with pytest.raises(ValueError, match=r"unknown amcl parameter 'pf_max_sample'.*did you mean 'pf_max_samples'"):
        AmclParams.from_dict({"pf_max_sample": 100})


def test_from_dict_player_key_that_is_not_a_filter_parameter_says_where_it_went():
    with pytest.raises(ValueError, match=r"'laser_pose' is not a filter parameter: .*origins"):
        AmclParams.from_dict({"laser_pose": [0.13, 0, 0]})


@pytest.mark.parametrize(
    ("bad", "key"),
    [
        ({"pf_min_samples": 0}, "pf_min_samples"),
        ({"pf_max_samples": 12.5}, "pf_max_samples"),
        ({"laser_sigma_hit": -0.1}, "laser_sigma_hit"),
        ({"odom_alpha3": True}, "odom_alpha3"),
        ({"laser_z_rand": float("nan")}, "laser_z_rand"),
        ({"update_thresh": [0.2]}, "update_thresh"),
        ({"init_pose_var": [1.0, -1.0, 0.1]}, "init_pose_var"),
        ({"recover_alpha_fast": 1.5}, "recover_alpha_fast"),
        ({"seed": "seven"}, "seed"),
        ({"pf_min_samples": 500, "pf_max_samples": 100}, "pf_max_samples"),
        ({"recover_alpha_slow": 0.2, "recover_alpha_fast": 0.1}, "recover_alpha_fast"),
    ],
)
def test_invalid_parameter_values_name_the_key(bad, key):
    with pytest.raises(ValueError, match=rf"amcl parameter {key}\b"):
        AmclParams.from_dict(bad)


# ---------------------------------------------------------------------- motion model
def _ring_scan(n: int = 60, r: float = 1.0):
    b = np.linspace(-math.pi, math.pi, n, endpoint=False)
    return np.full(n, r), b, np.zeros((n, 2)), 0.02, 5.6


def _anchored(params: AmclParams, odom=(0.0, 0.0, 0.0)) -> Amcl:
    """A filter that has seen its first odometry pose and taken the first scan (so the next motion
    past ``update_thresh`` moves the particles at once)."""
    amcl = Amcl(_room(), params)
    amcl.odometry(odom)
    assert amcl.sensor(*_ring_scan())
    return amcl


def _at(amcl: Amcl, pose, n: int = 4000) -> None:
    amcl.particles = np.tile(np.asarray(pose, dtype=float), (n, 1))
    amcl.weights = np.full(n, 1.0 / n)


def test_motion_model_moves_particles_by_the_robot_frame_odometry_change_in_any_odometry_frame():
    delta = (1.0, 0.3, 0.4)  # robot-frame motion: forward, left, turn
    odom0 = (5.0, -3.0, 2.0)  # odometry frame unrelated to the map
    odom1 = compose(odom0, delta)
    start = (10.0, 10.0, -0.7)
    expect = compose(start, delta)

    exact = _anchored(AmclParams(seed=1, odom_alpha1=0, odom_alpha2=0, odom_alpha3=0, odom_alpha4=0), odom0)
    _at(exact, start)
    assert exact.odometry(odom1)
    np.testing.assert_allclose(exact.particles, np.tile(expect, (4000, 1)), atol=1e-9)

    # With noise the cloud is centred on the same pose (up to the few mm by which rotation noise
    # bends the translation inwards: E[cos(e)] < 1) and spread around it.
    small = {f"odom_alpha{i}": 0.01 for i in (1, 2, 3, 4)}
    noisy = _anchored(AmclParams(seed=2, **small), odom0)
    _at(noisy, start)
    noisy.odometry(odom1)
    q = noisy.particles
    assert math.hypot(q[:, 0].mean() - expect[0], q[:, 1].mean() - expect[1]) < 0.02
    assert abs(np.angle(np.exp(1j * q[:, 2]).mean() * np.exp(-1j * expect[2]))) < 0.01
    assert q[:, 0].std() > 0.03 and _ang(q[:, 2] - expect[2]).std() > 0.03


@pytest.mark.parametrize(
    ("alpha", "motion", "spread", "still"),
    [
        ("odom_alpha1", (0.0, 0.0, 0.6), "yaw", "xy"),  # rotation from rotation: a turn in place
        ("odom_alpha2", (1.0, 0.0, 0.0), "yaw", None),  # rotation from translation: driving straight
        ("odom_alpha2", (0.0, 0.0, 0.6), None, "all"),  # ... nothing from a turn in place
        ("odom_alpha3", (1.0, 0.0, 0.0), "along", "yaw"),  # translation from translation
        ("odom_alpha4", (0.0, 0.0, 0.6), "xy", "yaw"),  # translation from rotation: a turn in place
        ("odom_alpha4", (1.0, 0.0, 0.0), None, "all"),  # ... nothing from driving straight
    ],
)
def test_each_odom_alpha_has_players_meaning(alpha, motion, spread, still):
    params = {"odom_alpha1": 0.0, "odom_alpha2": 0.0, "odom_alpha3": 0.0, "odom_alpha4": 0.0, alpha: 0.2}
    amcl = _anchored(AmclParams(seed=3, **params))
    _at(amcl, (10.0, 10.0, 0.0))
    amcl.odometry(motion)
    q = amcl.particles
    sd = {"xy": math.hypot(q[:, 0].std(), q[:, 1].std()), "along": q[:, 0].std(), "yaw": _ang(q[:, 2]).std()}
    if spread is not None:
        assert sd[spread] > 0.02
    for k in ("xy", "yaw") if still == "all" else (() if still is None else (still,)):
        assert sd[k] < 1e-9


def test_motion_noise_grows_with_the_alphas():
    spreads = []
    for alpha in (0.02, 0.1, 0.4):
        amcl = _anchored(AmclParams(seed=4, **{f"odom_alpha{i}": alpha for i in (1, 2, 3, 4)}))
        _at(amcl, (10.0, 10.0, 0.0))
        amcl.odometry((0.8, 0.2, 0.6))
        q = amcl.particles
        spreads.append((q[:, 0].std(), q[:, 1].std(), _ang(q[:, 2]).std()))
    s = np.array(spreads)
    assert (np.diff(s, axis=0) > 0).all(), s
    # the yaw noise is linear in the sampled rotations: x4 alpha -> x2 standard deviation
    assert s[2, 2] / s[1, 2] == pytest.approx(2.0, rel=0.05)


# ---------------------------------------------------------------------- update scheduling
def test_sensor_update_is_due_only_after_update_thresh_motion():
    amcl = Amcl(_room(), AmclParams(seed=5, init_pose=(10.0, 10.0, 0.0), pf_max_samples=500))
    scan = _ring_scan()
    assert amcl.odometry((0.0, 0.0, 0.0))  # a fresh belief takes the next scan
    assert amcl.sensor(*scan) and amcl.n_updates == 1
    assert not amcl.odometry((0.1, 0.0, 0.0))  # 0.1 m < 0.2 m
    assert not amcl.sensor(*scan) and amcl.n_updates == 1
    before = amcl.particles.copy()
    assert amcl.odometry((0.25, 0.0, 0.0))  # past 0.2 m: the particles move, the next scan is due
    assert not np.array_equal(before, amcl.particles)
    assert amcl.sensor(*scan) and amcl.n_updates == 2
    assert not amcl.odometry((0.25, 0.0, math.radians(25)))
    assert amcl.odometry((0.25, 0.0, math.radians(35)))  # past 30 deg of turning


def test_max_range_and_invalid_readings_are_skipped():
    amcl = Amcl(_room(), AmclParams(seed=6, init_pose=(10.0, 10.0, 0.0), pf_max_samples=500))
    z, b, o, rmin, rmax = _ring_scan()
    z[:] = rmax
    z[::7] = np.nan
    z[1::7] = 0.001  # below range_min
    w = amcl.weights.copy()
    assert not amcl.sensor(z, b, o, rmin, rmax)
    assert amcl.n_updates == 0
    np.testing.assert_array_equal(amcl.weights, w)


def test_sensor_rejects_mismatched_beam_arrays():
    amcl = Amcl(_room(), AmclParams(seed=7, pf_max_samples=200))
    z, b, o, rmin, rmax = _ring_scan()
    with pytest.raises(ValueError, match="bearings"):
        amcl.sensor(z, b[:-1], o, rmin, rmax)
    with pytest.raises(ValueError, match="range_min, range_max and beam_width"):
        amcl.sensor(z, b, o, rmin, rmax, beam_width=np.zeros(3))


# ---------------------------------------------------------------------- initial beliefs
def test_init_pose_samples_the_given_gaussian():
    amcl = Amcl(_room(), AmclParams(seed=8, pf_max_samples=20000))
    cov = np.array([[0.3, 0.1, 0.02], [0.1, 0.2, -0.01], [0.02, -0.01, 0.05]])
    amcl.init_pose((10.0, 9.0, 0.5), cov)
    assert amcl.particles.shape == (20000, 3)
    np.testing.assert_allclose(amcl.particles.mean(axis=0), (10.0, 9.0, 0.5), atol=0.02)
    np.testing.assert_allclose(np.cov(amcl.particles.T), cov, atol=0.015)
    with pytest.raises(ValueError, match="positive semi-definite"):
        amcl.init_pose((10.0, 9.0, 0.5), np.diag([0.1, -0.1, 0.1]))


def test_init_global_spreads_pf_max_samples_over_free_cells(floor_spec):
    grid = _grid(World(floor_spec, seed=0))
    amcl = Amcl(grid, AmclParams(seed=9, pf_max_samples=20000))
    amcl.init_global()
    q = amcl.particles
    assert q.shape == (20000, 3)
    ix, iy = grid.world_to_cell(q[:, 0], q[:, 1])
    assert grid.free[iy, ix].all()
    # uniform over free space: the share west of x = 0 matches the free cells' share
    fx, _ = grid.cell_to_world(*grid.free_cells())
    assert abs((q[:, 0] < 0).mean() - (fx < 0).mean()) < 0.02
    assert abs(np.cos(q[:, 2]).mean()) < 0.03 and abs(np.sin(q[:, 2]).mean()) < 0.03


# ---------------------------------------------------------------------- outputs
def test_estimate_is_the_weighted_mean_and_covariance_with_circular_yaw():
    rng = np.random.default_rng(10)
    n = 500
    q = np.stack([rng.normal(3.0, 0.4, n), rng.normal(-2.0, 0.2, n), _ang(math.pi + rng.normal(0, 0.2, n))], axis=1)
    q[:, 0] += 0.5 * q[:, 1]  # correlate x and y
    w = rng.random(n)
    w /= w.sum()
    amcl = Amcl(_room(), AmclParams(seed=10, pf_max_samples=200))
    amcl.particles, amcl.weights = q.copy(), w.copy()
    mean, cov = amcl.estimate()

    resultant = np.sum(w * np.exp(1j * q[:, 2]))
    yaw = np.angle(resultant)
    assert mean[:2] == pytest.approx(np.average(q[:, :2], axis=0, weights=w))
    assert abs(_ang(mean[2] - yaw)) < 1e-9 and abs(abs(yaw) - math.pi) < 0.1  # around the seam
    np.testing.assert_allclose(cov[:2, :2], np.cov(q[:, :2].T, aweights=w, bias=True), rtol=1e-9)
    dyaw = _ang(q[:, 2] - yaw)
    assert cov[0, 2] == pytest.approx(np.sum(w * (q[:, 0] - mean[0]) * dyaw))
    assert cov[2, 2] == pytest.approx(-2.0 * math.log(abs(resultant)))
    np.testing.assert_array_equal(cov, cov.T)


def test_estimate_follows_odometry_between_updates():
    amcl = Amcl(_room(), AmclParams(seed=11, init_pose=(10.0, 10.0, 0.5), init_pose_var=(1e-6, 1e-6, 1e-6)))
    amcl.odometry((2.0, 1.0, 0.0))
    assert amcl.sensor(*_ring_scan())
    m0, _ = amcl.estimate()
    before = amcl.particles.copy()
    assert not amcl.odometry((2.0, 1.1, 0.3))  # 0.1 m and 17 deg: no filter update yet
    m1, _ = amcl.estimate()
    np.testing.assert_array_equal(amcl.particles, before)
    np.testing.assert_allclose(m1, compose(m0, (0.0, 0.1, 0.3)), atol=1e-9)  # 0.1 m to the robot's left


def test_hypotheses_are_clusters_heaviest_first_and_join_across_the_yaw_seam():
    rng = np.random.default_rng(12)
    a = np.stack([rng.normal(4, 0.1, 700), rng.normal(4, 0.1, 700), _ang(math.pi + rng.normal(0, 0.05, 700))], 1)
    b = np.stack([rng.normal(12, 0.1, 300), rng.normal(9, 0.1, 300), rng.normal(0.3, 0.05, 300)], 1)
    amcl = Amcl(_room(), AmclParams(seed=12, pf_max_samples=200))
    amcl.particles = np.vstack([a, b])
    amcl.weights = np.full(1000, 1e-3)
    hyp = amcl.hypotheses()
    assert len(hyp) == 2
    (wa, ma, ca), (wb, mb, cb) = hyp
    assert wa == pytest.approx(0.7) and wb == pytest.approx(0.3)
    assert ma[:2] == pytest.approx((4, 4), abs=0.02) and abs(abs(ma[2]) - math.pi) < 0.02
    assert mb == pytest.approx((12, 9, 0.3), abs=0.02)
    assert ca[0, 0] == pytest.approx(0.01, rel=0.2) and cb[2, 2] == pytest.approx(0.0025, rel=0.2)


# ---------------------------------------------------------------------- building blocks
def test_kld_sample_count_matches_the_chi_square_quantile():
    err, z = 0.01, 3.0
    k = np.array([2, 5, 10, 50, 200, 1000])
    exact = stats.chi2.ppf(stats.norm.cdf(z), k - 1) / (2 * err)
    np.testing.assert_allclose(kld_sample_count(k, err, z), exact, rtol=0.03)
    assert kld_sample_count(1, err, z) == 0


def test_systematic_resampling_gives_each_particle_floor_or_ceil_of_n_times_its_weight():
    rng = np.random.default_rng(13)
    for n in (50, 1000, 3333):
        w = rng.random(400) ** 3
        w /= w.sum()
        counts = np.bincount(systematic_indices(np.cumsum(w), n, rng), minlength=w.size)
        assert counts.sum() == n
        assert ((counts == np.floor(n * w)) | (counts == np.ceil(n * w))).all()


@pytest.mark.parametrize("rays", [1, CONE_RAYS])
def test_compiled_likelihood_field_matches_numpy(rays):
    rng = np.random.default_rng(14)
    grid = _room()
    table = rng.normal(size=(grid.height + 2) * (grid.width + 2)).astype(np.float32)
    px, py = rng.uniform(-2, 22, 300), rng.uniform(-2, 22, 300)  # some off the map
    pth = rng.uniform(-4, 4, 300)
    lx, ly = rng.uniform(-6, 6, 12 * rays), rng.uniform(-6, 6, 12 * rays)
    args = (px, py, pth, lx, ly, rays, table, 0.0, 0.0, 20.0, grid.width, grid.height)
    np.testing.assert_allclose(likelihood_field_jit(*args), likelihood_field_numpy(*args), rtol=1e-6, atol=1e-5)


def test_scan_likelihood_peaks_at_the_true_pose(floor_spec):
    """The field measures distance to wall *surfaces*: with cell-centre distances (0 anywhere in a
    wall) the best fit sat up to 0.3 m off, where beams ended deep inside thick walls."""
    w = _world(floor_spec, 0)
    grid = _grid(w)
    amcl = Amcl(grid, AmclParams(seed=15, laser_sigma_hit=0.05, laser_max_beams=682, pf_max_samples=100))
    b, o, width, rmin, rmax = _scan_geometry(w.rangers(ROBOT)[1])
    rng = np.random.default_rng(15)
    d = np.linspace(-0.3, 0.3, 31)
    t = np.radians(np.linspace(-2, 2, 5))
    dx, dy, dt = (g.ravel() for g in np.meshgrid(d, d, t, indexing="ij"))
    offsets = []
    for _ in range(12):
        truth = _place(w, grid, rng)
        w.step()
        z = w.ranger(ROBOT, 1).ranges.astype(float)
        ok = z < rmax - 1e-3
        lx = o[ok, 0] + z[ok] * np.cos(b[ok])
        ly = o[ok, 1] + z[ok] * np.sin(b[ok])
        amcl.particles = np.stack([truth[0] + dx, truth[1] + dy, truth[2] + dt], axis=1)
        best = amcl.particles[np.argmax(amcl._log_likelihood(lx, ly, 1, rmax))]
        offsets.append(math.hypot(best[0] - truth[0], best[1] - truth[1]))
    assert max(offsets) <= 0.05, np.round(offsets, 3)


# ---------------------------------------------------------------------- against the simulator
@pytest.fixture(scope="module")
def laser_runs(floor_spec):
    return [_track(floor_spec, seed, ranger=1) for seed in SEEDS]


def _report(name, worst):
    print(f"\n{name}: per-seed max error (m) {np.round(worst, 3).tolist()}")


def test_laser_tracking_error_stays_under_15_cm_in_every_seed(laser_runs):
    """Start 0.5 m / 20 deg off, 30 s of wandering with the URG-04LX (682 beams, 5.6 m): after
    10 s the error stays under 0.15 m at every step."""
    worst = np.array([errors[100:].max() for errors, _ in laser_runs])
    _report("laser tracking, 10-30 s", worst)
    assert (worst < 0.15).all(), np.round(worst, 3)


def test_kld_particle_count_shrinks_as_the_filter_converges_within_its_bounds(laser_runs):
    p = AmclParams()
    for _, counts in laser_runs:
        c = np.array(counts)
        assert (c >= p.pf_min_samples).all() and (c <= p.pf_max_samples).all()
        assert c[0] == p.pf_max_samples  # the initial belief, not yet resampled
        assert np.median(c[len(c) // 2 :]) < 0.3 * p.pf_max_samples, c


@pytest.mark.parametrize(("robot", "sonars"), [("pioneer2dx", 8), ("pioneer3at", 16)])
def test_sonar_tracking_error_stays_under_half_a_metre_in_every_seed(floor_spec, robot, sonars):
    """As the laser test with the Pioneer sonar ring only (15 deg cones, 5 m)."""
    worst = []
    for seed in SEEDS:
        w_sonars = len(_world(floor_spec, seed, robot).rangers(ROBOT)[0].sensors)
        assert w_sonars == sonars
        errors, _ = _track(floor_spec, seed, ranger=0, robot=robot)
        worst.append(errors[100:].max())
    _report(f"{sonars} sonars tracking, 10-30 s", np.array(worst))
    assert (np.array(worst) < 0.5).all(), np.round(worst, 3)


def _converged(errors, hold_steps: int = 150) -> bool:
    e = np.asarray(errors)
    return e.size >= hold_steps and bool((e[-hold_steps:] < 0.3).all())


def test_global_localization_converges_within_60_s_in_8_of_10_seeds(floor_spec):
    """Uniform start, robot anywhere in the laboratory (the thesis's start area), wandering:
    converged = under 0.3 m from then on (held 15 s). Player's parameters except
    ``pf_max_samples`` 20000: the floor has about 900 m^2 of free space to cover."""
    times = []
    for seed in SEEDS:
        w = _world(floor_spec, seed)
        grid = _grid(w)
        _place(w, grid, np.random.default_rng(2000 + seed), LAB)
        amcl = Amcl(grid, AmclParams(seed=seed, pf_max_samples=20000))
        amcl.init_global()
        errors, _ = _drive(w, amcl, 1, 750, until=_converged)
        times.append((len(errors) - 150) * w.spec.interval_sim if _converged(errors) else math.inf)
    print(f"\nglobal localization: per-seed convergence time (s) {np.round(times, 1).tolist()}")
    assert sum(t <= 60.0 for t in times) >= 8, times


def _outside_lab(w: World, grid: NavGrid, rng) -> np.ndarray:
    x0, x1, y0, y1 = LAB
    while True:  # anywhere not in (or next to) the laboratory
        pose = _place(w, grid, rng)
        if not (x0 - 3 < pose[0] < x1 + 3 and y0 - 3 < pose[1] < y1 + 3):
            return pose


def test_kidnapped_robot_recovers_through_random_particles(floor_spec):
    """Tracking somewhere on the floor, then teleported into the laboratory: Augmented MCL starts
    injecting random particles within 5 s, KLD-sampling widens the set for them, and the filter is
    back under 0.3 m (held 10 s) within 60 s."""
    recover = []
    for seed in range(5):
        rng = np.random.default_rng(3000 + seed)
        w = _world(floor_spec, seed)
        grid = _grid(w)
        truth = _outside_lab(w, grid, rng)
        amcl = Amcl(grid, AmclParams(seed=seed, init_pose=tuple(truth), init_pose_var=(0.01, 0.01, 0.003), **TUNED))
        errors, counts = _drive(w, amcl, 1, 150)
        assert errors[50:].max() < 0.15
        assert amcl.recovery_probability < 0.05
        n_tracking = counts[-1]
        _place(w, grid, rng, LAB)
        injected = []

        def watch(errs, amcl=amcl, injected=injected):
            injected.append(amcl.recovery_probability)
            return _converged(errs, 100)

        errors, counts = _drive(w, amcl, 1, 700, until=watch)
        assert max(injected[:50]) > 0.05
        assert max(counts) > 3 * n_tracking
        assert _converged(errors, 100), errors[-100:].max()
        recover.append((len(errors) - 100) * w.spec.interval_sim)
    print(f"\nkidnapping: per-seed recovery time (s) {np.round(recover, 1).tolist()}")
    assert max(recover) <= 60.0, recover


def test_unknown_cells_bound_the_likelihood_field_as_walls_do():
    """A built map's unexplored space starts right behind the walls it saw: a beam ending in unknown
    space scores as a hit on a wall, and a map without unknown cells keeps the grid's own field."""
    free = np.full((40, 40), -1, dtype=np.int8)
    free[:, 30:] = 0  # unexplored east of x = 1.5 m
    walled = free.copy()
    walled[:, 30:] = 1  # the same space as a wall
    a, b = Amcl(NavGrid(free, 0.05, (0.0, 0.0))), Amcl(NavGrid(walled, 0.05, (0.0, 0.0)))
    np.testing.assert_allclose(a._surface_distance(), b._surface_distance())
    assert a._surface_distance()[20, 29] == pytest.approx(0.025)  # half a cell from the boundary
    known = np.where(walled > 0, 1, -1).astype(np.int8)
    g = NavGrid(known, 0.05, (0.0, 0.0))
    np.testing.assert_allclose(Amcl(g)._surface_distance()[g.free], g.distance[g.free] - 0.025)


# ---------------------------------------------------------------------- distance filter
def test_expected_ranges_march_to_the_first_blocked_cell_and_off_the_map():
    """A 2 m x 2 m room at 0.05 m with walls two cells thick and an opening in the east wall at
    y = 0.95..1.05 m. From (0.5, 0.5) facing east: the east wall 1.4 m away, the west wall 0.4 m,
    the north wall 1.4 m; a beam mounted 0.475 m to the left leaves through the opening and ends at
    the map's edge (x = 2 m); nothing within a 1 m range is infinite."""
    cells = np.full((40, 40), -1, dtype=np.int8)
    cells[:, :2] = cells[:, 38:] = cells[:2, :] = cells[38:, :] = 1
    cells[19:21, 38:] = -1
    blocked = cells >= 0
    pose = (0.5, 0.5, 0.0)
    bearings = [0.0, math.pi, math.pi / 2, 0.0]
    origins = [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.475]]
    exp = expected_ranges(blocked, 0.05, (0.0, 0.0), pose, bearings, origins, 5.0)
    np.testing.assert_allclose(exp, [1.4, 0.4, 1.4, 1.5], atol=0.026)
    assert np.isinf(expected_ranges(blocked, 0.05, (0.0, 0.0), pose, [0.0], [[0.0, 0.0]], 1.0)).all()


def test_unmodeled_leaves_out_short_readings_but_never_most_of_a_scan():
    expected = np.array([2.0, 2.0, 2.0, 2.0, 2.0])
    assert unmodeled([1.0, 1.9, 2.0, 1.6, 3.0], expected, 0.3).tolist() == [True, False, False, True, False]
    assert not unmodeled([1.0, 1.0, 1.0, 2.0, 2.0], expected, 0.3).any()  # 3 of 5: the estimate is wrong


def test_distance_filter_keeps_the_estimate_beside_a_robot_not_on_the_map(floor_spec):
    """Tracking from the corridor with a second Pioneer (not on the map) parked 1 m ahead: the
    distance filter leaves readings out (the intruder's) in every seed and the worst error stays
    under 0.15 m. (Here, with the intruder seen only briefly, the filter does not help: the worst
    errors are 0.086 / 0.074 / 0.106 m without it, 0.105 / 0.133 / 0.138 m with it; its benefit
    with robots crossing the route is measured by benchmarks/bench_nav.py, docs/benchmarks.md.)"""
    worst, left_out = [], []
    for seed in range(3):
        w = World(floor_spec, seed=seed)
        w.remove_model("r0")
        grid = _grid(w)
        truth = w.get_pose(ROBOT)
        w.set_pose("r2", truth[0] + math.cos(truth[2]), truth[1] + math.sin(truth[2]), truth[2])
        amcl = Amcl(
            grid,
            AmclParams(
                seed=seed,
                init_pose=tuple(truth),
                init_pose_var=(0.01, 0.01, 0.003),
                laser_unmodeled_margin=0.5,
                **TUNED,
            ),
        )
        seen = []

        def watch(errs, amcl=amcl, seen=seen):
            seen.append(amcl.n_unmodeled)
            return False

        errors, _ = _drive(w, amcl, 1, 300, until=watch)
        worst.append(float(errors.max()))
        left_out.append(max(seen))
    print(f"\ndistance filter: worst errors {np.round(worst, 3).tolist()}, most readings left out {left_out}")
    assert max(worst) < 0.15, worst
    assert min(left_out) > 0, left_out
