"""The guidance's bow-wave feed-forward (app.control.bow_wave) against the hose–drogue model it
stands for (app.sim.hose_drogue, stepped by its own integrator), the closure feed-forward
against the design model's equations, and the standoff hold of the reference generator."""

from __future__ import annotations

import numpy as np
import pytest

from app.control.bow_wave import BowWaveModel, bow_force_n
from app.control.design import closure_feedforward
from app.control.reference import GuidanceConfig, ReferenceGenerator
from app.sim.hose_drogue import HoseDrogue, HoseDrogueParams
from app.sim.receiver import LinearReceiver

A4_DROGUE = HoseDrogueParams(air_density=0.771, airspeed_mps=147.5)


def _approach(closure: float, horizon: float, dt: float = 0.02) -> tuple[HoseDrogue, list]:
    """The hose–drogue model pushed by a nose closing straight in at ``closure`` m/s from
    5 m behind the drogue, 0.5 m left of and 0.3 m below it (an A-4-like probe offset)."""
    d = HoseDrogue(A4_DROGUE)
    nose0 = d.eq_m + np.array([-5.0, -0.5, 0.3])
    axis = np.array([1.0, 0.0, 0.0])
    states = []
    for k in range(int(round(horizon / dt))):
        nose = nose0 + axis * closure * k * dt
        d.step(dt, np.zeros(3), d.bow_wave_force(nose, axis))
        states.append((nose.copy(), d.d.copy(), d.v.copy()))
    return d, states


def test_force_is_the_hose_drogue_models():
    d = HoseDrogue(A4_DROGUE)
    d.reset(np.array([0.0, 0.1, -0.05]))
    for nose in ([-3.0, -0.5, 0.3], [-1.0, 0.2, 0.0], [0.5, 0.0, 0.0]):
        n = d.eq_m + np.array(nose)
        axis = np.array([0.999, 0.0, -0.0447])
        axis /= np.linalg.norm(axis)
        np.testing.assert_allclose(
            bow_force_n(A4_DROGUE.guidance_model(), d.position_m, n, axis),
            d.bow_wave_force(n, axis),
            atol=1e-12,
        )


def test_the_model_run_alongside_reproduces_the_pushed_drogue():
    dt = 0.02
    _, states = _approach(1.2, 4.0, dt)
    model = BowWaveModel(A4_DROGUE.guidance_model())
    d = HoseDrogue(A4_DROGUE)
    axis = np.array([1.0, 0.0, 0.0])
    for nose, d_true, _ in states:
        model.step(dt, bow_force_n(A4_DROGUE.guidance_model(), d.position_m, nose, axis))
        d.step(dt, np.zeros(3), d.bow_wave_force(nose, axis))
        np.testing.assert_allclose(model.d, d.d[1:], atol=1e-9)
        np.testing.assert_allclose(d.d, d_true, atol=1e-12)
    assert np.linalg.norm(model.d) > 0.1  # the push is real: > 10 cm at the nose


@pytest.mark.parametrize("closure", [0.8, 1.2, 1.6])
def test_forecast_predicts_the_push_at_the_arrival(closure):
    """From 2 s into the approach, forecast where the push has the drogue when the nose has
    closed to 0.6 m (the probe at the drogue): within 1.5 cm of the stepped model (the
    forecast holds the force's direction fixed; the model turns it as the drogue moves)."""
    dt = 0.02
    gap0, arrive = 5.0, (5.0 - 0.6) / closure
    _, states = _approach(closure, arrive, dt)
    k0 = int(round(2.0 / dt))
    nose, d0, v0 = states[k0 - 1]
    model = BowWaveModel(A4_DROGUE.guidance_model())
    model.d, model.v = d0[1:].copy(), v0[1:].copy()
    direction = np.array([0.5, -0.3 - A4_DROGUE.bow_up_bias_m])
    direction /= np.linalg.norm(direction)
    nose_gap = gap0 - closure * k0 * dt
    got = model.forecast(arrive - k0 * dt, nose_gap, closure, direction)
    truth = states[-1][1][1:]
    assert np.linalg.norm(truth) > 0.08
    np.testing.assert_allclose(got, truth, atol=0.015)


def test_forecast_without_force_is_the_free_swing_and_zero_horizon_the_present():
    params = HoseDrogueParams(air_density=0.771, airspeed_mps=147.5, bow_force_n=0)
    model = BowWaveModel(params.guidance_model())
    model.d, model.v = np.array([0.2, -0.1]), np.array([0.0, 0.1])
    d = HoseDrogue(params)
    d.reset(np.array([0.0, 0.2, -0.1]))
    d.v = np.array([0.0, 0.0, 0.1])
    for _ in range(50):
        d.step(0.02, np.zeros(3))
    np.testing.assert_allclose(
        model.forecast(1.0, 2.0, 1.2, np.array([1.0, 0.0])), d.d[1:], atol=0.01
    )
    np.testing.assert_allclose(model.forecast(0.0, 2.0, 1.2, np.array([1.0, 0.0])), model.d)


def test_closure_feedforward_is_a_steady_closure_of_the_design_model():
    model = LinearReceiver().linear_model()
    x, u = closure_feedforward(model)
    xdot = model.a @ x + model.b @ u
    np.testing.assert_allclose(xdot[:9], 0.0, atol=1e-9)  # velocities, rates, angles steady
    np.testing.assert_allclose(xdot[9:], [1.0, 0.0, 0.0], atol=1e-9)  # 1 m/s closing, no drift
    assert u[0] > 0  # more thrust to fly faster than the tanker


def test_standoff_hold_waits_for_the_commit_then_closes_through():
    cfg = GuidanceConfig(closure_speed_mps=1.2, standoff_gap_m=1.5)
    g = ReferenceGenerator(cfg, start_gap_m=4.0)
    drogue, vel, dt = np.array([-20.0, 0.0, 4.0]), np.zeros(3), 0.02
    for _ in range(500):  # 10 s: reaches the standoff (slowing down into it) and holds
        ref, ref_vel = g.update(dt, drogue, vel, lock=True, commit=False)
    assert g.holding and g.gap_cmd == pytest.approx(1.5)
    assert ref[0] == pytest.approx(drogue[0] - 1.5) and ref_vel[0] == 0.0
    g.update(dt, drogue, vel, lock=False, commit=True)  # no lock: no commit
    assert g.holding
    g.update(dt, drogue, vel, lock=True, commit=True)
    assert g.committed and not g.holding
    for _ in range(100):  # committed: closes through whatever the guidance says now
        g.update(dt, drogue, vel, lock=True, commit=False)
    assert g.gap_cmd == pytest.approx(-cfg.overshoot_m, abs=0.03)
    g.start_backoff()
    assert not g.committed


def test_without_standoff_the_closure_never_holds():
    g = ReferenceGenerator(GuidanceConfig(closure_speed_mps=1.2), start_gap_m=2.0)
    for _ in range(50):
        g.update(0.02, np.zeros(3), np.zeros(3), lock=True, commit=False)
    assert not g.holding and g.gap_cmd == pytest.approx(2.0 - 1.2)
