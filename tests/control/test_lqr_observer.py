"""Closed-loop stability of the docking controller (eq. 20) and observer convergence (eq. 19)."""

from __future__ import annotations

import control
import numpy as np
from scipy.linalg import solve_continuous_are, solve_discrete_are

from app.control.design import A4_WEIGHTS, AEROSONDE_WEIGHTS, design_controller
from app.control.lqr import IntegralLqr, augment_integral, continuous_lqr, discrete_lqr
from app.control.observer import StateObserver, continuous_observer_gain
from app.sim.receiver import FlightCondition, LinearReceiver

DT = 0.02
RECEIVER = LinearReceiver(condition=FlightCondition(airspeed_mps=120.0, air_density=0.909))


def _models():
    return design_controller(RECEIVER.linear_model(), DT, (3.0, 0.0, -0.3), AEROSONDE_WEIGHTS)


def test_receiver_trim_is_an_equilibrium_and_open_loop_has_unstable_or_neutral_modes():
    rec = LinearReceiver()
    # trim residual: the linear model's drift at x = 0, u = 0 is zero by construction; check the
    # nonlinear model directly: straight-and-level, no acceleration
    from app.sim.receiver import nonlinear_dynamics

    xd = nonlinear_dynamics(
        rec.params, rec.condition, rec.t_max, rec.x_trim, rec.u_trim, np.zeros(3)
    )
    assert np.allclose(xd[:9], 0.0, atol=1e-6)
    assert np.allclose(xd[9:], 0.0, atol=1e-6)  # moves with the tanker
    # position states are pure integrators: the open loop is not asymptotically stable
    assert np.max(np.linalg.eigvals(rec.A).real) >= -1e-9


def test_discrete_integral_lqr_closed_loop_inside_unit_circle():
    m = _models()
    ctrl = IntegralLqr(
        kp=m.lqr_kp, ki=m.lqr_ki, c=m.c_tip, dt=DT, ke=m.lqr_ke, design_lag_s=m.lqr_design_lag_s
    )
    eig = np.linalg.eigvals(ctrl.closed_loop_matrix(m.ad, m.bd))
    assert eig.shape == (15 + (4 if m.lqr_ke is not None else 0),)
    assert np.max(np.abs(eig)) < 1.0


def _dare_gain(ad, bd, q, r):
    """The DARE gain written out from scipy's Riccati solver (independent of python-control,
    which :func:`discrete_lqr` calls)."""
    p = solve_discrete_are(ad, bd, q, r)
    return np.linalg.solve(r + bd.T @ p @ bd, bd.T @ p @ ad)


def test_discrete_lqr_is_the_dare_gain():
    m = _models()
    a_aug, b_aug = augment_integral(m.ad, m.bd, m.c_tip, DT)
    q = np.diag(np.concatenate([AEROSONDE_WEIGHTS.q_state, AEROSONDE_WEIGHTS.q_int]))
    r = np.diag(AEROSONDE_WEIGHTS.r)
    k_ours = discrete_lqr(a_aug, b_aug, q, r)
    assert np.allclose(k_ours, _dare_gain(a_aug, b_aug, q, r), rtol=1e-5, atol=1e-8)


def _lag_rate_integral_plant(ad, bd, c, alpha, rate):
    """The design's augmented plant written out block by block (not with app.control.lqr's
    ``augment_*``): state ``[x, e_{k−1}, (u_{k−1},) ζ]``, input ``u_k`` (or ``Δu_k`` with
    ``rate``), the servo lag ``e_k = e_{k−1} + α (u_k − e_{k−1})``, ``ζ_{k+1} = ζ_k + Δt C x``."""
    n, m = bd.shape
    p = c.shape[0]
    a_ = np.diag(alpha)
    blocks_a = [[ad, bd @ (np.eye(m) - a_)], [np.zeros((m, n)), np.eye(m) - a_]]
    blocks_b = [[bd @ a_], [a_]]
    if rate:  # u_k = u_{k−1} + Δu_k: u_{k−1} feeds the lag like the input does
        blocks_a = [[*row, rb[0]] for row, rb in zip(blocks_a, blocks_b, strict=True)]
        blocks_a.append([np.zeros((m, n)), np.zeros((m, m)), np.eye(m)])
        blocks_b.append([np.eye(m)])
    a = np.block(blocks_a)
    b = np.block(blocks_b)
    k = a.shape[0]
    a_full = np.block([[a, np.zeros((k, p))], [DT * c, np.zeros((p, k - n)), np.eye(p)]])
    b_full = np.vstack([b, np.zeros((p, m))])
    return a_full, b_full


def _relative_error(k, k_ref):
    return float(np.linalg.norm(k - k_ref) / np.linalg.norm(k_ref))


def test_lag_aware_and_rate_weighted_designs_are_the_dare_gain_of_their_augmented_plant():
    """IntegralLqr.design (python-control's dlqr with integral action) gives, to 1e-6 relative,
    the DARE gain of the augmented plant written out here, solved with scipy: the lag-aware
    form (the Aerosonde's) and the rate-weighted form (the A-4's weights, per-input lags)."""
    m = _models()
    n, n_in = m.bd.shape
    w = AEROSONDE_WEIGHTS
    lags = (0.1, 0.03, 0.03, 0.03)  # s: an engine's spool-up, three servos
    alpha = 1.0 - np.exp(-DT / np.asarray(lags))
    q_state, q_int, r = (np.asarray(v, float) for v in (w.q_state, w.q_int, w.r))
    r_rate = np.asarray(A4_WEIGHTS.r_rate, float)

    plain = IntegralLqr.design(m.ad, m.bd, m.c_tip, DT, q_state, q_int, r, design_lag_s=lags)
    a, b = _lag_rate_integral_plant(m.ad, m.bd, m.c_tip, alpha, rate=False)
    q = np.diag(np.concatenate([q_state, np.zeros(n_in), q_int]))
    k_ref = _dare_gain(a, b, q, np.diag(r))
    k = np.hstack([plain.kp, plain.ke, plain.ki])
    assert _relative_error(k, k_ref) < 1e-6

    rated = IntegralLqr.design(
        m.ad, m.bd, m.c_tip, DT, q_state, q_int, r, design_lag_s=lags, r_rate=r_rate
    )
    a, b = _lag_rate_integral_plant(m.ad, m.bd, m.c_tip, alpha, rate=True)
    q = np.diag(np.concatenate([q_state, np.zeros(n_in), r, q_int]))
    k_ref = _dare_gain(a, b, q, np.diag(r_rate))
    k = np.hstack([rated.kp, rated.ke, rated.ku, rated.ki])
    assert k.shape == (n_in, n + 2 * n_in + 3)
    assert _relative_error(k, k_ref) < 1e-6


def test_continuous_eq20_gain_places_poles_in_left_half_plane():
    rec = LinearReceiver()
    n = 12
    c = np.zeros((3, n))
    c[:, 9:] = np.eye(3)
    a = np.zeros((15, 15))
    a[:n, :n] = rec.A
    a[n:, :n] = c
    b = np.vstack([rec.B, np.zeros((3, 4))])
    q = np.diag(np.concatenate([AEROSONDE_WEIGHTS.q_state, AEROSONDE_WEIGHTS.q_int]))
    r = np.diag(AEROSONDE_WEIGHTS.r)
    k = continuous_lqr(a, b, q, r)
    eig = np.linalg.eigvals(a - b @ k)
    assert np.max(eig.real) < 0.0
    p = solve_continuous_are(a, b, q, r)  # eq. 20 written out (scipy, not python-control)
    assert np.allclose(k, np.linalg.solve(r, b.T @ p), rtol=1e-5, atol=1e-8)


def test_continuous_observer_gain_eq19_matches_python_control_lqe():
    rec = LinearReceiver()
    c = np.zeros((9, 12))
    for row, idx in enumerate(range(3, 12)):
        c[row, idx] = 1.0
    q0 = np.eye(12) * 0.1
    r0 = np.eye(9) * 0.01
    gain = continuous_observer_gain(rec.A, c, q0, r0)
    gain_ctrl, _, _ = control.lqe(rec.A, np.eye(12), c, q0, r0)
    assert np.allclose(gain, gain_ctrl, rtol=1e-5, atol=1e-8)
    assert np.max(np.linalg.eigvals(rec.A - gain @ c).real) < 0.0


def test_observer_converges_from_wrong_initial_state():
    m = _models()
    obs = StateObserver(m.ad, m.bd, m.c_meas, m.ed @ m.ed.T + np.eye(12) * 1e-6, np.eye(9) * 1e-4)
    assert np.max(np.abs(np.linalg.eigvals(obs.error_matrix()))) < 1.0
    rng = np.random.default_rng(3)
    x = np.zeros(12)
    x_hat0 = np.array([4.0, -2.0, 1.5, 0.2, -0.1, 0.1, 0.1, -0.05, 0.08, 3.0, -2.0, 1.0])
    obs.reset(x_hat0)
    e0 = np.linalg.norm(obs.x_hat - x)
    u = np.zeros(4)
    for _ in range(int(10.0 / DT)):  # 10 s, small random inputs to excite the plant
        u = rng.normal(0.0, [0.02, 0.002, 0.002, 0.002])
        x = m.ad @ x + m.bd @ u
        obs.update(u, m.c_meas @ x)
    assert np.linalg.norm(obs.x_hat - x) < 1e-3 * e0
