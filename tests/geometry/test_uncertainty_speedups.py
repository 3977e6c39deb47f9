"""The error bound's cheaper formulations equal the ones they replace.

The χ² statistic of a lock's residuals (:func:`~app.geometry.uncertainty.fit_consistency`,
:func:`~app.geometry.uncertainty.lock_terms`) is computed with the residual covariance's null
space removed in closed form and one Cholesky solve; here it is compared with the truncated
eigendecomposition (``tests.support.uncertainty_reference.chi2_by_eigh``) on rings of 3–5
LEDs from 0.6 to 8 m, tilted 0–70°, with honest noise and with a centroid pulled off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.geometry.calibration import StereoCalibration
from app.geometry.circle_fit import fit_circle_3d
from app.geometry.projection import project_stereo, undistort_pixels
from app.geometry.triangulation import refine_reprojection, triangulate_linear
from app.geometry.uncertainty import fit_consistency, lock_terms
from app.geometry.uncertainty_kernels import residual_system, ring_terms, stereo_kernel
from tests.support.uncertainty_reference import chi2_by_eigh

CALIB = StereoCalibration.load(Path(__file__).parents[2] / "sample_data" / "calibration.json")


def ring(depth_mm: float, radius_mm: float, tilt_deg: float, n: int) -> np.ndarray:
    """N LEDs evenly spaced on a ring in front of the rig (left camera frame, mm)."""
    t = np.radians(tilt_deg)
    normal = np.array([0.0, np.sin(t), -np.cos(t)])
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(normal, e1)
    ang = np.radians(90.0 + 360.0 / 5 * np.arange(n))  # n of the 5 slots
    centre = np.array([0.5 * CALIB.baseline_mm, -10.0, depth_mm])
    return np.asarray(centre + radius_mm * (np.outer(np.cos(ang), e1) + np.outer(np.sin(ang), e2)))


def lock(depth_mm, radius_mm, tilt_deg, n, seed, bias_px=0.0):  # type: ignore[no-untyped-def]
    """(left px, right px, σ left, σ right, triangulated points, fitted circle) of a noisy
    measurement of the ring, the first LED's left centroid pulled ``bias_px`` along u."""
    rng = np.random.default_rng(seed)
    pl, pr = project_stereo(CALIB, ring(depth_mm, radius_mm, tilt_deg, n))
    sl = rng.uniform(0.03, 0.3, n)
    sr = rng.uniform(0.03, 0.3, n)
    pl = pl + rng.standard_normal((n, 2)) * sl[:, None]
    pr = pr + rng.standard_normal((n, 2)) * sr[:, None]
    pl[0, 0] += bias_px
    xl, xr = undistort_pixels(CALIB.left, pl), undistort_pixels(CALIB.right, pr)
    X0 = triangulate_linear(CALIB.P_left, CALIB.P_right, xl, xr)
    X, _ = refine_reprojection(CALIB.P_left, CALIB.P_right, xl, xr, X0)
    return pl, pr, sl, sr, X, fit_circle_3d(X)


CASES = [
    (depth, radius, tilt, n, seed, bias)
    for depth, radius in ((600.0, 75.0), (1000.0, 75.0), (2500.0, 75.0), (8000.0, 305.0))
    for tilt in (0.0, 20.0, 45.0, 70.0)
    for n in (3, 4, 5)
    for seed, bias in ((1, 0.0), (2, 0.0), (3, 0.5), (4, 3.0))
]


@pytest.mark.parametrize("depth, radius, tilt, n", sorted({c[:4] for c in CASES}))
def test_chi2_by_closed_form_null_space_equals_the_eigendecomposition(depth, radius, tilt, n):
    for case in CASES:
        if case[:4] != (depth, radius, tilt, n):
            continue
        pl, pr, sl, sr, X, circle = lock(*case)
        _, gain, C, a, epi = stereo_kernel(*CALIB.kernel_arrays, pl, pr, X, sl, sr, False)
        c, nrm = circle.center, circle.normal / np.linalg.norm(circle.normal)
        _, jr, _ = ring_terms(X, c, nrm, float(circle.radius))
        if not np.all(np.isfinite(jr)):  # no circle through these points: no statistic
            assert depth == 8000.0 and n == 3, case
            continue
        S, y = residual_system(a, gain, C, epi, X, c, nrm, float(circle.radius), jr)
        want = chi2_by_eigh(S, y, n)
        got = fit_consistency(CALIB, pl, pr, X, sl, sr, circle)
        assert got.dof == 3 * n - 6
        assert got.statistic == pytest.approx(want, rel=1e-11), case
        terms = lock_terms(CALIB, pl, pr, X, sl, sr, circle, systematic_px=0.1)
        assert terms.chi2 == pytest.approx(want, rel=1e-11), case
