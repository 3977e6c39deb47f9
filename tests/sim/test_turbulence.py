"""Dryden gusts: intensity and correlation match the spec; seeded determinism."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.turbulence import LENGTH_SCALE_M, DrydenTurbulence, dryden_sigma


def _series(level: str, seed: int, n: int, dt: float = 0.1, v: float = 120.0) -> np.ndarray:
    turb = DrydenTurbulence(level, v, dt, altitude_m=3000.0, seed=seed)
    return np.array([turb.step() for _ in range(n)])


def test_sigma_table_interpolation_at_tabulated_altitudes():
    ft = 0.3048
    assert dryden_sigma("light", 7500 * ft) == pytest.approx(2.0)
    assert dryden_sigma("moderate", 15000 * ft) == pytest.approx(2.4)
    assert dryden_sigma("severe", 25000 * ft) == pytest.approx(6.1)
    assert dryden_sigma("none", 3000.0) == 0.0
    with pytest.raises(ValueError):
        dryden_sigma("extreme", 3000.0)
    with pytest.raises(ValueError):
        dryden_sigma("light", 100.0)


@pytest.mark.parametrize("level", ["light", "moderate", "severe"])
def test_output_sigma_within_15_percent_of_spec(level: str):
    sigma = dryden_sigma(level, 3000.0)
    g = _series(level, seed=11, n=60_000)  # 6000 s ≈ 1350 correlation times L/V
    measured = g.std(axis=0)
    assert np.all(np.abs(measured / sigma - 1.0) < 0.15), measured / sigma


def test_longitudinal_autocorrelation_is_exponential_with_length_scale():
    dt, v = 0.1, 120.0
    g = _series("moderate", seed=5, n=60_000, dt=dt, v=v)[:, 0]
    g = g - g.mean()
    lag = int(round(LENGTH_SCALE_M / v / dt))  # one correlation time: ρ = e^-1 for H_u
    rho = float(np.dot(g[:-lag], g[lag:]) / np.dot(g, g))
    assert abs(rho - np.exp(-1.0)) < 0.1


def test_seeded_determinism_and_none_level():
    a = _series("light", seed=7, n=500)
    b = _series("light", seed=7, n=500)
    c = _series("light", seed=8, n=500)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    assert np.all(_series("none", seed=1, n=50) == 0.0)
