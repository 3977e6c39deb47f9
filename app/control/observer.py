"""State observer with a Riccati gain (paper §6.1, eq. 19).

Eq. 19 writes the observer gain ``L = P₀ C'ᵀ R₀⁻¹`` with P₀ the solution of the filter Riccati
equation; :func:`continuous_observer_gain` is that formula. The simulation runs at a fixed tick,
so :class:`StateObserver` uses its discrete counterpart (steady-state Kalman gain from
``solve_discrete_are`` on the dual system) in predictor–corrector form.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_continuous_are, solve_discrete_are

from app.types import FloatArray


def continuous_observer_gain(
    a: FloatArray, c: FloatArray, q0: FloatArray, r0: FloatArray
) -> FloatArray:
    """Eq. 19: ``L = P₀ Cᵀ R₀⁻¹``, ``A P₀ + P₀ Aᵀ − P₀ Cᵀ R₀⁻¹ C P₀ + Q₀ = 0``."""
    p0 = solve_continuous_are(a.T, c.T, q0, r0)
    return np.asarray(p0 @ c.T @ np.linalg.inv(r0))


class StateObserver:
    """Discrete observer ``x̂⁺ = x̂⁻ + L (y − C x̂⁻)``, ``x̂⁻ = A_d x̂ + B_d u``."""

    def __init__(
        self, ad: FloatArray, bd: FloatArray, c: FloatArray, q0: FloatArray, r0: FloatArray
    ) -> None:
        self.ad, self.bd, self.c = ad, bd, c
        p = solve_discrete_are(ad.T, c.T, q0, r0)
        self.gain = p @ c.T @ np.linalg.inv(c @ p @ c.T + r0)
        self.x_hat = np.zeros(ad.shape[0])

    def reset(self, x0: FloatArray | None = None) -> None:
        self.x_hat = np.zeros(self.ad.shape[0]) if x0 is None else np.asarray(x0, float).copy()

    def error_matrix(self) -> FloatArray:
        """Estimation-error transition ``(I − L C) A_d`` (stable iff all |λ| < 1)."""
        n = self.ad.shape[0]
        return np.asarray((np.eye(n) - self.gain @ self.c) @ self.ad)

    def update(self, u_prev: FloatArray, y: FloatArray) -> FloatArray:
        """Predict with the last applied input, correct with measurement ``y``; return x̂."""
        x_pred = self.ad @ self.x_hat + self.bd @ u_prev
        self.x_hat = x_pred + self.gain @ (y - self.c @ x_pred)
        return self.x_hat
