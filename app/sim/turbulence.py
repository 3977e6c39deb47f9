"""Dryden turbulence (MIL-F-8785C §3.7 / MIL-HDBK-1797), generated as shaped white noise.

Above 2000 ft the model is isotropic: ``σ_u = σ_v = σ_w = σ`` and ``L_u = L_v = L_w = 1750 ft``
(533.4 m). Spectra (ω in rad/s, airspeed V):

* ``H_u(s) = σ √(2L/(πV)) / (1 + (L/V) s)``
* ``H_v(s) = H_w(s) = σ √(L/(πV)) (1 + √3 (L/V) s) / (1 + (L/V) s)²``

Each filter is written in state space, discretised exactly at the tick (Van Loan), and its white
noise intensity chosen so that the stationary output standard deviation is exactly σ (the state is
also started from its stationary distribution, so there is no warm-up transient). Intensities σ
come from the MIL-HDBK-1797 high-altitude exceedance table (light ≈ 10⁻², moderate ≈ 10⁻³,
severe ≈ 10⁻⁵), interpolated linearly in altitude between the tabulated points quoted in
``/work/shared/notes/reference.md``. Output: gust velocity (m/s) in the tanker frame
(x forward, y right, z down): ``(u_g, v_g, w_g)`` with the longitudinal gust along +x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm, solve_discrete_lyapunov

from app.types import FloatArray

FT = 0.3048
LENGTH_SCALE_M = 1750.0 * FT  # MIL-F-8785C, h > 2000 ft
LEVELS = ("none", "light", "moderate", "severe")
# (altitude ft, σ light, σ moderate, σ severe) in m/s -- MIL-HDBK-1797 exceedance-probability table
_SIGMA_TABLE = np.array(
    [
        [7500.0, 2.0, 3.1, 7.2],
        [15000.0, 1.4, 2.4, 6.7],
        [25000.0, 0.8, 2.0, 6.1],
    ]
)


def dryden_sigma(level: str, altitude_m: float) -> float:
    """Turbulence intensity σ (m/s) for ``level`` at ``altitude_m`` (clamped to the table's span)."""
    if level not in LEVELS:
        raise ValueError(f"turbulence level must be one of {LEVELS}, got {level!r}")
    if level == "none":
        return 0.0
    col = LEVELS.index(level)
    alt_ft = altitude_m / FT
    if alt_ft < 2000.0:
        raise ValueError("the high-altitude Dryden model needs altitude above 2000 ft (610 m)")
    return float(np.interp(alt_ft, _SIGMA_TABLE[:, 0], _SIGMA_TABLE[:, col]))


def _discretise(a: FloatArray, b: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Exact discretisation of ``ẋ = a x + b n`` (n unit-intensity white noise): (Φ, Q_d)."""
    n = a.shape[0]
    m = np.zeros((2 * n, 2 * n))
    m[:n, :n] = -a
    m[:n, n:] = b @ b.T
    m[n:, n:] = a.T
    e = expm(m * dt)
    phi = e[n:, n:].T
    qd = phi @ e[:n, n:]
    return phi, 0.5 * (qd + qd.T)


@dataclass
class _ShapingFilter:
    phi: FloatArray
    chol: FloatArray  # Cholesky factor of Q_d
    c: FloatArray
    p_ss: FloatArray  # stationary covariance (for the start state)


def _make_filter(kind: str, sigma: float, length_m: float, v: float, dt: float) -> _ShapingFilter:
    tau = length_m / v
    if kind == "u":
        a = np.array([[-1.0 / tau]])
        b = np.array([[1.0]])
        c = np.array([[1.0]])
    else:
        # (1 + √3 τ s)/(1 + τ s)²  in controllable canonical form
        a = np.array([[0.0, 1.0], [-1.0 / tau**2, -2.0 / tau]])
        b = np.array([[0.0], [1.0]])
        c = np.array([[1.0 / tau**2, np.sqrt(3.0) / tau]])
    phi, qd = _discretise(a, b, dt)
    p_ss = solve_discrete_lyapunov(phi, qd)
    var = float((c @ p_ss @ c.T)[0, 0])
    scale = sigma / np.sqrt(var) if sigma > 0 else 0.0
    qd = qd * scale**2
    p_ss = p_ss * scale**2
    chol: FloatArray = np.asarray(np.linalg.cholesky(qd), float) if sigma > 0 else np.zeros_like(qd)
    return _ShapingFilter(phi=phi, chol=chol, c=c, p_ss=p_ss)


class DrydenTurbulence:
    """Seeded Dryden gust generator; ``step()`` returns the gust (m/s, tanker frame) for one tick."""

    def __init__(
        self,
        level: str,
        airspeed_mps: float,
        dt: float,
        altitude_m: float = 3000.0,
        seed: int = 0,
        length_scale_m: float = LENGTH_SCALE_M,
    ) -> None:
        if airspeed_mps <= 0 or dt <= 0:
            raise ValueError("airspeed and dt must be positive")
        self.level = level
        self.sigma_mps = dryden_sigma(level, altitude_m)
        self.length_scale_m = length_scale_m
        self.dt = dt
        self._filters = [
            _make_filter(k, self.sigma_mps, length_scale_m, airspeed_mps, dt)
            for k in ("u", "v", "w")
        ]
        self.reset(seed)

    def reset(self, seed: int) -> None:
        self._rng = np.random.default_rng(seed)
        self._states: list[FloatArray] = []
        for f in self._filters:
            if self.sigma_mps > 0:
                x0 = self._rng.multivariate_normal(np.zeros(len(f.p_ss)), f.p_ss)
            else:
                x0 = np.zeros(len(f.p_ss))
            self._states.append(np.asarray(x0, float))

    def current(self) -> FloatArray:
        return np.array(
            [float((f.c @ x)[0]) for f, x in zip(self._filters, self._states, strict=True)]
        )

    def step(self) -> FloatArray:
        """Advance one tick; return the gust velocity (u_g, v_g, w_g) in m/s."""
        for i, f in enumerate(self._filters):
            n = self._rng.standard_normal(len(self._states[i]))
            self._states[i] = f.phi @ self._states[i] + f.chol @ n
        return self.current()
