"""app.sim.jsbsim_plant: JSBSim's A-4 as the receiver plant, against JSBSim's own numbers and
against the linear model designed on it (the FDM is the independent reference here)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from app.sim.jsbsim_plant import (
    FT_M,
    SETTLE_STEPS,
    JsbsimCondition,
    JsbsimPlant,
    JsbsimUnavailable,
    substeps_for,
)
from app.sim.plant import LinearPlant

TICK_HZ = 50.0


@cache
def plant() -> JsbsimPlant:
    return JsbsimPlant(JsbsimCondition(), TICK_HZ)


def test_trim_at_the_refuelling_condition_is_an_equilibrium():
    p = JsbsimPlant(JsbsimCondition(), TICK_HZ)
    t = p.trim
    assert t.altitude_ft == pytest.approx(15000.0, abs=1.0)
    assert t.kcas == pytest.approx(230.0, abs=0.1)
    assert 140.0 < t.tas_mps < 155.0 and 2.0 < t.alpha_deg < 5.0 and 0.2 < t.throttle < 0.8
    assert t.weight_lbs == pytest.approx(13250.0, abs=1.0)
    res = p.trim_residual()  # after FGTrim and the settling steps
    assert np.all(np.abs(res[:3]) < 1e-3), res  # m/s²
    assert np.all(np.abs(res[3:]) < 1e-3), res  # rad/s²
    # the state in the design coordinates starts at zero (position: the offset asked for)
    x = p.reset(np.array([0.0] * 9 + [-10.0, 0.3, -0.2]))
    np.testing.assert_allclose(x, [0.0] * 9 + [-10.0, 0.3, -0.2], atol=1e-6)
    with pytest.raises(ValueError):
        p.reset(np.array([1.0] + [0.0] * 11))


def test_design_model_eigenvalues_equal_jsbsims_linearisation():
    p = plant()
    ours = np.linalg.eigvals(p.model.a[:9, :9])
    fgl = p.fgl_eigenvalues()
    for lam in fgl:
        if abs(lam) < 1e-6:
            continue  # ψ: a free integrator in both
        k = int(np.argmin(np.abs(ours - lam)))
        assert abs(ours[k] - lam) <= 0.01 * abs(lam), (lam, ours[k])
    # the modes the A-4 is known for at this condition (docs/models.md): a short period of
    # ωn ≈ 2.7 rad/s, a phugoid of ≈ 68 s, a yaw-damped Dutch roll
    sp = max((lam for lam in fgl if lam.imag > 1.5), key=lambda lam: -lam.real)
    assert 2.0 < abs(sp) < 3.5
    ph = [lam for lam in fgl if 0.05 < lam.imag < 0.15]
    assert ph and 50.0 < 2 * np.pi / ph[0].imag < 90.0


def _fly(plant_obj, inputs, air=None):
    xs = []
    for k, u in enumerate(inputs):
        xs.append(plant_obj.step(u, np.zeros(3) if air is None else air[k]))
    return np.array(xs)


def _doublet(n: int, channel: int, amp: float, start: int = 5, width: int = 25) -> np.ndarray:
    u = np.zeros((n, 4))
    u[start : start + width, channel] = amp
    u[start + width : start + 2 * width, channel] = -amp
    return u


@pytest.mark.parametrize(
    ("channel", "states"),
    [(2, (2, 4, 7)), (1, (3, 6, 1))],  # elevator: w, q, θ; aileron: p, φ, v
)
def test_small_doublet_matches_the_linear_model_for_the_first_seconds(channel, states):
    p = plant()
    lin = LinearPlant(p.model, 1.0 / TICK_HZ, "linear A-4", p.trim)
    n = 150  # 3 s
    u = _doublet(n, channel, 0.02)
    p.reset(np.zeros(12))
    lin.reset(np.zeros(12))
    fdm, model = _fly(p, u), _fly(lin, u)
    for s in states:
        peak = np.max(np.abs(fdm[:, s]))
        assert peak > 0
        assert np.max(np.abs(fdm[:, s] - model[:, s])) <= 0.15 * peak, s


def test_a_large_manoeuvre_leaves_the_linear_model():
    """Full aileron for 2 s rolls the A-4 past 90°: the linear model's prediction of the
    bank, the heading and the height is then far off — the plant really is nonlinear."""
    p = plant()
    lin = LinearPlant(p.model, 1.0 / TICK_HZ, "linear A-4", p.trim)
    n = 200
    u = np.zeros((n, 4))
    u[:100, 1] = 0.8
    p.reset(np.zeros(12))
    lin.reset(np.zeros(12))
    fdm, model = _fly(p, u), _fly(lin, u)
    assert np.max(np.abs(fdm[:, 6])) > np.radians(90)
    worst = max(
        np.max(np.abs(fdm[:, s] - model[:, s])) / np.max(np.abs(fdm[:, s])) for s in (6, 8, 11)
    )
    assert worst > 0.5


def test_a_gust_enters_the_fdm_as_the_linear_model_says():
    """1 m/s of air moving down: α falls by atan(1/V) at once, and the response of the first
    second matches the model's gust input (E)."""
    p = plant()
    lin = LinearPlant(p.model, 1.0 / TICK_HZ, "linear A-4", p.trim)
    n = 50
    air = np.tile([0.0, 0.0, 1.0], (n, 1))
    p.reset(np.zeros(12))
    lin.reset(np.zeros(12))
    alpha0 = p.fdm["aero/alpha-rad"]
    p.step(np.zeros(4), air[0])
    d_alpha = p.fdm["aero/alpha-rad"] - alpha0
    assert d_alpha == pytest.approx(-np.arctan(1.0 / p.trim.tas_mps), rel=0.05)
    p.reset(np.zeros(12))
    fdm, model = _fly(p, np.zeros((n, 4)), air), _fly(lin, np.zeros((n, 4)), air)
    for s in (2, 4, 7):  # w, q, θ
        peak = np.max(np.abs(fdm[:, s]))
        assert np.max(np.abs(fdm[:, s] - model[:, s])) <= 0.15 * peak, s


def test_jsbsim_integrates_every_tick_at_120_hz_or_more():
    assert substeps_for(50.0) == 3 and substeps_for(25.0) == 5 and substeps_for(120.0) == 1
    p = plant()
    p.reset(np.zeros(12))
    t0 = p.fdm_time_s
    for _ in range(10):
        p.step(np.zeros(4), np.zeros(3))
    assert p.dt_fdm <= 1.0 / 120.0
    assert p.fdm_time_s - t0 == pytest.approx(10 / TICK_HZ, abs=1e-9)
    assert t0 == pytest.approx(SETTLE_STEPS * p.dt_fdm, abs=1e-9)


def test_gust_properties_are_written_in_feet_per_second():
    p = plant()
    p.reset(np.zeros(12))
    p.step(np.zeros(4), np.array([1.0, -2.0, 0.5]))
    got = [p.fdm[f"atmosphere/gust-{a}-fps"] for a in ("north", "east", "down")]
    np.testing.assert_allclose(np.array(got) * FT_M, [1.0, -2.0, 0.5], atol=1e-9)


def test_unknown_airframe_or_condition_is_refused():
    with pytest.raises(ValueError):
        JsbsimPlant(JsbsimCondition(aircraft="c172x"), TICK_HZ)
    with pytest.raises(ValueError):
        JsbsimPlant(JsbsimCondition(kcas=20.0), TICK_HZ)


def test_an_untrimmable_condition_is_a_clear_error():
    with pytest.raises(JsbsimUnavailable, match="cannot trim"):
        JsbsimPlant(JsbsimCondition(fuel_lbs=0.0), TICK_HZ)  # an empty tank: the J52 is out
