"""Compiled loops of stereo triangulation (numba, cached on disk): the paper's linear least
squares (eqs. 15–16) and the Gauss–Newton refinement of the reprojection error in both images,
one 3×3 normal-equation solve per point and per step. From Python the small batched array
calls cost more than this arithmetic. Called by :mod:`app.geometry.triangulation`, which
documents the formulas; ``tests/geometry/test_geometry.py`` checks them against
``cv2.triangulatePoints``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _solve3(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """x with a·x = b for one 3×3 system (Gaussian elimination, partial pivoting); NaN when
    singular."""
    m = np.empty((3, 4))
    for i in range(3):
        for j in range(3):
            m[i, j] = a[i, j]
        m[i, 3] = b[i]
    for col in range(3):
        piv = col
        for r in range(col + 1, 3):
            if abs(m[r, col]) > abs(m[piv, col]):
                piv = r
        if m[piv, col] == 0.0:
            return np.full(3, np.nan)
        if piv != col:
            for j in range(4):
                m[col, j], m[piv, j] = m[piv, j], m[col, j]
        for r in range(col + 1, 3):
            f = m[r, col] / m[col, col]
            for j in range(col, 4):
                m[r, j] -= f * m[col, j]
    x = np.empty(3)
    for i in range(2, -1, -1):
        acc = m[i, 3]
        for j in range(i + 1, 3):
            acc -= m[i, j] * x[j]
        x[i] = acc / m[i, i]
    return x


@njit(cache=True, nogil=True)
def linear_kernel(
    P_left: np.ndarray, P_right: np.ndarray, xl: np.ndarray, xr: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """Eqs. 15–16 per point: X (N×3, mm) = (MᵀM)⁻¹MᵀU from the ideal pixels ``xl``, ``xr``
    (N×2) and the projection matrices (3×4); NaN where MᵀM is singular."""
    n = xl.shape[0]
    out = np.empty((n, 3))
    mtm = np.empty((3, 3))
    mtu = np.empty(3)
    row = np.empty(3)
    for p in range(n):
        mtm[:] = 0.0
        mtu[:] = 0.0
        for cam in range(2):
            P = P_left if cam == 0 else P_right
            x = xl if cam == 0 else xr
            for k in range(2):
                c = x[p, k]
                for j in range(3):
                    row[j] = c * P[2, j] - P[k, j]
                u = P[k, 3] - c * P[2, 3]
                for i in range(3):
                    mtu[i] += row[i] * u
                    for j in range(3):
                        mtm[i, j] += row[i] * row[j]
        out[p] = _solve3(mtm, mtu)
    return out


@njit(cache=True, nogil=True)
def _residuals_kernel(
    P: np.ndarray, X: np.ndarray, x: np.ndarray, r: np.ndarray, J: np.ndarray, col: int
) -> None:  # pragma: no cover - compiled
    """Residuals (projection − x, px) of one image into r[:, col:col+2], their Jacobian
    (d/dX, px/mm) into J[:, col:col+2, :]."""
    for p in range(X.shape[0]):
        h0 = P[0, 0] * X[p, 0] + P[0, 1] * X[p, 1] + P[0, 2] * X[p, 2] + P[0, 3]
        h1 = P[1, 0] * X[p, 0] + P[1, 1] * X[p, 1] + P[1, 2] * X[p, 2] + P[1, 3]
        w = P[2, 0] * X[p, 0] + P[2, 1] * X[p, 1] + P[2, 2] * X[p, 2] + P[2, 3]
        u, v = h0 / w, h1 / w
        r[p, col] = u - x[p, 0]
        r[p, col + 1] = v - x[p, 1]
        for j in range(3):  # d(u)/dX = (P_0 − u·P_2)/w, d(v)/dX = (P_1 − v·P_2)/w
            J[p, col, j] = (P[0, j] - u * P[2, j]) / w
            J[p, col + 1, j] = (P[1, j] - v * P[2, j]) / w


@njit(cache=True, nogil=True)
def refine_kernel(
    P_left: np.ndarray,
    P_right: np.ndarray,
    xl: np.ndarray,
    xr: np.ndarray,
    X0: np.ndarray,
    iterations: int,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Gauss–Newton from ``X0`` (N×3, mm) on the 4 reprojection residuals per point, at
    most ``iterations`` steps (stops when every step is below 1e-9 mm): (X N×3 mm, RMS
    reprojection N px)."""
    n = X0.shape[0]
    X = X0.copy()
    r = np.empty((n, 4))
    J = np.empty((n, 4, 3))
    jtj = np.empty((3, 3))
    jtr = np.empty(3)
    for _ in range(iterations):
        _residuals_kernel(P_left, X, xl, r, J, 0)
        _residuals_kernel(P_right, X, xr, r, J, 2)
        biggest = 0.0
        for p in range(n):
            for i in range(3):
                jtr[i] = 0.0
                for k in range(4):
                    jtr[i] -= J[p, k, i] * r[p, k]
                for j in range(3):
                    acc = 1e-12 if i == j else 0.0
                    for k in range(4):
                        acc += J[p, k, i] * J[p, k, j]
                    jtj[i, j] = acc
            delta = _solve3(jtj, jtr)
            for i in range(3):
                X[p, i] += delta[i]
                if not abs(delta[i]) <= biggest:  # NaN propagates as the largest step
                    biggest = abs(delta[i]) if delta[i] == delta[i] else np.inf
        if biggest < 1e-9:
            break
    _residuals_kernel(P_left, X, xl, r, J, 0)
    _residuals_kernel(P_right, X, xr, r, J, 2)
    rms = np.empty(n)
    for p in range(n):
        rms[p] = np.sqrt((r[p, 0] ** 2 + r[p, 1] ** 2 + r[p, 2] ** 2 + r[p, 3] ** 2) / 4.0)
    return X, rms
