"""The online swing identification against oscillations made without it: scipy's exact
discretisation of a damped oscillator driven by white noise (``scipy.signal``), and inputs with
no resonance at all."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from app.control.swing_identifier import SwingIdentifier
from app.model.drogue import DrogueModel

NOMINAL = DrogueModel(
    omega_rad_s=1.6,
    damping_ratio=0.08,
    effective_mass_kg=50.0,
    bow_force_n=60.0,
    bow_length_m=1.5,
    bow_up_bias_m=0.3,
    rest_m=(-14.0, 0.0, 4.0),
)
DT = 0.02  # the docking loop's tick (s)


def swing_record(omega: float, zeta: float, seconds: float, seed: int) -> np.ndarray:
    """Lateral and vertical swing (m, 0.4 m RMS) of ẍ + 2ζω ẋ + ω² x = w, w white, plus 1 cm
    of measurement noise."""
    rng = np.random.default_rng(seed)
    n = int(seconds / DT)
    plant = ss.StateSpace([[0, 1], [-(omega**2), -2 * zeta * omega]], [[0], [1]], [[1, 0]], [[0]])
    disc = plant.to_discrete(DT)
    axes = [ss.dlsim(disc, rng.normal(size=n))[1][:, 0] for _ in range(2)]
    x = np.array(axes).T
    return x / x.std() * 0.4 + rng.normal(0.0, 0.01, x.shape)


@pytest.mark.parametrize(("omega", "zeta"), [(2.0, 0.09), (1.2, 0.15), (1.6, 0.05)])
def test_identifies_a_noise_driven_oscillator(omega: float, zeta: float) -> None:
    """120 s of swing. Over 8 seeds the fit's spread is ≤ 2 % in ω and ≤ 0.017 in ζ (1σ): the
    tolerances are ≈ 2.5σ."""
    ident = SwingIdentifier(NOMINAL, DT)
    for x in swing_record(omega, zeta, 120.0, seed=int(omega * 100)):
        ident.update(x)
    est = ident.estimate()
    assert est.identified
    assert est.omega_rad_s == pytest.approx(omega, rel=0.05)
    assert est.damping_ratio == pytest.approx(zeta, abs=0.045)


def test_the_nominal_model_until_enough_swing_was_seen() -> None:
    ident = SwingIdentifier(NOMINAL, DT)
    record = swing_record(2.0, 0.09, 90.0, seed=1)
    for x in record[: int(5.0 / DT)]:  # 5 s: fewer samples than the fit needs
        ident.update(x)
    est = ident.estimate()
    assert not est.identified
    assert (est.omega_rad_s, est.damping_ratio) == (NOMINAL.omega_rad_s, NOMINAL.damping_ratio)
    quiet = SwingIdentifier(NOMINAL, DT)
    for x in record * 0.01:  # a drogue at rest (4 mm RMS): nothing to identify
        quiet.update(x)
    assert not quiet.estimate().identified and quiet.samples == 0


def test_gaps_in_the_measurements_do_not_bias_the_fit() -> None:
    """The estimate coasts while the drogue is out of sight: those ticks must not enter the
    regression (a frozen estimate looks like a very slow, heavily damped motion)."""
    ident = SwingIdentifier(NOMINAL, DT)
    record = swing_record(2.0, 0.09, 120.0, seed=2)
    held = record[0]
    for k, x in enumerate(record):
        measured = (k // 250) % 3 != 2  # out of sight 5 s in every 15 s
        held = x if measured else held
        ident.update(held, measured)
    est = ident.estimate()
    assert est.identified and est.omega_rad_s == pytest.approx(2.0, rel=0.05)


def test_no_resonance_gives_the_nominal_model() -> None:
    """White noise (no oscillator behind it) has no lightly damped pole pair in range."""
    rng = np.random.default_rng(3)
    ident = SwingIdentifier(NOMINAL, DT)
    for x in rng.normal(0.0, 0.3, (int(90.0 / DT), 2)):
        ident.update(x)
    assert not ident.estimate().identified
