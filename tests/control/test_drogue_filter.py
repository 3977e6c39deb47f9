"""Drogue Kalman filter (gating, coasting) and breakaway logic."""

from __future__ import annotations

import numpy as np
import pytest

from app.control.abort import predicted_miss_m, should_abort
from app.control.drogue_filter import DrogueFilter
from app.control.reference import GuidanceConfig, ReferenceGenerator


def test_filter_tracks_constant_velocity_and_gates_outlier():
    f = DrogueFilter(accel_sigma=0.5)
    rng = np.random.default_rng(0)
    r = np.eye(3) * 0.01**2
    dt = 0.02
    v = np.array([0.0, 0.3, -0.2])
    p = np.array([-14.0, 0.0, 4.0])
    for _k in range(200):
        f.predict(dt)
        p = p + v * dt
        assert f.update(p + rng.normal(0, 0.01, 3), r)
    assert np.allclose(f.velocity, v, atol=0.05)
    f.predict(dt)
    p = p + v * dt
    assert not f.update(p + np.array([0.0, 1.0, 0.0]), r)  # 1 m outlier is rejected
    assert np.linalg.norm(f.position - p) < 0.05
    for _ in range(10):
        f.predict(dt)
    assert f.coast_time_s > 0.2


def test_predicted_miss_and_abort_rules():
    rel = np.array([0.8, 0.1, 0.0])
    vel = np.array([-1.0, 0.5, 0.0])  # closing at 1 m/s, drifting 0.5 m/s sideways
    assert abs(predicted_miss_m(rel, vel) - (0.1 + 0.5 * 0.8)) < 1e-9
    assert should_abort(0.8, 0.5, 0.305, lock_lost=False) == "predicted_miss"
    assert should_abort(0.8, 0.1, 0.305, lock_lost=True) == "lock_lost"
    assert should_abort(3.0, 0.5, 0.305, lock_lost=False) is None  # outside the last metre


def test_reference_closes_at_commanded_speed_and_backs_off():
    g = ReferenceGenerator(GuidanceConfig(closure_speed_mps=1.2), start_gap_m=10.0)
    drogue = np.array([-14.0, 0.3, 4.0])
    ref = None
    for _ in range(100):  # 2 s
        ref, vel = g.update(0.02, drogue, np.zeros(3), True)
    assert ref is not None
    assert abs((drogue[0] - ref[0]) - (10.0 - 2.4)) < 1e-6
    assert np.allclose(ref[1:], drogue[1:])
    assert g.phase == "approach"
    for _ in range(300):  # 6 more s: gap 0.4 m, inside the final metre
        ref, vel = g.update(0.02, drogue, np.zeros(3), True)
    assert g.phase == "final"
    g.start_backoff()
    gap0 = g.gap_cmd
    ref, vel = g.update(0.02, drogue, np.zeros(3), False)
    assert g.phase == "backoff" and g.gap_cmd > gap0
    assert vel[0] < 0.0  # reference moves aft, away from the drogue


def _feed(f: DrogueFilter, z: np.ndarray, r: np.ndarray, n: int) -> list[bool]:
    """``n`` ticks of 20 ms, each a prediction and the fix ``z`` (covariance ``r``); the
    update results."""
    results = []
    for _ in range(n):
        f.predict(0.02)
        results.append(f.update(z, r))
    return results


def test_filter_reseeds_after_consistent_rejections():
    """If the drogue really jumped, consecutive consistent measurements re-seed the filter."""
    f = DrogueFilter(accel_sigma=0.5)
    r = np.eye(3) * 0.005**2
    p = np.array([-14.0, 0.0, 4.0])
    _feed(f, p, r, 50)
    jumped = p + np.array([0.0, 0.5, 0.0])
    assert _feed(f, jumped, r, 3) == [False, False, True]
    assert f.reseeds == 1
    assert np.allclose(f.position, jumped, atol=1e-6)


def test_filter_holds_a_lost_drogue_after_the_coast_limit():
    """Coasting past ``hold_after_s`` the estimate stops extrapolating its last velocity (a
    lost drogue is held where last seen; the reference does not drift away with it)."""
    f = DrogueFilter(hold_after_s=0.5)
    r = np.eye(3) * 1e-4
    for k in range(20):  # moving at 1 m/s along y
        f.predict(0.02)
        f.update(np.array([0.0, 0.02 * k, 0.0]), r)
    assert f.velocity[1] > 0.5
    for _ in range(25):  # 0.5 s: still extrapolating
        f.predict(0.02)
    moving = f.position[1]
    for _ in range(100):
        f.predict(0.02)
    assert f.position[1] == pytest.approx(moving, abs=0.03)
    assert np.all(f.velocity == 0.0)
    free = DrogueFilter()  # without the hold it keeps going
    free.x = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    free.initialised = True
    for _ in range(100):
        free.predict(0.02)
    assert free.position[1] == pytest.approx(2.0)


def _tracked(**kw: float) -> DrogueFilter:
    """A filter that has tracked a still drogue at the origin to a centimetre."""
    f = DrogueFilter(**kw)
    _feed(f, np.zeros(3), np.eye(3) * 0.01**2, 50)
    return f


def test_far_fixes_update_only_the_cross_stream_axes():
    """Fixes whose fore-aft σ exceeds the bound (a far stereo fix: its depth error is a
    calibration bias) move y and z and leave x alone — however many of them, however biased
    along x; a fix inside the bound updates all three."""
    f = _tracked(fore_aft_fix_sigma_max_m=1.0)
    far = np.diag([5.0**2, 0.05**2, 0.05**2])  # σ_x 5 m
    fix = np.array([12.0, 0.1, -0.05])  # 12 m too far along x (2.4 σ), 0.1 m aside
    # 2 s at 50 Hz, every fix inside the gate (2 σ across, 2.4 σ along)
    assert all(_feed(f, fix, far, 100))
    assert abs(f.position[0]) < 0.05  # the fore-aft estimate waits
    np.testing.assert_allclose(f.position[1:], fix[1:], atol=0.02)
    free = _tracked()  # without the bound: the same fixes drag x onto the bias
    _feed(free, fix, far, 100)
    assert free.position[0] > 4.0  # a third of the bias in 2 s, and walking on
    near = _tracked(fore_aft_fix_sigma_max_m=1.0)
    _feed(near, np.array([0.5, 0.0, 0.0]), np.eye(3) * 0.1**2, 100)
    assert near.position[0] == pytest.approx(0.5, abs=0.05)


def test_a_far_fix_reseeds_the_cross_stream_axes_and_keeps_the_fore_aft_estimate():
    f = _tracked(fore_aft_fix_sigma_max_m=1.0)
    far = np.diag([5.0**2, 0.01**2, 0.01**2])
    jumped = np.array([30.0, 0.5, 0.0])  # 0.5 m aside: a real jump across the stream
    assert _feed(f, jumped, far, 3) == [False, False, True]
    assert f.reseeds == 1
    np.testing.assert_allclose(f.position[1:], jumped[1:], atol=1e-6)
    assert abs(f.position[0]) < 0.01  # not 30 m
    p = f.P
    np.testing.assert_allclose(p, p.T)
    assert np.all(np.linalg.eigvalsh(p) >= -1e-12)
