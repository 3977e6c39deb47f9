"""Stereo triangulation: the paper's linear least squares (eqs. 15–16) and a refinement
minimising the reprojection error in both images. Inputs are ideal (undistorted) pixels."""

from __future__ import annotations

import numpy as np

from app.geometry.calibration import FloatArray


def triangulate_linear(
    P_left: FloatArray, P_right: FloatArray, x_left: FloatArray, x_right: FloatArray
) -> FloatArray:
    """Eqs. 15–16: X = (MᵀM)⁻¹ MᵀU, with rows ``u·h₃ − h₁`` (N×3, mm).

    M (4×3) stacks, per image, ``u·h_{31..33} − h_{11..13}`` and ``v·h_{31..33} − h_{21..23}``;
    U (4) stacks ``h_{14} − u·h_{34}`` and ``h_{24} − v·h_{34}``.
    """
    xl = np.asarray(x_left, dtype=np.float64).reshape(-1, 2)
    xr = np.asarray(x_right, dtype=np.float64).reshape(-1, 2)
    rows_m = []
    rows_u = []
    for P, x in ((P_left, xl), (P_right, xr)):
        for k in (0, 1):
            coord = x[:, k : k + 1]
            rows_m.append(coord * P[2, :3] - P[k, :3])
            rows_u.append(P[k, 3] - x[:, k] * P[2, 3])
    M = np.stack(rows_m, axis=1)  # (N, 4, 3)
    U = np.stack(rows_u, axis=1)  # (N, 4)
    MtM = np.einsum("nki,nkj->nij", M, M)
    MtU = np.einsum("nki,nk->ni", M, U)
    return np.asarray(np.linalg.solve(MtM, MtU[..., None])[..., 0], dtype=np.float64)


def _residuals_and_jacobian(
    P: FloatArray, X: FloatArray, x: FloatArray
) -> tuple[FloatArray, FloatArray]:
    h = X @ P[:, :3].T + P[:, 3]
    w = h[:, 2:3]
    proj = h[:, :2] / w
    r = proj - x
    # d(u)/dX = (P_0 − u·P_2)/w, d(v)/dX = (P_1 − v·P_2)/w
    J = (P[None, :2, :3] - proj[:, :, None] * P[None, 2:3, :3]) / w[:, :, None]
    return r, J


def reprojection_rms(
    P_left: FloatArray, P_right: FloatArray, x_left: FloatArray, x_right: FloatArray, X: FloatArray
) -> FloatArray:
    """RMS reprojection error (px) per point over both images (4 residuals per point)."""
    rl, _ = _residuals_and_jacobian(P_left, X, x_left)
    rr, _ = _residuals_and_jacobian(P_right, X, x_right)
    return np.asarray(np.sqrt((np.sum(rl**2, axis=1) + np.sum(rr**2, axis=1)) / 4.0))


def refine_reprojection(
    P_left: FloatArray,
    P_right: FloatArray,
    x_left: FloatArray,
    x_right: FloatArray,
    X0: FloatArray,
    iterations: int = 5,
) -> tuple[FloatArray, FloatArray]:
    """Gauss–Newton on the 4 reprojection residuals per point (the maximum-likelihood point
    under isotropic pixel noise). Returns (X mm N×3, RMS reprojection px N)."""
    xl = np.asarray(x_left, dtype=np.float64).reshape(-1, 2)
    xr = np.asarray(x_right, dtype=np.float64).reshape(-1, 2)
    X = np.array(X0, dtype=np.float64).reshape(-1, 3)
    for _ in range(iterations):
        rl, Jl = _residuals_and_jacobian(P_left, X, xl)
        rr, Jr = _residuals_and_jacobian(P_right, X, xr)
        r = np.concatenate([rl, rr], axis=1)  # (N, 4)
        J = np.concatenate([Jl, Jr], axis=1)  # (N, 4, 3)
        JtJ = np.einsum("nki,nkj->nij", J, J)
        Jtr = np.einsum("nki,nk->ni", J, r)
        delta = np.linalg.solve(JtJ + 1e-12 * np.eye(3), -Jtr[..., None])[..., 0]
        X = X + delta
        if float(np.max(np.abs(delta), initial=0.0)) < 1e-9:
            break
    return X, reprojection_rms(P_left, P_right, xl, xr, X)
