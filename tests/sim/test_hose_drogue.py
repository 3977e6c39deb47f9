"""Reduced-order hose–drogue: statics and dynamics against the closed-form derivation."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.hose_drogue import HoseDrogue, HoseDrogueParams


def test_parameters_give_flight_scale_drag_close_to_reel_tension():
    p = HoseDrogueParams()
    # ½ ρ V² Cd π r² at 3000 m, 120 m/s vs the quoted 1610 N reel tension
    assert p.drag_n == pytest.approx(0.5 * 0.909 * 120**2 * 0.8 * np.pi * 0.305**2)
    assert 1300 < p.drag_n < 1800


def test_steady_cross_gust_aligns_hose_with_relative_wind():
    p = HoseDrogueParams()
    d = HoseDrogue(p)
    gust = np.array([0.0, 2.0, -1.0])
    for _ in range(int(120.0 / 0.02)):
        d.step(0.02, gust)
    expected = p.hose_length_m * gust[1:] / p.airspeed_mps  # L g / V
    assert np.allclose(d.d[1:], expected, rtol=0.02, atol=1e-4)


def test_free_swing_period_and_decay_match_second_order_model():
    p = HoseDrogueParams()
    d = HoseDrogue(p, substeps=20)
    d.reset(np.array([0.0, 0.5, 0.0]))
    dt = 0.005
    ys, ts = [], []
    for k in range(int(30.0 / dt)):
        d.step(dt, np.zeros(3))
        ys.append(d.d[1])
        ts.append((k + 1) * dt)
    y = np.array(ys)
    t = np.array(ts)
    up = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    crossings = t[up] - y[up] * dt / (y[up + 1] - y[up])
    period = float(np.mean(np.diff(crossings)))
    wd = p.omega_rad_s * np.sqrt(1 - p.damping_ratio**2)
    assert period == pytest.approx(2 * np.pi / wd, rel=0.02)
    assert 0.05 < p.damping_ratio < 0.2


def test_bow_wave_pushes_drogue_up_and_away_when_nose_is_close():
    d = HoseDrogue()
    axis = np.array([1.0, 0.0, 0.0])
    nose_far = d.position_m - np.array([20.0, 0.1, 0.0])
    nose_near = d.position_m - np.array([1.0, 0.1, 0.0])  # nose slightly left of the drogue
    f_far = d.bow_wave_force(nose_far, axis)
    f_near = d.bow_wave_force(nose_near, axis)
    assert np.linalg.norm(f_near) > 20 * np.linalg.norm(f_far)
    assert f_near[2] < 0.0  # up (z down)
    assert f_near[1] > 0.0  # away from the nose axis (drogue is to the right of it)
