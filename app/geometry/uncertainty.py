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

The per-point and per-node arithmetic runs in the compiled loops of
:mod:`app.geometry.uncertainty_kernels`. :func:`lock_terms` gives a lock's covariances and χ²
statistic in one compiled call (≈ 0.03 ms for 5 LEDs, the whole bound with its protection
levels; the three separate functions cost ≈ 0.3 ms): the χ² statistic there removes the
residual covariance's known null space in closed form and solves by Cholesky
(:func:`~app.geometry.uncertainty_kernels.chi2_kernel`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
from numpy.polynomial.legendre import leggauss
from scipy.special import chdtrc, chdtri

from app.geometry.calibration import StereoCalibration
from app.geometry.circle_fit import Circle3D, FitError
from app.geometry.uncertainty_kernels import (
    LOCK_BAD_POINTS,
    LOCK_BAD_SIGMA_LEFT,
    LOCK_BAD_SIGMA_RIGHT,
    LOCK_OK,
    chi2_kernel,
    lock_kernel,
    pl_kernel,
    ring_terms,
    stereo_kernel,
)
from app.types import FloatArray

# ---- stereo: per-point covariance --------------------------------------------------------


def _sigmas(sigma: FloatArray | float, n: int, name: str, check: bool = True) -> FloatArray:
    """One σ per point (px) as a float64 array; ``check``: ``ValueError`` unless each is
    positive and finite (without, the compiled call checks them)."""
    if isinstance(sigma, np.ndarray) and sigma.dtype == np.float64 and sigma.shape == (n,):
        # (the common case: one σ per point already; the compiled loops only read it)
        s = sigma if not check else sigma.copy()
    else:
        s = np.broadcast_to(np.asarray(sigma, dtype=np.float64).reshape(-1), (n,)).copy()
    if check and not all(0.0 < v < math.inf for v in s.tolist()):
        raise ValueError(f"{name} must be positive and finite (px)")
    return s


def _vector3(values: FloatArray) -> FloatArray:
    """``values`` as a C-contiguous float64 (3,) array (as is when it already is one)."""
    if (
        isinstance(values, np.ndarray)
        and values.dtype == np.float64
        and values.shape == (3,)
        and values.flags.c_contiguous
    ):
        return values
    return np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(3))


def _rows(values: FloatArray, width: int) -> FloatArray:
    """``values`` as C-contiguous float64 rows of ``width`` (as is when they already are)."""
    if (
        isinstance(values, np.ndarray)
        and values.dtype == np.float64
        and values.ndim == 2
        and values.shape[1] == width
        and values.flags.c_contiguous
    ):
        return values
    return np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(-1, width))


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
    out = stereo_kernel(
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


def _center_normal(circle: Circle3D) -> tuple[FloatArray, FloatArray]:
    nrm = np.asarray(circle.normal, dtype=np.float64).reshape(3)
    x, y, z = nrm.tolist()
    norm = math.sqrt(x * x + y * y + z * z)  # (cheaper than np.linalg.norm for 3 terms)
    return np.asarray(circle.center, dtype=np.float64).reshape(3), nrm / norm


def _ring_jacobians(
    points_mm: FloatArray, circle: Circle3D
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`~app.geometry.uncertainty_kernels.ring_terms` of these points and ``circle``
    (``FitError`` when degenerate)."""
    pts = np.ascontiguousarray(np.asarray(points_mm, dtype=np.float64).reshape(-1, 3))
    if len(pts) < 3 or not np.all(np.isfinite(pts)):
        raise FitError("a circle needs at least 3 finite points")
    c, nrm = _center_normal(circle)
    jt, jr, design = ring_terms(pts, c, nrm, float(circle.radius))
    if not (np.all(np.isfinite(jt)) and np.all(np.isfinite(jr))):
        raise FitError("the circle fit is degenerate at these points")
    return jt, jr, design


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
    (``_fit_jacobians`` of :mod:`app.geometry.uncertainty_kernels`), the refitted normal
    signed like ``circle.normal``, taken at the points' closest points on ``circle`` (see
    :func:`_ring_jacobians`); Σ = Σ_k J_k Σ_k J_kᵀ
    (points independent, ``point_cov`` N×3×3 mm² from :func:`point_covariances`). The
    Jacobians are kept for :func:`fit_consistency` of the same lock (a small cache).
    """
    jt, _, _ = _ring_jacobians(points_mm, circle)
    cov = _propagate(jt, np.asarray(point_cov, dtype=np.float64).reshape(-1, 3, 3))
    return RingCovariance(
        center_cov_mm2=cov[0:3, 0:3].copy(),
        normal_cov=cov[3:6, 3:6].copy(),
        radius_var_mm2=float(cov[6, 6]),
    )


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
    X = _rows(X_mm, 3)
    n = len(X)
    status, cov, centre, T, lam = lock_kernel(
        *calib.kernel_arrays,
        _rows(left_px, 2).reshape(n, 2),
        _rows(right_px, 2).reshape(n, 2),
        X,
        _sigmas(sigma_left_px, n, "sigma_left_px", check=False),
        _sigmas(sigma_right_px, n, "sigma_right_px", check=False),
        float(systematic_px),
        _vector3(circle.center),
        _vector3(circle.normal),  # (made unit in the call, as _center_normal makes it)
        float(circle.radius),
    )
    # the compiled call checked the inputs; reported in the order the three functions do
    if status == LOCK_BAD_SIGMA_LEFT:
        raise ValueError("sigma_left_px must be positive and finite (px)")
    if status == LOCK_BAD_SIGMA_RIGHT:
        raise ValueError("sigma_right_px must be positive and finite (px)")
    if status == LOCK_BAD_POINTS:
        raise FitError("a circle needs at least 3 finite points")
    if not (math.isfinite(systematic_px) and systematic_px >= 0.0):
        raise ValueError("systematic_px must be finite and ≥ 0 (px)")
    if status != LOCK_OK:
        raise FitError("the circle fit is degenerate at these points")
    return LockTerms(
        led_cov_mm2=cov, center_cov_mm2=centre, chi2=T, dof=3 * n - 6, lambda_max_mm2=lam
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
    values = lam.ravel().tolist()
    if not all(math.isfinite(v) for v in values):
        raise ValueError("covariance is not finite")
    q3 = chi2_3_quantile(float(p_exceed))
    # (per value: a handful of them per lock, where numpy's per-call cost would dominate)
    levels = [math.sqrt(v * q3) if v > 0.0 else 0.0 for v in values]
    return np.array(levels, dtype=np.float64).reshape(lam.shape)


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
    return np.asarray(pl_kernel(lams, x0, float(p_exceed), q1, q3, _U2, _C2, _W))


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
    _, jr, design = _ring_jacobians(X, circle)
    T = float(
        chi2_kernel(
            a, gain, C, epi, np.ascontiguousarray(X), c, nrm, float(circle.radius), jr, design
        )
    )
    dof = 3 * n - 6
    p_value = float(chdtrc(dof, T))
    return FitConsistency(statistic=T, dof=dof, p_value=p_value, consistent=p_value >= alpha)
