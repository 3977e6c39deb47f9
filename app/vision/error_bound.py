"""The error bound reported with every lock (pipeline and tracker alike).

From each ring LED's centroid noise σ (px, :mod:`app.vision.local_centroid`, per image) the
first-order covariances of the triangulated LEDs (eqs. 15–16) and of the fitted drogue centre
(§5.2), their protection levels (radii the 3-D error exceeds with probability ≤ ``p_exceed``)
and a χ² test that the lock's own residuals are what that noise allows
(:mod:`app.geometry.uncertainty`); the covariances add a systematic centroid error common to
both views (``systematic_px``), which the residual test cannot see. A lock that fails the
test is refused: its centroids are
disturbed by something the noise model does not describe (a reflection merged with an LED,
a glint taken for one), so its covariance would be a lie.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special.cython_special import chdtrc  # scipy.special.chdtrc without the ufunc layer

from app.geometry.calibration import StereoCalibration
from app.geometry.circle_fit import Circle3D, FitError
from app.geometry.uncertainty import eigen_protection_levels_mm, lock_terms
from app.model.pose import DrogueResult
from app.types import FloatArray
from app.vision.types import Blob


@dataclass(frozen=True)
class ErrorBoundConfig:
    """Protection-level probability and the residual test's false-refusal probability."""

    enabled: bool = True
    p_exceed: float = 1e-3  # P(error > protection level)
    alpha: float = 1e-3  # P(refusing an honest lock) of the residual test
    refuse_inconsistent: bool = True
    # centroid error common to both views (px, 1σ): an LED dome's visible centre off its
    # physical centre, the same in both images, so the residual test cannot see it; it widens
    # the covariances and protection levels only (measured on the physically based dev set,
    # docs/integrity.md)
    systematic_px: float = 0.1
    # calibration doubt (px, 1σ per image, in quadrature with each centroid's σ in the residual
    # test and the covariances): a navigation calibration known only to 0.1° and 0.5 px
    # (app.sim.imperfections) moves the epipolar residuals by ≈ 4 px, which a test at the
    # centroids' 0.03 px would refuse on every frame (χ² ≈ 2·10⁴ for 9 dof)
    calibration_px: float = 0.0


@dataclass(frozen=True)
class LockBound:
    """A lock's covariances (mm²), protection levels (mm) and residual test."""

    led_cov_mm2: FloatArray  # (N, 3, 3), rows as the LEDs passed in
    led_pl_mm: FloatArray  # (N,)
    center_cov_mm2: FloatArray  # (3, 3)
    center_pl_mm: float
    chi2: float
    dof: int
    p_value: float
    consistent: bool

    def refusal(self) -> str:
        """The no-lock reason of an inconsistent lock."""
        return (
            f"fit residuals exceed what the centroid noise allows (χ² = {self.chi2:.1f} for "
            f"{self.dof} dof, p = {self.p_value:.1e})"
        )


def isotropic_sigma_px(blob: Blob) -> float:
    """One σ (px) of a blob's centroid: the RMS of its (σ_u, σ_v); NaN when not measured."""
    s = blob.centroid_sigma_px
    if s is None:
        return math.nan
    return math.sqrt(0.5 * (s[0] * s[0] + s[1] * s[1]))


def isotropic_model_sigma_px(blob: Blob) -> float:
    """:func:`isotropic_sigma_px` of the sensor model's share alone (shot and read noise,
    :attr:`Blob.model_sigma_px`); the blob's σ where that is not kept apart."""
    s = blob.model_sigma_px
    if s is None:
        return isotropic_sigma_px(blob)
    return math.sqrt(0.5 * (s[0] * s[0] + s[1] * s[1]))


def lock_bound(
    calib: StereoCalibration,
    left_px: FloatArray,
    right_px: FloatArray,
    sigma_left_px: FloatArray,
    sigma_right_px: FloatArray,
    xyz_mm: FloatArray,
    circle: Circle3D,
    cfg: ErrorBoundConfig,
) -> LockBound | None:
    """The bound of a lock on these N ring LEDs (distorted centroids px, their σ px, their
    triangulated points mm and the fitted circle); None when a σ is not measured."""
    sl = np.asarray(sigma_left_px, dtype=np.float64)
    sr = np.asarray(sigma_right_px, dtype=np.float64)
    if not cfg.enabled or not all(math.isfinite(v) for v in sl.tolist() + sr.tolist()):
        return None
    if cfg.calibration_px > 0:
        c2 = cfg.calibration_px * cfg.calibration_px
        sl, sr = np.sqrt(sl * sl + c2), np.sqrt(sr * sr + c2)
    try:
        terms = lock_terms(
            calib, left_px, right_px, xyz_mm, sl, sr, circle, systematic_px=cfg.systematic_px
        )
    except (FitError, np.linalg.LinAlgError, ValueError):
        return None
    # the LEDs' and the centre's levels: sqrt(λ_max·χ²₃(1 − p)), conservative by construction
    # (≤ 1.23× the exact quantile of :func:`protection_level_mm`, 4× cheaper), from the
    # largest eigenvalues the compiled call gives (led_protection_levels_mm's "eigen" levels)
    levels = eigen_protection_levels_mm(terms.lambda_max_mm2, cfg.p_exceed)
    p_value = float(chdtrc(float(terms.dof), terms.chi2))
    return LockBound(
        led_cov_mm2=terms.led_cov_mm2,
        led_pl_mm=levels[:-1],
        center_cov_mm2=terms.center_cov_mm2,
        center_pl_mm=float(levels[-1]),
        chi2=terms.chi2,
        dof=terms.dof,
        p_value=p_value,
        consistent=p_value >= cfg.alpha,
    )


def bound_lock(
    calib: StereoCalibration,
    left_px: FloatArray,
    right_px: FloatArray,
    sigmas_px: list[tuple[float, float]],
    xyz_mm: FloatArray,
    circle: Circle3D,
    cfg: ErrorBoundConfig,
) -> LockBound | None | str:
    """:func:`lock_bound` of a lock's ring LEDs (rows: their distorted centroids px in both
    images, their (left, right) σ px, their points mm, all in the same order): the bound,
    None where no σ is measured, or the no-lock reason when its residuals are inconsistent
    and ``cfg.refuse_inconsistent``."""
    bound = lock_bound(
        calib,
        np.asarray(left_px, dtype=np.float64),
        np.asarray(right_px, dtype=np.float64),
        np.array([s[0] for s in sigmas_px]),
        np.array([s[1] for s in sigmas_px]),
        xyz_mm,
        circle,
        cfg,
    )
    if bound is not None and not bound.consistent and cfg.refuse_inconsistent:
        return bound.refusal()
    return bound


def led_bound_fields(
    bound: LockBound | None, k: int, sigma_px: tuple[float, float]
) -> dict[str, Any]:
    """The bound's fields of row ``k``'s :class:`LedResult` (none without a bound): the
    records are built once with them."""
    if bound is None:
        return {}
    return {
        "sigma_px": sigma_px,
        "cov_mm2": bound.led_cov_mm2[k].tolist(),
        "protection_level_mm": float(bound.led_pl_mm[k]),
    }


def drogue_with_bound(circle: Circle3D, bound: LockBound | None) -> DrogueResult:
    """The result contract's drogue (centre mm, unit normal, radius mm, RMS mm) and, with a
    bound, its centre covariance, protection level and residual test."""
    c, n = circle.center.tolist(), circle.normal.tolist()
    fields: dict[str, Any] = {}
    if bound is not None:
        fields = {
            "center_cov_mm2": bound.center_cov_mm2.tolist(),
            "protection_level_mm": bound.center_pl_mm,
            "fit_chi2": bound.chi2,
            "fit_dof": bound.dof,
        }
    return DrogueResult(
        center_mm=(c[0], c[1], c[2]),
        normal=(n[0], n[1], n[2]),
        radius_mm=float(circle.radius),
        rms_mm=float(circle.rms),
        **fields,
    )
