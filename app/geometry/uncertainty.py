"""First-order error bounds of a lock: LED points, ring centre/normal/radius, a protection
level, and a χ² test that the lock's own residuals agree with them.

Noise model: each LED centroid is measured in the DISTORTED image with isotropic Gaussian
noise of standard deviation σ (px, per LED and per image), independent between LEDs and
images. Everything is linearised at the lock (first order); the tests check the result
against Monte-Carlo runs of an independent OpenCV path.

* :func:`point_covariances` — covariance (mm²) of each triangulated point (eqs. 15–16 and
  the reprojection refinement of :mod:`app.geometry.triangulation`). σ is mapped to ideal
  (undistorted) pixels through the 2×2 Jacobian of the undistortion (inverse of eq. 7) at the
  measured pixel; J is the 4×3 Jacobian of the ideal projections (eqs. 4–5) at X.
* :func:`ring_covariance` — the point covariances propagated through the plane + circle fit
  (§5.2, eqs. 17–18's role, :func:`~app.geometry.circle_fit.fit_circle_3d`), its Jacobian in
  closed form at the points' closest points on the circle.
* :func:`protection_level_mm` / :func:`led_protection_levels_mm` — radius PL with
  P(‖e‖ > PL) = p_exceed for e ~ N(0, Σ) in 3-D: the exact quantile of the generalised χ²
  ‖e‖² = Σ λᵢ zᵢ² (see :func:`protection_level_mm`).
* :func:`fit_consistency` — χ² test of the lock's epipolar and circle residuals against the
  covariance (3N − 6 degrees of freedom for N LEDs).

The per-point and per-node arithmetic runs in compiled loops (numba, cached on disk; ~13 s
to compile on first use). :func:`lock_terms` gives a lock's covariances and χ² statistic in
one compiled call (≈ 0.07 ms for 5 LEDs, the whole bound with its protection levels; the
three separate functions cost ≈ 0.3 ms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
from numba import njit
from numpy.polynomial.legendre import leggauss
from scipy.special import chdtrc, chdtri

from app.geometry.calibration import FloatArray, StereoCalibration
from app.geometry.circle_fit import Circle3D, FitError, plane_axes

_MINOR_ROWS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])  # rows kept per minor


# ---- stereo: per-point Jacobians, measurement covariance, gains -------------------------
@njit(cache=True, nogil=True)
def _distort(
    dist: np.ndarray, x: float, y: float
) -> tuple[float, float, float, float, float]:  # pragma: no cover - compiled
    """Eq. 7 (OpenCV's k1, k2, p1, p2, k3) at normalised (x, y): (x_d, y_d, ∂x_d/∂x,
    ∂x_d/∂y = ∂y_d/∂x, ∂y_d/∂y)."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r²
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    jxx = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x
    jxy = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y
    jyy = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, jxx, jxy, jyy


@njit(cache=True, nogil=True)
def _camera_terms(
    K: np.ndarray, dist: np.ndarray, P: np.ndarray, X: np.ndarray, px: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """One point in one camera: (J 2×3 = ∂(ideal px)/∂X (px/mm), D 2×2 = ∂(distorted px)/
    ∂(ideal px) at the measured pixel, r 2 = measured pixel undistorted − projection of X)."""
    h0 = P[0, 0] * X[0] + P[0, 1] * X[1] + P[0, 2] * X[2] + P[0, 3]
    h1 = P[1, 0] * X[0] + P[1, 1] * X[1] + P[1, 2] * X[2] + P[1, 3]
    w = P[2, 0] * X[0] + P[2, 1] * X[1] + P[2, 2] * X[2] + P[2, 3]
    u, v = h0 / w, h1 / w
    J = np.empty((2, 3))
    for j in range(3):
        J[0, j] = (P[0, j] - u * P[2, j]) / w
        J[1, j] = (P[1, j] - v * P[2, j]) / w
    fx, g, u0, fy, v0 = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    # undistort the measured pixel: K⁻¹ (eq. 2), then Newton on eq. 7 from X's projection
    yt = (px[1] - v0) / fy
    xt = (px[0] - u0 - g * yt) / fx
    y = (v - v0) / fy
    x = (u - u0 - g * y) / fx
    for _ in range(20):
        xd, yd, jxx, jxy, jyy = _distort(dist, x, y)
        det = jxx * jyy - jxy * jxy
        dx = (jyy * (xd - xt) - jxy * (yd - yt)) / det
        dy = (jxx * (yd - yt) - jxy * (xd - xt)) / det
        x -= dx
        y -= dy
        if abs(dx) + abs(dy) < 1e-15:
            break
    _, _, jxx, jxy, jyy = _distort(dist, x, y)
    # D = K₂ · ∂(x_d, y_d)/∂(x, y) · K₂⁻¹ with K₂ = [[fx, γ], [0, fy]]
    a00, a01 = fx * jxx + g * jxy, fx * jxy + g * jyy
    a10, a11 = fy * jxy, fy * jyy
    D = np.empty((2, 2))
    D[0, 0] = a00 / fx
    D[0, 1] = a01 / fy - a00 * g / (fx * fy)
    D[1, 0] = a10 / fx
    D[1, 1] = a11 / fy - a10 * g / (fx * fy)
    r = np.empty(2)
    r[0] = fx * x + g * y + u0 - u
    r[1] = fy * y + v0 - v
    return J, D, r


@njit(cache=True, nogil=True)
def _left_null(J: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Unit a (4) with aᵀJ = 0 for a 4×3 J: the signed 3×3 minors."""
    a = np.empty(4)
    for i in range(4):
        r0, r1, r2 = _MINOR_ROWS[i, 0], _MINOR_ROWS[i, 1], _MINOR_ROWS[i, 2]
        m = (
            J[r0, 0] * (J[r1, 1] * J[r2, 2] - J[r1, 2] * J[r2, 1])
            - J[r0, 1] * (J[r1, 0] * J[r2, 2] - J[r1, 2] * J[r2, 0])
            + J[r0, 2] * (J[r1, 0] * J[r2, 1] - J[r1, 1] * J[r2, 0])
        )
        a[i] = m if i % 2 == 0 else -m
    return a / np.sqrt(a @ a)


@njit(cache=True, nogil=True)
def _mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """a·b for small matrices (a loop beats a BLAS call at these sizes)."""
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            aik = a[i, k]
            for j in range(b.shape[1]):
                out[i, j] += aik * b[k, j]
    return out


@njit(cache=True, nogil=True)
def _inv2(m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Inverse of a 2×2 matrix."""
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    inv = np.empty((2, 2))
    inv[0, 0], inv[0, 1] = m[1, 1] / det, -m[0, 1] / det
    inv[1, 0], inv[1, 1] = -m[1, 0] / det, m[0, 0] / det
    return inv


@njit(cache=True, nogil=True)
def _inv3(m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Inverse of a 3×3 matrix (adjugate / determinant)."""
    inv = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            a, b = (j + 1) % 3, (j + 2) % 3
            c, d = (i + 1) % 3, (i + 2) % 3
            inv[i, j] = m[a, c] * m[b, d] - m[a, d] * m[b, c]
    det = m[0, 0] * inv[0, 0] + m[0, 1] * inv[1, 0] + m[0, 2] * inv[2, 0]
    return inv / det


@njit(cache=True, nogil=True)
def _stereo_kernel(
    K_l: np.ndarray,
    dist_l: np.ndarray,
    P_l: np.ndarray,
    K_r: np.ndarray,
    dist_r: np.ndarray,
    P_r: np.ndarray,
    left_px: np.ndarray,
    right_px: np.ndarray,
    X: np.ndarray,
    sigma_l: np.ndarray,
    sigma_r: np.ndarray,
    weighted: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Per point: (Σ_X 3×3 mm², gain B 3×4 with δX = B·δx, C 4×4 ideal-px covariance,
    unit a 4 with aᵀJ = 0, epipolar residual e = aᵀ·residual px)."""
    n = X.shape[0]
    cov = np.empty((n, 3, 3))
    gain = np.empty((n, 3, 4))
    C = np.zeros((n, 4, 4))
    null = np.empty((n, 4))
    epi = np.empty(n)
    J = np.empty((4, 3))
    W = np.zeros((4, 4))
    for p in range(n):
        Jl, Dl, rl = _camera_terms(K_l, dist_l, P_l, X[p], left_px[p])
        Jr, Dr, rr = _camera_terms(K_r, dist_r, P_r, X[p], right_px[p])
        J[0:2] = Jl
        J[2:4] = Jr
        for cam in range(2):
            D = Dl if cam == 0 else Dr
            s2 = sigma_l[p] ** 2 if cam == 0 else sigma_r[p] ** 2
            A = _inv2(D)  # ∂(ideal px)/∂(distorted px)
            o = 2 * cam
            for i in range(2):
                for j in range(2):
                    C[p, o + i, o + j] = s2 * (A[i, 0] * A[j, 0] + A[i, 1] * A[j, 1])
                    W[o + i, o + j] = (D[0, i] * D[0, j] + D[1, i] * D[1, j]) / s2
        if weighted:
            JtW = _mm(J.T.copy(), W)
            info_inv = _inv3(_mm(JtW, J))
            gain[p] = _mm(info_inv, JtW)
            cov[p] = info_inv
        else:
            B = _mm(_inv3(_mm(J.T.copy(), J)), J.T.copy())
            gain[p] = B
            cov[p] = _mm(_mm(B, C[p]), B.T.copy())
        a = _left_null(J)
        null[p] = a
        epi[p] = a[0] * rl[0] + a[1] * rl[1] + a[2] * rr[0] + a[3] * rr[1]
    return cov, gain, C, null, epi


def _sigmas(sigma: FloatArray | float, n: int, name: str) -> FloatArray:
    if isinstance(sigma, np.ndarray) and sigma.dtype == np.float64 and sigma.shape == (n,):
        s = sigma.copy()  # (the common case: one σ per point already)
    else:
        s = np.broadcast_to(np.asarray(sigma, dtype=np.float64).reshape(-1), (n,)).copy()
    if not all(0.0 < v < math.inf for v in s.tolist()):
        raise ValueError(f"{name} must be positive and finite (px)")
    return s


# K, dist, P of the left then the right camera; left px, right px, points mm; σ left, σ right
StereoArgs = tuple[
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
]


def _stereo_inputs(
    calib: StereoCalibration,
    left_px: FloatArray,
    right_px: FloatArray,
    X_mm: FloatArray,
    sigma_left_px: FloatArray | float,
    sigma_right_px: FloatArray | float,
) -> StereoArgs:
    """The compiled stereo loops' arguments: both cameras' K, distortion and P, the centroids
    (N×2 px), the points (N×3 mm) and each image's σ (N, px; validated)."""
    X = np.ascontiguousarray(np.asarray(X_mm, dtype=np.float64).reshape(-1, 3))
    n = len(X)
    return (
        *calib.kernel_arrays,
        np.ascontiguousarray(np.asarray(left_px, dtype=np.float64).reshape(n, 2)),
        np.ascontiguousarray(np.asarray(right_px, dtype=np.float64).reshape(n, 2)),
        X,
        _sigmas(sigma_left_px, n, "sigma_left_px"),
        _sigmas(sigma_right_px, n, "sigma_right_px"),
    )


def _stereo_terms(
    calib: StereoCalibration,
    left_px: FloatArray,
    right_px: FloatArray,
    X_mm: FloatArray,
    sigma_left_px: FloatArray | float,
    sigma_right_px: FloatArray | float,
    weighted: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    out = _stereo_kernel(
        *_stereo_inputs(calib, left_px, right_px, X_mm, sigma_left_px, sigma_right_px),
        bool(weighted),
    )
    return out  # type: ignore[no-any-return]


def point_covariances(
    calib: StereoCalibration,
    left_px: FloatArray,
    right_px: FloatArray,
    X_mm: FloatArray,
    sigma_left_px: FloatArray | float,
    sigma_right_px: FloatArray | float,
    weighted: bool = False,
) -> FloatArray:
    """Covariance (N×3×3, mm²) of each triangulated point (eqs. 15–16 + refinement).

    ``left_px``/``right_px`` (N×2): the measured, DISTORTED centroids (px); ``X_mm`` (N×3): the
    triangulated points (left camera frame, mm); ``sigma_*_px``: isotropic centroid noise σ in
    distorted px, a scalar or one per point. Per image, the ideal-pixel covariance is
    C = σ² A Aᵀ, A = D⁻¹ the undistortion Jacobian (inverse of eq. 7) at the measured pixel.
    With J the 4×3 Jacobian of both ideal projections (eqs. 4–5) at X and W = C⁻¹:

    * ``weighted=False`` (default): the estimator the pipeline runs —
      :func:`~app.geometry.triangulation.refine_reprojection` minimises the UNweighted
      reprojection error — so Σ_X = B C Bᵀ with B = (JᵀJ)⁻¹Jᵀ (the sandwich form). It equals
      (JᵀWJ)⁻¹ when both images have the same σ (up to the distortion's anisotropy, < 1 %),
      and is larger otherwise: across the epipolar lines (image y for this rig) 9.5× the
      variance for σ = 0.05 px in one image and 0.3 px in the other.
    * ``weighted=True``: Σ_X = (JᵀWJ)⁻¹, the covariance of the maximum-likelihood point
      (weighted by W), which an unweighted estimator does not reach.
    """
    return _stereo_terms(calib, left_px, right_px, X_mm, sigma_left_px, sigma_right_px, weighted)[0]


# ---- ring: Jacobians of the circle fit ----------------------------------------------------
@njit(cache=True, nogil=True)
def _circle_residuals(
    pts: np.ndarray, c: np.ndarray, nrm: np.ndarray, radius: float
) -> np.ndarray:  # pragma: no cover - compiled
    """(2N) per point: signed distance from the plane (along nrm, mm), then in-plane radial
    distance − radius (mm)."""
    n = pts.shape[0]
    out = np.empty(2 * n)
    for p in range(n):
        d = pts[p] - c
        off = d @ nrm
        q = d - off * nrm
        out[2 * p] = off
        out[2 * p + 1] = np.sqrt(q @ q) - radius
    return out


@njit(cache=True, nogil=True)
def _fit_jacobians(
    pts: np.ndarray, c: np.ndarray, nrm: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """(∂θ/∂p 7×3N, ∂ρ/∂p 2N×3N) of the plane + circle fit at points ON the circle (c, unit
    nrm, radius): θ = (centre, normal signed like nrm, radius), ρ the points' residuals from
    their own refitted circle. NaN when the points do not define a circle.

    At zero residual the fit is first-order the least-squares solution of the linearised
    residuals (the TLS plane is the least-squares plane of the off-plane offsets; Kåsa +
    Gauss–Newton in it the least-squares circle of the radial distances; the plane's tilt
    moves the radial distances at second order only). With u_k the unit radial of point k,
    (e1, e2) in-plane axes and ψ = (δc 3, tilt t1, t2, δr):
    off_k = n·δp_k − n·δc + r·(t1 u_k·e1 + t2 u_k·e2), radial_k = u_k·δp_k − u_k·δc − δr,
    i.e. ρ = A ψ + B δp; the fit takes ψ = −(AᵀA)⁻¹AᵀB δp, and ∂ρ/∂p = B + A ∂ψ/∂p.
    (Tested against central differences of :func:`~app.geometry.circle_fit.fit_circle_3d`.)
    """
    n = pts.shape[0]
    e1, e2 = plane_axes(nrm)
    A = np.zeros((2 * n, 6))
    B = np.zeros((2 * n, 3 * n))
    for k in range(n):
        u = (pts[k] - c) / radius
        for i in range(3):
            A[2 * k, i] = -nrm[i]
            A[2 * k + 1, i] = -u[i]
            B[2 * k, 3 * k + i] = nrm[i]
            B[2 * k + 1, 3 * k + i] = u[i]
        A[2 * k, 3] = radius * (u @ e1)
        A[2 * k, 4] = radius * (u @ e2)
        A[2 * k + 1, 5] = -1.0
    jt = np.full((7, 3 * n), np.nan)
    jr = np.full((2 * n, 3 * n), np.nan)
    ata = A.T @ A
    # a singular system (collinear points, fewer than 3): no circle, NaN Jacobians
    if (
        n < 3
        or not np.all(np.isfinite(ata))
        or abs(np.linalg.det(ata)) < 1e-12 * max(1.0, radius) ** 8
    ):
        return jt, jr
    G = -np.linalg.solve(ata, A.T @ B)  # ∂ψ/∂p, 6×3N
    jt[0:3] = G[0:3]
    for i in range(3):
        jt[3 + i] = e1[i] * G[3] + e2[i] * G[4]
    jt[6] = G[5]
    jr[:] = B + A @ G
    return jt, jr


def _center_normal(circle: Circle3D) -> tuple[FloatArray, FloatArray]:
    nrm = np.asarray(circle.normal, dtype=np.float64).reshape(3)
    x, y, z = nrm.tolist()
    norm = math.sqrt(x * x + y * y + z * z)  # (cheaper than np.linalg.norm for 3 terms)
    return np.asarray(circle.center, dtype=np.float64).reshape(3), nrm / norm


@njit(cache=True, nogil=True)
def _ring_terms(
    pts: np.ndarray, c: np.ndarray, nrm: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """(∂θ/∂p 7×3N, ∂ρ/∂p 2N×3N) of the circle fit (see :func:`_fit_jacobians`), linearised at
    the points' closest points on the circle: the model's estimate of the true configuration.
    There the residuals have exactly 2N − 6 dof; at the measured points the fit's response to
    a point sliding along the ring is not zero (∝ its residual), a noise-induced term that
    first-order theory does not have (it made the 8 m ring's centre covariance ~25 % high and
    the consistency test's null space ill-defined). NaN when there is no such circle."""
    n = pts.shape[0]
    on = np.empty((n, 3))
    for k in range(n):
        d = pts[k] - c
        q = d - (d @ nrm) * nrm
        on[k] = c + radius * q / np.sqrt(q @ q)
    return _fit_jacobians(on, c, nrm, radius)


def _ring_jacobians(points_mm: FloatArray, circle: Circle3D) -> tuple[FloatArray, FloatArray]:
    """:func:`_ring_terms` of these points and ``circle`` (``FitError`` when degenerate)."""
    pts = np.ascontiguousarray(np.asarray(points_mm, dtype=np.float64).reshape(-1, 3))
    if len(pts) < 3 or not np.all(np.isfinite(pts)):
        raise FitError("a circle needs at least 3 finite points")
    c, nrm = _center_normal(circle)
    jt, jr = _ring_terms(pts, c, nrm, float(circle.radius))
    if not (np.all(np.isfinite(jt)) and np.all(np.isfinite(jr))):
        raise FitError("the circle fit is degenerate at these points")
    return jt, jr


def _propagate(jac: FloatArray, point_cov: FloatArray) -> FloatArray:
    """Σ_k J_k Σ_k J_kᵀ for J (m×3N) and independent points' Σ_k (N×3×3)."""
    n = len(point_cov)
    jk = jac.reshape(jac.shape[0], n, 3)
    return np.asarray(np.einsum("aki,kij,bkj->ab", jk, point_cov, jk, optimize=False))


@dataclass(frozen=True)
class RingCovariance:
    """First-order covariance of the ring fit (§5.2). ``normal_cov`` is of the unit normal
    (dimensionless; rank 2, in the ring plane: its eigenvalues are tilt variances in rad²)."""

    center_cov_mm2: FloatArray  # (3, 3) mm²
    normal_cov: FloatArray  # (3, 3)
    radius_var_mm2: float  # mm²


def ring_covariance(
    points_mm: FloatArray,
    point_cov: FloatArray,
    circle: Circle3D,
) -> RingCovariance:
    """Covariance of the centre, unit normal and radius of ``circle`` =
    :func:`~app.geometry.circle_fit.fit_circle_3d` (``points_mm``), optionally oriented.

    J = ∂(centre, normal, radius)/∂(3N coordinates) of ``fit_circle_3d`` in closed form
    (:func:`_fit_jacobians`), the refitted normal signed like ``circle.normal``, taken at the
    points' closest points on ``circle`` (see :func:`_ring_jacobians`); Σ = Σ_k J_k Σ_k J_kᵀ
    (points independent, ``point_cov`` N×3×3 mm² from :func:`point_covariances`). The
    Jacobians are kept for :func:`fit_consistency` of the same lock (a small cache).
    """
    jt, _ = _ring_jacobians(points_mm, circle)
    cov = _propagate(jt, np.asarray(point_cov, dtype=np.float64).reshape(-1, 3, 3))
    return RingCovariance(
        center_cov_mm2=cov[0:3, 0:3].copy(),
        normal_cov=cov[3:6, 3:6].copy(),
        radius_var_mm2=float(cov[6, 6]),
    )


# ---- a lock's terms in one call ------------------------------------------------------------
@njit(cache=True, nogil=True)
def _largest_eigenvalue_sym3(m: np.ndarray) -> float:  # pragma: no cover - compiled
    """λ_max of a symmetric 3×3 matrix in closed form (the trigonometric solution of the
    characteristic cubic; equal to ``np.linalg.eigvalsh(m)[-1]`` to rounding, tested); NaN
    when ``m`` is not finite."""
    a00, a11, a22 = m[0, 0], m[1, 1], m[2, 2]
    a01, a02, a12 = m[0, 1], m[0, 2], m[1, 2]
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    if not math.isfinite(p1 + q):
        return np.nan
    d0, d1, d2 = a00 - q, a11 - q, a22 - q
    p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1
    if p2 == 0.0:  # a multiple of the identity
        return q
    p = math.sqrt(p2 / 6.0)
    # r = det((m − q·I) / p) / 2, in [−1, 1] up to rounding
    det = d0 * (d1 * d2 - a12 * a12) - a01 * (a01 * d2 - a12 * a02) + a02 * (a01 * a12 - d1 * a02)
    r = det / (2.0 * p * p * p)
    r = min(1.0, max(-1.0, r))
    return q + 2.0 * p * math.cos(math.acos(r) / 3.0)


@njit(cache=True, nogil=True)
def _lock_kernel(
    K_l: np.ndarray,
    dist_l: np.ndarray,
    P_l: np.ndarray,
    K_r: np.ndarray,
    dist_r: np.ndarray,
    P_r: np.ndarray,
    left_px: np.ndarray,
    right_px: np.ndarray,
    X: np.ndarray,
    sigma_l: np.ndarray,
    sigma_r: np.ndarray,
    systematic_px: float,
    c: np.ndarray,
    nrm: np.ndarray,
    radius: float,
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:  # pragma: no cover - compiled
    """(point covariances N×3×3 and centre covariance 3×3 with σ² + systematic² per image,
    mm²; the χ² statistic with σ alone; the largest eigenvalue of each point's covariance,
    then of the centre's, mm²); NaN centre covariance when the fit is degenerate."""
    _, gain, C, a, epi = _stereo_kernel(
        K_l, dist_l, P_l, K_r, dist_r, P_r, left_px, right_px, X, sigma_l, sigma_r, False
    )
    # C_k = σ² A Aᵀ per image: with σ² + systematic² it scales by (σ² + s²)/σ² per block
    s2 = systematic_px * systematic_px
    n = X.shape[0]
    cov = np.empty((n, 3, 3))
    Cb = np.zeros((4, 4))
    for k in range(n):
        fl = (sigma_l[k] * sigma_l[k] + s2) / (sigma_l[k] * sigma_l[k])
        fr = (sigma_r[k] * sigma_r[k] + s2) / (sigma_r[k] * sigma_r[k])
        Cb[0:2, 0:2] = C[k, 0:2, 0:2] * fl
        Cb[2:4, 2:4] = C[k, 2:4, 2:4] * fr
        cov[k] = _mm(_mm(gain[k], Cb), gain[k].T.copy())
    jt, jr = _ring_terms(X, c, nrm, radius)
    centre = np.zeros((3, 3))
    for k in range(X.shape[0]):
        jk = jt[0:3, 3 * k : 3 * k + 3].copy()
        centre += _mm(_mm(jk, cov[k]), jk.T.copy())
    lam = np.empty(n + 1)
    for k in range(n):
        lam[k] = _largest_eigenvalue_sym3(cov[k])
    lam[n] = _largest_eigenvalue_sym3(centre)
    if not np.all(np.isfinite(jr)):
        return cov, centre, np.nan, lam
    return cov, centre, _chi2_kernel(a, gain, C, epi, X, c, nrm, radius, jr), lam


@dataclass(frozen=True)
class LockTerms:
    """What :func:`lock_terms` returns for one lock on N LEDs."""

    led_cov_mm2: FloatArray  # (N, 3, 3), σ² + systematic² per image
    center_cov_mm2: FloatArray  # (3, 3), σ² + systematic² per image
    chi2: float  # the χ² statistic of :func:`fit_consistency` (σ alone)
    dof: int  # 3N − 6
    # (N + 1,) the largest eigenvalue of each LED's covariance, then of the centre's (mm²):
    # the "eigen" protection levels sqrt(λ_max·χ²₃(1 − p)) of :func:`led_protection_levels_mm`
    lambda_max_mm2: FloatArray


def lock_terms(
    calib: StereoCalibration,
    left_px: FloatArray,
    right_px: FloatArray,
    X_mm: FloatArray,
    sigma_left_px: FloatArray | float,
    sigma_right_px: FloatArray | float,
    circle: Circle3D,
    systematic_px: float = 0.0,
) -> LockTerms:
    """:func:`point_covariances`, :func:`ring_covariance`'s centre and
    :func:`fit_consistency`'s statistic of one lock in one compiled call (unweighted
    estimator). The covariances take a centroid error common to both views, ``systematic_px``
    (1σ, px), in quadrature with each σ; the χ² statistic does not (it cannot see it). Equal
    to the three functions to rounding (tested); ``FitError`` when the fit is degenerate."""
    args = _stereo_inputs(calib, left_px, right_px, X_mm, sigma_left_px, sigma_right_px)
    X = args[8]
    n = len(X)
    if n < 3 or not np.all(np.isfinite(X)):
        raise FitError("a circle needs at least 3 finite points")
    if not (math.isfinite(systematic_px) and systematic_px >= 0.0):
        raise ValueError("systematic_px must be finite and ≥ 0 (px)")
    c, nrm = _center_normal(circle)
    cov, centre, T, lam = _lock_kernel(*args, float(systematic_px), c, nrm, float(circle.radius))
    if not (np.all(np.isfinite(centre)) and math.isfinite(T)):
        raise FitError("the circle fit is degenerate at these points")
    return LockTerms(
        led_cov_mm2=cov, center_cov_mm2=centre, chi2=float(T), dof=3 * n - 6, lambda_max_mm2=lam
    )


# ---- protection level -------------------------------------------------------------------
def _sphere_rule(n_u: int = 16, n_phi: int = 12) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Nodes (u², cos²φ) and weights (sum 1) of the mean over the unit sphere (one octant by
    symmetry): u = ω₁ (the largest eigenvalue's axis) is uniform on [0, 1] (Archimedes),
    Gauss–Legendre; the azimuth φ is uniform on [0, π/2], midpoint rule (periodic)."""
    xu, wu = leggauss(n_u)
    u = 0.5 * (xu + 1.0)
    phi = (np.arange(n_phi) + 0.5) * (0.5 * np.pi / n_phi)
    w = np.repeat(wu, n_phi)
    u2 = np.repeat(u * u, n_phi)
    c2 = np.tile(np.cos(phi) ** 2, n_u)
    return u2, c2, w / w.sum()


_U2, _C2, _W = _sphere_rule()


@njit(cache=True, nogil=True)
def _tail(
    x: float, lam: np.ndarray, u2: np.ndarray, c2: np.ndarray, w: np.ndarray
) -> tuple[float, float]:  # pragma: no cover - compiled
    """P(Σ λᵢ zᵢ² > x) = E_ω[S₃(x / ωᵀΛω)] and its derivative in x (λ descending)."""
    tot, dtot = 0.0, 0.0
    for j in range(w.shape[0]):
        g = lam[0] * u2[j] + (1.0 - u2[j]) * (lam[1] * c2[j] + lam[2] * (1.0 - c2[j]))
        if g <= 0.0:
            continue
        t = x / g
        if t > 1400.0:
            continue
        e = math.exp(-0.5 * t)
        tot += w[j] * (math.erfc(math.sqrt(0.5 * t)) + math.sqrt(2.0 * t / math.pi) * e)
        dtot -= w[j] * math.sqrt(t / (2.0 * math.pi)) * e / g
    return tot, dtot


@njit(cache=True, nogil=True)
def _pl_kernel(
    lams: np.ndarray,
    x0: np.ndarray,
    p: float,
    q1: float,
    q3: float,
    u2: np.ndarray,
    c2: np.ndarray,
    w: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """Radius r with P(‖e‖ > r) = p per row of descending eigenvalues: safeguarded Newton on
    log P in x = r² from x0, bracketed by the λ₁·χ²₁ and λ₁·χ²₃ quantiles."""
    out = np.empty(lams.shape[0])
    lp = math.log(p)
    for i in range(lams.shape[0]):
        lam = lams[i]
        if lam[0] <= 0.0:
            out[i] = 0.0
            continue
        lo, hi = lam[0] * q1, lam[0] * q3
        x = min(max(x0[i], lo), hi)
        for _ in range(60):
            s, ds = _tail(x, lam, u2, c2, w)
            if s <= 0.0:  # far beyond the quantile
                hi = x
                x = 0.5 * (lo + hi)
                continue
            f = math.log(s) - lp
            if abs(f) < 1e-10:  # P within 1e-10 (relative) of p
                break
            if f > 0.0:
                lo = x
            else:
                hi = x
            xn = x - f * s / ds
            if not lo < xn < hi:
                xn = 0.5 * (lo + hi)
            x = xn
        out[i] = math.sqrt(x)
    return out


@lru_cache(maxsize=16)
def chi2_3_quantile(p_exceed: float) -> float:
    """χ²₃(1 − p): the squared radius a standard 3-D Gaussian exceeds with probability p."""
    if not 0.0 < p_exceed < 1.0:
        raise ValueError("p_exceed must be in (0, 1)")
    return float(chdtri(3.0, p_exceed))


def eigen_protection_levels_mm(lambda_max_mm2: FloatArray, p_exceed: float = 1e-3) -> FloatArray:
    """The ``method="eigen"`` levels of :func:`led_protection_levels_mm`, sqrt(λ_max·χ²₃(1 − p))
    mm, from each covariance's largest eigenvalue (mm², e.g. :class:`LockTerms`'
    ``lambda_max_mm2``); ``ValueError`` when one is not finite."""
    lam = np.asarray(lambda_max_mm2, dtype=np.float64)
    if not np.all(np.isfinite(lam)):
        raise ValueError("covariance is not finite")
    return np.asarray(np.sqrt(np.maximum(lam, 0.0) * chi2_3_quantile(float(p_exceed))))


def led_protection_levels_mm(
    covs: FloatArray,
    p_exceed: float = 1e-3,
    method: Literal["exact", "eigen"] = "exact",
) -> FloatArray:
    """:func:`protection_level_mm` of each of N covariances (N×3×3 mm², e.g. the LEDs' from
    :func:`point_covariances`): (N,) mm, each exceeded with probability ``p_exceed``."""
    c = np.asarray(covs, dtype=np.float64).reshape(-1, 3, 3)
    if not 0.0 < p_exceed < 1.0:
        raise ValueError("p_exceed must be in (0, 1)")
    lams = np.ascontiguousarray(np.clip(np.linalg.eigvalsh(c)[:, ::-1], 0.0, None))
    if not np.all(np.isfinite(lams)):
        raise ValueError("covariance is not finite")
    q3 = float(chdtri(3.0, p_exceed))
    if method == "eigen":
        return np.asarray(np.sqrt(lams[:, 0] * q3))
    q1 = float(chdtri(1.0, p_exceed))
    # start: Welch–Satterthwaite's a·χ²_ν matching the mean and variance of Σ λᵢ zᵢ²
    s1, s2 = lams.sum(axis=1), (lams * lams).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        x0 = np.nan_to_num(s2 / s1 * chdtri(s1 * s1 / s2, p_exceed))
    return np.asarray(_pl_kernel(lams, x0, float(p_exceed), q1, q3, _U2, _C2, _W))


def protection_level_mm(
    cov: FloatArray,
    p_exceed: float = 1e-3,
    method: Literal["exact", "eigen"] = "exact",
) -> float:
    """Radius PL (mm) with P(‖e‖ > PL) = ``p_exceed`` for e ~ N(0, ``cov``) (3×3, mm²).

    ``method="exact"`` (default): the (1 − p) quantile of ‖e‖² = Σ λᵢ zᵢ² (λ the eigenvalues,
    zᵢ iid N(0, 1)). Writing z = ρω (ρ² ~ χ²₃ independent of ω uniform on the sphere),
    P(‖e‖² > x) = E_ω[S₃(x / Σ λᵢωᵢ²)] with S₃(t) = erfc(√(t/2)) + √(2t/π)·e^(−t/2) the χ²₃
    survival function; the mean over the sphere is a smooth 2-D integral, done by a 16×12
    product rule (:func:`_sphere_rule`; relative error in p < 2e-8 for p ≤ 0.01 and < 2e-7 at
    p = 0.1 over eigenvalue ratios 1 to 1e-6, against a 300×200 rule), the quantile by
    Newton. The tests check it against Gaussian sampling and the exact isotropic (χ²₃) and
    one-axis (χ²₁) limits.
    It always lies between sqrt(λ_max·χ²₁(1−p)) and the conservative bound
    sqrt(λ_max·χ²₃(1−p)) (which is up to 23 % larger at p = 1e-3 for an elongated Σ).
    ``method="eigen"``: that bound, sqrt(λ_max·χ²₃(1−p)), conservative by construction.
    """
    return float(led_protection_levels_mm(np.asarray(cov).reshape(1, 3, 3), p_exceed, method)[0])


@njit(cache=True, nogil=True)
def _residual_cov(
    a: np.ndarray, gain: np.ndarray, C: np.ndarray, jr: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """cov(y) = Σ_k M_k C_k M_kᵀ of y = (N epipolar, 2N circle residuals): M_k (3N×4) has
    a_kᵀ in row k and ∂ρ/∂p_k · B_k below."""
    n = a.shape[0]
    m = 3 * n
    S = np.zeros((m, m))
    Mk = np.empty((m, 4))
    for k in range(n):
        Mk[:n] = 0.0
        Mk[k] = a[k]
        for r in range(2 * n):
            for j in range(4):
                Mk[n + r, j] = (
                    jr[r, 3 * k] * gain[k, 0, j]
                    + jr[r, 3 * k + 1] * gain[k, 1, j]
                    + jr[r, 3 * k + 2] * gain[k, 2, j]
                )
        MC = _mm(Mk, C[k])
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for q in range(4):
                    acc += MC[i, q] * Mk[j, q]
                S[i, j] += acc
    return S


@njit(cache=True, nogil=True)
def _chi2_kernel(
    a: np.ndarray,
    gain: np.ndarray,
    C: np.ndarray,
    epi: np.ndarray,
    X: np.ndarray,
    c: np.ndarray,
    nrm: np.ndarray,
    radius: float,
    jr: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """T = yᵀ cov(y)⁺ y of :func:`fit_consistency` on the top 3N − 6 directions of cov(y)."""
    n = X.shape[0]
    S = _residual_cov(a, gain, C, jr)
    y = np.concatenate((epi, _circle_residuals(X, c, nrm, radius)))
    dof = 3 * n - 6
    if n == 3:  # the circle passes through the 3 points: only the epipolar residuals remain
        S, y = S[:n, :n].copy(), y[:n].copy()
    scale = np.sqrt(np.diag(S))
    lam, vec = np.linalg.eigh(S / np.outer(scale, scale))  # unit-free, then the top 3N − 6
    m = len(y)
    T = 0.0
    for j in range(m - dof, m):
        proj = 0.0
        for i in range(m):
            proj += vec[i, j] * y[i] / scale[i]
        T += proj * proj / lam[j]
    return T


# ---- consistency ---------------------------------------------------------------------------
@dataclass(frozen=True)
class FitConsistency:
    """χ² test of a lock's residuals (see :func:`fit_consistency`)."""

    statistic: float  # T, dimensionless
    dof: int  # 3N − 6
    p_value: float  # P(χ²_dof > T)
    consistent: bool  # p_value ≥ alpha


def fit_consistency(
    calib: StereoCalibration,
    left_px: FloatArray,
    right_px: FloatArray,
    X_mm: FloatArray,
    sigma_left_px: FloatArray | float,
    sigma_right_px: FloatArray | float,
    circle: Circle3D,
    alpha: float = 1e-3,
    weighted: bool = False,
) -> FitConsistency:
    """Are a lock's own residuals consistent with its covariance? (χ², false refusal ``alpha``)

    Inputs are those of :func:`point_covariances` for the ring's N LEDs only, and ``circle`` =
    :func:`~app.geometry.circle_fit.fit_circle_3d` of ``X_mm`` (any sign of the normal).

    Residuals, y (3N):

    * per LED, its epipolar residual e = aᵀ r (px): r the 4 reprojection residuals in ideal
      px, a the unit vector with aᵀJ = 0 — 4 measurements − 3 unknowns = 1 dof per point. To
      first order e = aᵀ(noise) whatever triangulation gave X.
    * per LED, its distance from the fitted circle's plane and its in-plane radial distance
      from the circle (mm): 2 constraints per point on 6 circle parameters (centre 3, unit
      normal 2, radius 1) → 2N − 6 dof.

    To first order y = M·(pixel noise), so cov(y) = Σ_k M_k C_k M_kᵀ with the triangulation
    gains B_k (``weighted`` as in :func:`point_covariances`) and the fit's residual Jacobian
    (in closed form at the LEDs' closest points on the circle, see
    :func:`_ring_jacobians`); this takes the circle residuals' own covariance (the share the
    fit absorbs included) and their correlation with the epipolar ones (non-zero for the
    unweighted estimator with unequal σ). T = yᵀ cov(y)⁺ y on its 3N − 6 non-null
    directions, ~ χ²_{3N−6} for honest data (N = 3: only the 3 epipolar dof). The ring's slot
    angles are NOT used as constraints (the LEDs' even spacing is known and would add N − 1
    dof along the circle; the ring search tests them separately), so a centroid error that
    slides an LED along the ring is invisible here.

    First order holds while the ring's tilt is well determined: Monte Carlo (σ 0.05–0.3 px)
    gives the nominal refusal rate at 1 m (tilt σ 0.5°), ~1.7× α at α = 1e-2 and 3–4× at 1e-3
    at 2.5 m (tilt σ 3°), and 25× at 1e-3 at 8 m with a 305 mm ring (tilt σ 7°; nominal
    again with σ ≤ 0.09 px). Power: 9 dof at α = 1e-3 need a noncentrality ≈ 40 for 90 %
    refusals; a bias is seen through its epipolar component (across the epipolar line) and
    its effect on the ring, e.g. 0.3 px on one centroid at σ = 0.05 px gives ≈ 18 across and
    ≈ 13 along the line (refused in ~45 % and ~20 % of locks).
    """
    X = np.asarray(X_mm, dtype=np.float64).reshape(-1, 3)
    n = len(X)
    _, gain, C, a, epi = _stereo_terms(
        calib, left_px, right_px, X, sigma_left_px, sigma_right_px, weighted
    )
    c, nrm = _center_normal(circle)
    _, jr = _ring_jacobians(X, circle)
    T = float(
        _chi2_kernel(a, gain, C, epi, np.ascontiguousarray(X), c, nrm, float(circle.radius), jr)
    )
    dof = 3 * n - 6
    p_value = float(chdtrc(dof, T))
    return FitConsistency(statistic=T, dof=dof, p_value=p_value, consistent=p_value >= alpha)
