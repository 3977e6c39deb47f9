"""Robustness of the docking loop to the plant spread (issue 13 follow-up).

The `standard` light failures were the plant draw: with the 30 ms actuator lag the Dutch roll of
some perturbed aircraft went unstable under the first observer (it trusted the design model's
unmeasured side velocity). These tests check the mechanism and the fix on the small-signal loop
(:mod:`app.control.margins`), the lag-aware LQR design against python-control, and one run.
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from app.control.design import AEROSONDE_WEIGHTS, design_controller
from app.control.lqr import IntegralLqr, augment_integral, augment_lag, discrete_lqr, lag_alpha
from app.control.margins import closed_loop_matrix, delay_margin_ticks, spectral_radius
from app.control.observer import StateObserver
from app.sim.docking import DockingConfig, DockingSimulation
from app.sim.imperfections import NONE, STANDARD, draw
from app.sim.receiver import FlightCondition, LinearReceiver, perturbed_params

DT = 0.02
RECEIVER = LinearReceiver(condition=FlightCondition(airspeed_mps=120.0, air_density=0.909))
DESIGN_SEEDS = range(100_000, 100_030)  # sampled plants of the design check (not campaign seeds)


@cache
def _models():  # type: ignore[no-untyped-def]
    return design_controller(RECEIVER.linear_model(), DT, (3.0, 0.0, -0.3), AEROSONDE_WEIGHTS)


def _plant(seed: int) -> tuple[np.ndarray, np.ndarray]:
    d = draw(STANDARD, seed)
    rec = LinearReceiver(
        params=perturbed_params(RECEIVER.params, d.aero_scale, d.mass_scale, d.inertia_scale),
        condition=RECEIVER.condition,
    )
    ad, bd, _ = rec.discretise(DT)
    return ad, bd


def _current_loop(**extra):  # type: ignore[no-untyped-def]
    return _models().margin_loop(DT, **extra)


@cache
def _first_tuning():  # type: ignore[no-untyped-def]
    """The gains before this fix (commit 933ab54): observer model uncertainty 1e-2 on u…r,
    LQR without the servo-lag model, its weights. Designed once: they depend only on the
    design model (``_models()``), not on the plant a loop closes them on."""
    m = _models()
    q0 = m.ed @ m.ed.T * 4.0 + np.diag([1e-2] * 6 + [0.0] * 6) + np.eye(12) * 1e-6
    obs = StateObserver(m.ad, m.bd, m.c_meas, q0, np.diag(m.meas_sigma**2))
    ctrl = IntegralLqr.design(
        m.ad,
        m.bd,
        m.c_tip,
        DT,
        np.array([2.0, 2.0, 2.0, 0.1, 0.1, 0.1, 10.0, 10.0, 10.0, 5.0, 600.0, 600.0]),
        np.array([3.0, 300.0, 300.0]),
        np.array([300.0, 4.0e5, 4.0e5, 4.0e5]),
    )
    gains = {"obs_gain": obs.gain, "kp": ctrl.kp, "ki": ctrl.ki}
    for name, g in gains.items():  # shared between tests: read-only copies
        gains[name] = np.array(g, dtype=np.float64)
        gains[name].setflags(write=False)
    return dict(**gains, ke=None, design_lag_s=0.0)


def _first_tuning_loop(**extra):  # type: ignore[no-untyped-def]
    """The loop before this fix with the first tuning's gains (:func:`_first_tuning`)."""
    return _models().margin_loop(DT, **_first_tuning(), **extra)


def test_every_sampled_standard_plant_keeps_40ms_of_delay_margin_with_the_lag() -> None:
    """Over 30 draws of the `standard` plant distribution, with its 30 ms actuator lag: the
    current loop keeps ≥ 2 ticks (40 ms) of extra input delay on every plant; the first
    tuning left some plant with < 2 ticks (the mechanism of the four light failures)."""
    plants = [_plant(s) for s in DESIGN_SEEDS]
    now = [delay_margin_ticks(max_ticks=2, **_current_loop(lag_s=0.03, plant=p)) for p in plants]
    before = [
        delay_margin_ticks(max_ticks=2, **_first_tuning_loop(lag_s=0.03, plant=p)) for p in plants
    ]
    assert min(now) >= 2
    assert min(before) < 2


@pytest.mark.parametrize("seed", [43, 155])
def test_the_failing_standard_plants_were_unstable_and_are_now_stable(seed: int) -> None:
    """Campaign seeds 43 and 155 (`standard`): Dutch roll (≈ 2.4–2.8 Hz) unstable under the first
    tuning with the 30 ms lag; the current loop is stable with ≥ 2 ticks of delay margin."""
    p = _plant(seed)
    m_before = closed_loop_matrix(**_first_tuning_loop(lag_s=0.03, plant=p))
    assert spectral_radius(m_before) > 1.0
    lam = np.linalg.eigvals(m_before)
    worst = lam[np.argmax(np.abs(lam))]
    assert 2.0 < abs(np.angle(worst)) / (2 * np.pi * DT) < 3.0  # Hz: the Dutch roll
    assert delay_margin_ticks(max_ticks=2, **_current_loop(lag_s=0.03, plant=p)) >= 2


def test_lag_aware_design_matches_python_control_and_the_margins_loop() -> None:
    m = _models()
    tau = m.lqr_design_lag_s
    assert tau > 0 and m.lqr_ke is not None
    # the gain is dlqr on [x, e, ζ] (plant behind the servo lag, then the integral of C x)
    a_l, b_l = augment_lag(m.ad, m.bd, lag_alpha(DT, tau))
    a_aug, b_aug = augment_integral(a_l, b_l, np.hstack([m.c_tip, np.zeros((3, 4))]), DT)
    q = np.diag(np.concatenate([np.full(16, 1.0), np.full(3, 10.0)]))
    r = np.diag([300.0, 1e5, 1e5, 1e5])
    p = solve_discrete_are(a_aug, b_aug, q, r)  # the DARE gain written out (scipy)
    k_dare = np.linalg.solve(r + b_aug.T @ p @ b_aug, b_aug.T @ p @ a_aug)
    assert np.allclose(discrete_lqr(a_aug, b_aug, q, r), k_dare, rtol=1e-5, atol=1e-8)
    # separation: with full-state "measurements" and the flown lag equal to the design lag, the
    # margins loop (observer, modelled deflection ê, lagged servos) contains the design
    # closed loop's eigenvalues
    ctrl = IntegralLqr(kp=m.lqr_kp, ki=m.lqr_ki, c=m.c_tip, dt=DT, ke=m.lqr_ke, design_lag_s=tau)
    design = np.linalg.eigvals(ctrl.closed_loop_matrix(m.ad, m.bd))
    assert np.max(np.abs(design)) < 1.0
    full = closed_loop_matrix(
        **{**_current_loop(lag_s=tau), "c_meas": np.eye(12), "obs_gain": np.eye(12)}
    )
    loop = np.linalg.eigvals(full)
    for lam in design:
        assert np.min(np.abs(loop - lam)) < 1e-6


def test_modelled_deflection_follows_the_servo_with_the_design_lag() -> None:
    m = _models()
    ctrl = IntegralLqr(kp=m.lqr_kp, ki=m.lqr_ki, c=m.c_tip, dt=DT, ke=m.lqr_ke, design_lag_s=0.03)
    step = np.array([0.0, 0.1, 0.0, 0.0])
    e = [ctrl.lag_step(step)[1] for _ in range(50)]
    k_tau = int(round(0.03 / DT))  # after one time constant (rounded to ticks): 1 − e^(−t/τ)
    assert e[k_tau - 1] == pytest.approx(0.1 * (1 - np.exp(-k_tau * DT / 0.03)), rel=1e-9)
    assert e[-1] == pytest.approx(0.1, rel=1e-6)
    no_lag = IntegralLqr(kp=m.lqr_kp, ki=m.lqr_ki, c=m.c_tip, dt=DT)
    np.testing.assert_array_equal(no_lag.lag_step(step), step)  # no model: the servo acts


def test_a_formerly_failing_standard_plant_now_captures() -> None:
    """Seed 43 (`standard`, its Dutch roll unstable under the first tuning) broke away four
    times even with perfect drogue measurements; it now captures on the first approach. (The
    plant's draw is the subject: the hose is the nominal one, as when the case was found.)"""
    sim = DockingSimulation(
        DockingConfig(
            turbulence="light",
            seed=43,
            vision=False,
            imperfections=replace(STANDARD, hose_frac=0.0),
            station_keep_s=0.5,
        )
    )
    out = sim.run()
    assert out.captured and out.aborts == 0 and out.recoveries == 0
    assert out.envelope.alpha_max_deg < 10.0 and out.envelope.bank_max_deg < 45.0


def test_hold_gap_on_lost_lock_rides_out_long_frame_drop_bursts() -> None:
    """Long bursts of dropped frames (mean 25 frames) lose the lock before the last metre: with
    ``hold_gap_on_lost_lock=False`` each loss breaks away (a fly-out to the standoff and a
    rejoin, ≈ 25 s each, or the run fails); with the default (True) the receiver holds its
    gap — never closing while unlocked — and captures once the drogue is tracked again."""
    imp = replace(NONE, name="long drops", drop_prob=0.05, drop_burst_mean=25.0)
    outcomes = {}
    for hold in (False, True):
        sim = DockingSimulation(
            DockingConfig(
                plant="linear",  # the guidance rule on the design model
                turbulence="light",
                seed=1,
                vision=False,
                imperfections=imp,
                station_keep_s=0.5,
                hold_gap_on_lost_lock=hold,
            )
        )
        unlocked_far = 0
        while not sim.done:
            gap_before = sim.guidance.gap_cmd
            phase_before = sim.guidance.phase
            tick = sim.step()
            if hold and not tick.lock and phase_before == "approach" and tick.phase == "approach":
                unlocked_far += 1
                assert sim.guidance.gap_cmd >= gap_before  # no closing while unlocked
        outcomes[hold] = sim.outcome()
        if hold:
            assert unlocked_far > 25  # the bursts did cost the lock for a while
    lost, held = outcomes[False], outcomes[True]
    assert lost.aborts >= 1  # the loss broke away
    assert held.captured and held.aborts <= 1
    assert held.time_to_capture_s is not None
    assert not lost.captured or lost.time_to_capture_s > held.time_to_capture_s + 15.0
