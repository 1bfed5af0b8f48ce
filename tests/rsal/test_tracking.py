"""rsal.tracking: the constant-velocity Kalman tracker of broadcast poses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rsal.tracking import PoseTracker, Tracks


def feed_line(tr: PoseTracker, vx: float, vy: float, rate: float = 2.0, n: int = 10, noise: float = 0.0, seed: int = 1):
    rng = np.random.default_rng(seed)
    yaw = math.atan2(vy, vx)
    for i in range(n):
        t = i / rate
        assert tr.update(vx * t + rng.normal(0, noise), vy * t + rng.normal(0, noise), yaw, t)
    return (n - 1) / rate


def test_converges_on_a_straight_line():
    tr = PoseTracker()
    t_last = feed_line(tr, 0.4, 0.3, noise=0.01)
    p = tr.predict(t_last)
    assert p.vx == pytest.approx(0.4, abs=0.03) and p.vy == pytest.approx(0.3, abs=0.03)
    assert math.hypot(p.x - 0.4 * t_last, p.y - 0.3 * t_last) < 0.02
    assert p.w == pytest.approx(0.0, abs=0.05)


def test_predicts_between_samples_better_than_holding():
    tr = PoseTracker()
    t_last = feed_line(tr, 0.5, 0.0)
    for dt in (0.1, 0.25, 0.45):
        p = tr.predict(t_last + dt)
        truth = 0.5 * (t_last + dt)
        held = 0.5 * t_last
        assert abs(p.x - truth) < 0.02, dt
        assert abs(p.x - truth) < 0.2 * abs(held - truth), dt
        assert p.t == pytest.approx(t_last + dt)


def test_predict_leaves_the_filter_unchanged_and_stops_at_the_horizon():
    tr = PoseTracker(horizon=1.0)
    t_last = feed_line(tr, 1.0, 0.0)
    state = tr.kf.x.copy()
    far = tr.predict(t_last + 10.0)
    assert np.array_equal(tr.kf.x, state)
    assert far.x == pytest.approx(tr.predict(t_last + 1.0).x)
    assert far.t == pytest.approx(t_last + 1.0)
    assert tr.predict(t_last - 5.0).x == pytest.approx(tr.predict(t_last).x)  # never before the last sample


def test_rejects_out_of_order_and_non_finite_samples():
    tr = PoseTracker()
    t_last = feed_line(tr, 0.5, 0.0)
    before = tr.predict(t_last)
    assert not tr.update(-3.0, 4.0, 0.0, t_last - 0.3)
    assert not tr.update(math.nan, 0.0, 0.0, t_last + 0.5)
    assert not tr.update(0.0, 0.0, 0.0, math.inf)
    assert tr.rejected == 3 and tr.samples == 10 and tr.t == t_last
    assert tr.predict(t_last) == before


def test_yaw_turns_through_pi_without_a_jump():
    tr = PoseTracker()
    w = 0.8  # rad/s, turning in place through +-pi
    for i in range(12):
        t = i * 0.5
        tr.update(0.0, 0.0, math.atan2(math.sin(2.5 + w * t), math.cos(2.5 + w * t)), t)
    p = tr.predict(5.5 + 0.25)
    truth = 2.5 + w * 5.75
    assert p.w == pytest.approx(w, abs=0.05)
    assert abs(math.atan2(math.sin(p.yaw - truth), math.cos(p.yaw - truth))) < 0.05
    assert -math.pi <= p.yaw <= math.pi


def test_nothing_before_the_first_sample_and_bad_parameters():
    assert PoseTracker().predict(3.0) is None
    with pytest.raises(ValueError, match="accel_std"):
        PoseTracker(accel_std=0.0)


def test_tracks_one_filter_per_robot():
    tracks = Tracks(horizon=0.5)
    assert tracks.predict("r0", 1.0) is None and "r0" not in tracks
    for i in range(6):
        tracks.update("r0", 0.5 * i * 0.5, 0.0, 0.0, i * 0.5)
        tracks.update("r1", 5.0, -0.3 * i * 0.5, -math.pi / 2, i * 0.5)
    a, b = tracks.predict("r0", 2.75), tracks.predict("r1", 2.75)
    assert a.x == pytest.approx(0.5 * 2.75, abs=0.02) and b.y == pytest.approx(-0.3 * 2.75, abs=0.02)
    assert tracks.trackers["r0"].horizon == 0.5
    tracks.forget("r1")
    assert "r1" not in tracks
    with pytest.raises(ValueError, match="horizon"):
        Tracks(horizon=-1)
