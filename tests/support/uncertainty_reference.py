"""numpy formulations of :mod:`app.geometry.uncertainty`'s compiled steps, for the tests."""

from __future__ import annotations

import numpy as np


def chi2_by_eigh(S: np.ndarray, y: np.ndarray, n: int) -> float:
    """T = yᵀ S⁺ y on the top 3N − 6 eigen-directions of S scaled to unit diagonal (the
    statistic of :func:`~app.geometry.uncertainty.fit_consistency`); N = 3: the epipolar
    residuals only."""
    dof = 3 * n - 6
    if n == 3:
        S, y = S[:n, :n], y[:n]
    scale = np.sqrt(np.diag(S))
    lam, vec = np.linalg.eigh(S / np.outer(scale, scale))
    proj = vec.T @ (y / scale)
    return float(np.sum(proj[-dof:] ** 2 / lam[-dof:]))
