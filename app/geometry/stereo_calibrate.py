"""Stereo rig calibration from detected checkerboard corners (paper §3.2, Zhang's method [18, 19]).

The paper photographs a checkerboard (CCP) from several angles with both cameras and
estimates fx, fy, γ, u0, v0, k1, k2 for each camera (eqs. 2, 7) and the rig's R, T (eqs. 3–5).
Here, from the corners of :mod:`app.geometry.board_detect`:

1. each camera is calibrated alone (``cv2.calibrateCamera``: Zhang's closed form + LM);
2. **rig check** (:func:`rig_check`): every pair's two board poses imply a rig (R, T); the
   rig most pairs agree on is calibrated from them, and each pair's corners are then
   triangulated with it under every index mapping (as detected, reversed, offset by ±1
   column/row: :data:`MAPPINGS`) and fitted to the flat board (:func:`mapping_fits_mm`). A pair
   whose right grid is the left one reversed is corrected; a pair whose grids are offset by a
   column or row (not the same physical corners), or that fits no mapping, is rejected with
   the reason — :func:`calibrate_checkerboard` first searches its images again with the
   other detectors (:func:`redetect_rejected`) and keeps the pair if the new grids agree;
3. the rig is refined jointly (``cv2.stereoCalibrateExtended``, intrinsics as initial guess);
4. **robust view dropping** (:func:`robust_outlier`): while a view's RMS reprojection error
   ``e`` (px, both cameras) has a robust z-score ``0.6745 · (e − median) / MAD > 3.5``
   (Iglewicz–Hoaglin) *and* ``e > 2 · median`` *and* ``e > median + 0.1 px``, the worst
   such view is dropped and step 3 repeated — at most a quarter of the views, never below
   ``MIN_VIEWS``;
5. optionally (``estimate_skew``) everything is refined once more *with* the skew γ
   (:func:`refine_with_skew`, sparse least squares), which OpenCV's model lacks;
6. **held-out check** (:func:`held_out_check`): each view's board is triangulated with a
   calibration made without it (k-fold) and its square size compared with the true one (mm).

Distortion models: ``"paper"`` estimates k1, k2 only (``CALIB_FIX_K3 | CALIB_ZERO_TANGENT_DIST``,
the paper's eq. 7); ``"full"`` estimates OpenCV's five terms k1, k2, p1, p2, k3.
Without step 5, γ is **not** estimated and is 0 in the output.

Bad input raises :class:`CheckerboardError` (a ``ValueError``) with a one-line message.
Pure numpy/OpenCV/scipy.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.board_detect import (
    METHODS,
    Board,
    CheckerboardError,
    CornerResult,
    PairDetection,
    check_image_sizes,
    detect_corners_detail,
    detect_pairs,
    match_orientation,
    suggest_board,
)
from app.geometry.calibration import CalibrationError, FloatArray, StereoCalibration
from app.geometry.calibration_report import (
    SKEW_NOTE,
    SKEW_REFINED_NOTE,
    CalibrationReport,
    DroppedView,
    HeldOutCheck,
    RejectedView,
    ViewReport,
    coverage_map,
    coverage_warnings,
    intrinsics_summary,
)
from app.geometry.projection import undistort_pixels
from app.geometry.triangulation import triangulate_linear

MIN_VIEWS = 6
DEFAULT_MAX_STEREO_RMS_PX = 0.5
Model = Literal["paper", "full"]
MODEL_FLAGS: dict[str, int] = {
    "paper": cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "full": 0,
}
_TERM = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-10)
_TERM_FOLD = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-8)
RIG_TOL_SQUARES = 0.4  # rig check: |ΔT| tolerance, in squares (candidates are 1 square apart)
RIG_TOL_DEG = 3.0  # rig check: rotation tolerance (deg)
RIG_MAX_FIT_SQUARES = 0.1  # rig check: worst accepted board-fit RMS, in squares ...
RIG_FIT_SPREAD = 5.0  # ... or this multiple of the median pair's fit (noisy corners)
OUTLIER_Z = 3.5  # robust z-score threshold (Iglewicz & Hoaglin)
OUTLIER_RATIO = 2.0  # ... and at least this multiple of the median view RMS
OUTLIER_MIN_EXCESS_PX = 0.1  # ... and at least this much above the median (px)
MAX_DROP_FRACTION = 0.25
HELD_OUT_MAX_FOLDS = 3


def _pose(rvec: Any, tvec: Any) -> tuple[FloatArray, FloatArray]:
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return np.asarray(R, dtype=np.float64), np.asarray(tvec, dtype=np.float64).ravel()


@dataclass(frozen=True)
class GridMapping:
    """The right grid's corner (i, j) is physical corner (i+dx, j+dy), or (C−1−i+dx, R−1−j+dy)
    when ``flip`` (the grid reversed, 180°); the left grid's corner (i, j) is (i, j)."""

    flip: bool
    dx: int
    dy: int

    @property
    def shifted(self) -> bool:
        return self.dx != 0 or self.dy != 0


# as detected first, then the offsets by one column and/or row, then the same reversed
MAPPINGS = tuple(
    GridMapping(flip, dx, dy)
    for flip in (False, True)
    for dx, dy in itertools.product((0, -1, 1), (0, -1, 1))
)


@dataclass(frozen=True)
class RigCandidate(GridMapping):
    """A :class:`GridMapping` of the right grid onto the left's with the rig it implies
    (R, T: X_right = R·X_left + T, mm)."""

    R: FloatArray
    T: FloatArray


def rig_candidates(
    pose_l: tuple[FloatArray, FloatArray], pose_r: tuple[FloatArray, FloatArray], board: Board
) -> list[RigCandidate]:
    """The rig implied by one pair's board poses (board → camera), for every index mapping.

    If right index (i, j) is physical corner (i+dx, j+dy) (or, reversed, (C−1−i+dx, R−1−j+dy)),
    the board point is X = A·P_r + b with A = I or diag(−1, −1, 1); then
    R_rig = R_r·A·R_lᵀ and T_rig = t_r − R_r·A·(R_lᵀ·t_l + b)."""
    R_l, t_l = pose_l
    R_r, t_r = pose_r
    s = board.square_mm
    out = []
    for m in MAPPINGS:
        A = np.diag([-1.0, -1.0, 1.0]) if m.flip else np.eye(3)
        if m.flip:
            b = np.array([(board.cols - 1 + m.dx) * s, (board.rows - 1 + m.dy) * s, 0.0])
        else:
            b = np.array([m.dx * s, m.dy * s, 0.0])
        RA = R_r @ A
        T = t_r - RA @ (R_l.T @ t_l + b)
        out.append(RigCandidate(m.flip, m.dx, m.dy, RA @ R_l.T, T))
    return out


def _rig_distances(
    Rs: FloatArray, Ts: FloatArray, R: FloatArray, T: FloatArray, square_mm: float
) -> FloatArray:
    """Rig differences in tolerance units (< 1: the same rig) of rigs ``Rs`` (..., 3, 3),
    ``Ts`` (..., 3) from (R, T): max(|ΔT| / (RIG_TOL_SQUARES · s), angle(ΔR) / RIG_TOL_DEG)."""
    dT = np.linalg.norm(Ts - T, axis=-1) / (RIG_TOL_SQUARES * square_mm)
    cos = np.clip((np.einsum("...ij,ij->...", Rs, R) - 1.0) / 2.0, -1.0, 1.0)
    dR = np.degrees(np.arccos(cos)) / RIG_TOL_DEG
    return np.asarray(np.maximum(dT, dR), dtype=np.float64)


@dataclass
class RigVerdict:
    """Outcome of the rig check for one pair: ``action`` ok | flipped | rejected, and the
    board-fit RMS of the grids as detected (mm, :func:`mapping_fits_mm`)."""

    action: str
    reason: str | None
    fit_mm: float


def _offset_text(c: GridMapping) -> str:
    parts = []
    if c.dx:
        parts.append(f"{c.dx:+d} column{'s' if abs(c.dx) > 1 else ''}")
    if c.dy:
        parts.append(f"{c.dy:+d} row{'s' if abs(c.dy) > 1 else ''}")
    return " and ".join(parts) + (" (and reversed)" if c.flip else "")


def _right_to_physical(
    cand: GridMapping, board: Board
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Indices (right corner k, left corner m) of the corners the two grids share when the
    right grid's corner (i, j) is physical corner (i+dx, j+dy) — or (C−1−i+dx, R−1−j+dy)
    when reversed; the left grid's corner m = j·C + i is physical corner (i, j)."""
    C, Rw = board.cols, board.rows
    jj, ii = np.mgrid[0:Rw, 0:C]
    i, j = ii.ravel(), jj.ravel()
    if cand.flip:
        pi, pj = C - 1 - i + cand.dx, Rw - 1 - j + cand.dy
    else:
        pi, pj = i + cand.dx, j + cand.dy
    ok = (pi >= 0) & (pi < C) & (pj >= 0) & (pj < Rw)
    return np.flatnonzero(ok), (pj * C + pi)[ok]


def mapping_fits_mm(
    calib: StereoCalibration,
    left: FloatArray,
    right: FloatArray,
    board: Board,
    mappings: Sequence[GridMapping] = MAPPINGS,
) -> FloatArray:
    """How well one pair's corners, matched under each index mapping and triangulated with
    the rig ``calib`` (eqs. 15–16 on undistorted corners), form the flat board: RMS (mm) of
    a rigid fit (Kabsch) to the board's corner positions, one value per mapping. A wrong
    mapping scales and shears the triangulated board (a column's offset along the baseline
    changes every disparity by one square), which no rigid motion undoes."""
    xl = undistort_pixels(calib.left, np.asarray(left, dtype=np.float64).reshape(-1, 2))
    xr = undistort_pixels(calib.right, np.asarray(right, dtype=np.float64).reshape(-1, 2))
    idx = [_right_to_physical(m, board) for m in mappings]
    k_r = np.concatenate([i[0] for i in idx])
    m_l = np.concatenate([i[1] for i in idx])
    X = triangulate_linear(calib.P_left, calib.P_right, xl[m_l], xr[k_r])
    P = board.object_points().astype(np.float64)[m_l]
    # Kabsch per mapping: min Σ|R·a − b|² = Σ|a|² + Σ|b|² − 2(σ1 + σ2 + sign(det H)·σ3)
    lens = np.array([len(i[0]) for i in idx])
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
    a = P - np.repeat(np.add.reduceat(P, starts, axis=0) / lens[:, None], lens, axis=0)
    b = X - np.repeat(np.add.reduceat(X, starts, axis=0) / lens[:, None], lens, axis=0)
    H = np.add.reduceat(a[:, :, None] * b[:, None, :], starts, axis=0)
    sv = np.linalg.svd(H, compute_uv=False)
    sign = np.sign(np.linalg.det(H))
    ss = np.add.reduceat(np.sum(a * a, axis=1) + np.sum(b * b, axis=1), starts)
    err = ss - 2.0 * (sv[:, 0] + sv[:, 1] + sign * sv[:, 2])
    return np.asarray(np.sqrt(np.maximum(err, 0.0) / lens), dtype=np.float64)


def rig_tolerance_mm(fits_as_detected: Sequence[float], board: Board) -> float:
    """Worst accepted board fit (mm): ``RIG_MAX_FIT_SQUARES`` squares, or ``RIG_FIT_SPREAD`` ×
    the median fit of all pairs as detected when the corners are noisier than that."""
    med = float(np.median(fits_as_detected)) if len(fits_as_detected) else 0.0
    return max(RIG_MAX_FIT_SQUARES * board.square_mm, RIG_FIT_SPREAD * med)


def pair_verdict(fit: FloatArray, tol_mm: float, board: Board) -> RigVerdict:
    """Are one pair's grids the same corners in the same order? ``fit``: the pair's
    :func:`mapping_fits_mm`. Another mapping than the one detected wins only if it fits at
    least twice as well: reversed → ``flipped`` (to be corrected), offset by a column or row →
    ``rejected``; a best fit worse than ``tol_mm`` → ``rejected`` (matches no mapping)."""
    j = int(np.argmin(fit))
    r0 = float(fit[0])  # MAPPINGS[0]: as detected
    if j != 0 and fit[j] >= 0.5 * r0:
        j = 0
    m = MAPPINGS[j]
    if fit[j] > tol_mm:
        reason = (
            "left/right grids inconsistent with the rig of the other pairs (the pair's "
            f"triangulated board is off a flat {board.cols}x{board.rows} board by "
            f"{fit[j]:.1f} mm RMS, tolerance {tol_mm:.1f} mm)"
        )
        return RigVerdict("rejected", reason, r0)
    if m.shifted:
        reason = (
            "left and right grids are not the same corners: the right grid is offset by "
            f"{_offset_text(m)} (rig check: the triangulated board is off the flat board "
            f"by {r0:.1f} mm RMS as detected, {fit[j]:.2f} mm with the offset)"
        )
        return RigVerdict("rejected", reason, r0)
    return RigVerdict("flipped" if m.flip else "ok", None, r0)


def rig_check(
    poses_l: Sequence[tuple[FloatArray, FloatArray]],
    poses_r: Sequence[tuple[FloatArray, FloatArray]],
    board: Board,
    cams: tuple[tuple[FloatArray, FloatArray], tuple[FloatArray, FloatArray]],
    corners: Sequence[tuple[FloatArray, FloatArray]],
    image_size: tuple[int, int],
    flags: int,
) -> tuple[list[RigVerdict], str | None, tuple[list[int], _Stereo] | None]:
    """Do the pairs' two grids hold the same physical corners in the same order?

    1. Consensus rig: each pair's board poses (from each camera's own calibration) imply a
       rig for each index mapping (:func:`rig_candidates`); the consensus is the unshifted
       candidate supported by the most pairs (one of a pair's candidates within
       ``RIG_TOL_SQUARES`` squares and ``RIG_TOL_DEG``); the supporting pairs (reversed
       grids turned round) are calibrated together (``stereoCalibrate``) for the rig.
    2. Per pair, every mapping is scored by :func:`mapping_fits_mm` (corners triangulated with
       the consensus rig and each camera's own intrinsics, rigid fit to the flat board); the
       best one decides if it fits at least twice as well as the grids as detected: as
       detected → ok; reversed → ``flipped`` (to be corrected); offset by a column or row →
       ``rejected``; a best fit worse than :func:`rig_tolerance_mm` → ``rejected``.

    Returns the verdicts, a warning (inconclusive when fewer than half the pairs, or fewer
    than 3, agree on a rig: then no pair is changed) and the rig's calibration with the
    indices of the pairs it used (None if none was made)."""
    s = board.square_mm
    cands = [rig_candidates(pl, pr, board) for pl, pr in zip(poses_l, poses_r, strict=True)]
    n = len(cands)
    Rs = np.array([[c.R for c in cs] for cs in cands])  # (n, 18, 3, 3)
    Ts = np.array([[c.T for c in cs] for cs in cands])  # (n, 18, 3)
    hyps = [(i, j) for i in range(n) for j, c in enumerate(cands[i]) if not c.shifted]
    best: tuple[int, float, int, int] | None = None
    for i, j in hyps:
        dmin = _rig_distances(Rs, Ts, Rs[i, j], Ts[i, j], s).min(axis=1)
        support = int(np.sum(dmin < 1.0))
        cost = float(np.sum(np.minimum(dmin, 1.0)))
        if best is None or (support, -cost) > (best[0], -best[1]):
            best = (support, cost, i, j)
    if best is None or best[0] < max(3, math.ceil(n / 2)):
        return (
            [RigVerdict("ok", None, float("nan")) for _ in range(n)],
            "rig check inconclusive: the pairs' board poses agree on no common rig "
            f"({0 if best is None else best[0]} of {n} pairs agree); left/right grids unverified",
            None,
        )
    R_c = Rs[best[2], best[3]]
    d = _rig_distances(Rs, Ts, R_c, Ts[best[2], best[3]], s)
    near = d.argmin(axis=1)
    agree = d[np.arange(n), near] < 1.0
    # the rig itself: stereo calibration of the agreeing pairs (reversed grids turned round)
    seed = [i for i in range(n) if agree[i] and not cands[i][near[i]].shifted]
    img_l = [np.asarray(corners[i][0], dtype=np.float32).reshape(-1, 1, 2) for i in seed]
    img_r = [
        np.asarray(corners[i][1][::-1] if cands[i][near[i]].flip else corners[i][1])
        .astype(np.float32)
        .reshape(-1, 1, 2)
        for i in seed
    ]
    try:
        st = _stereo(
            board.object_points().astype(np.float64),
            img_l,
            img_r,
            cams[0][0],
            cams[0][1],
            cams[1][0],
            cams[1][1],
            image_size,
            flags,
        )
        calib = _as_calibration(image_size, st.K_l, st.d_l, st.K_r, st.d_r, st.R, st.T)
    except CheckerboardError as exc:
        return (
            [RigVerdict("ok", None, float("nan")) for _ in range(n)],
            f"rig check inconclusive ({exc}); left/right grids unverified",
            None,
        )
    fits = [mapping_fits_mm(calib, c[0], c[1], board) for c in corners]
    tol = rig_tolerance_mm([float(f[0]) for f in fits], board)
    flipped_seed = any(cands[i][near[i]].flip for i in seed)
    return [pair_verdict(f, tol, board) for f in fits], None, (None if flipped_seed else (seed, st))


def robust_outlier(errors: FloatArray) -> tuple[int, float] | None:
    """Index and robust z-score of the worst view if it is an outlier, else None.

    Rule: z = 0.6745·(e − median)/MAD > ``OUTLIER_Z`` (3.5, Iglewicz & Hoaglin's modified
    z-score), e > ``OUTLIER_RATIO`` × median and e − median > ``OUTLIER_MIN_EXCESS_PX``
    (so that a set of uniformly tight views with a tiny MAD drops nothing)."""
    e = np.asarray(errors, dtype=np.float64)
    med = float(np.median(e))
    mad = float(np.median(np.abs(e - med)))
    k = int(np.argmax(e))
    z = 0.6745 * (e[k] - med) / mad if mad > 0 else (math.inf if e[k] > med else 0.0)
    if z > OUTLIER_Z and e[k] > OUTLIER_RATIO * med and e[k] - med > OUTLIER_MIN_EXCESS_PX:
        return k, float(z)
    return None


def _rodrigues_many(rvecs: FloatArray) -> FloatArray:
    """(N, 3) rotation vectors → (N, 3, 3) matrices."""
    theta = np.linalg.norm(rvecs, axis=1)
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = rvecs / safe[:, None]
    kx = np.zeros((len(rvecs), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2] = -k[:, 2], k[:, 1]
    kx[:, 1, 0], kx[:, 1, 2] = k[:, 2], -k[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -k[:, 1], k[:, 0]
    s = np.sin(theta)[:, None, None]
    c = (1 - np.cos(theta))[:, None, None]
    return np.asarray(np.eye(3)[None] + s * kx + c * (kx @ kx), dtype=np.float64)


def _project_skew(cam: FloatArray, n_dist: int, X: FloatArray) -> FloatArray:
    """Eqs. 2 + 7 with skew: camera-frame points (..., 3) → distorted pixels (..., 2).

    ``cam`` = [fx, fy, γ, u0, v0, k1, k2(, p1, p2, k3)]; same model as
    :func:`app.geometry.projection.project_camera`.
    """
    fx, fy, g, u0, v0 = cam[:5]
    k1, k2 = cam[5], cam[6]
    p1, p2, k3 = (cam[7], cam[8], cam[9]) if n_dist == 5 else (0.0, 0.0, 0.0)
    x = X[..., 0] / X[..., 2]
    y = X[..., 1] / X[..., 2]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fx * xd + g * yd + u0, fy * yd + v0], axis=-1)


def refine_with_skew(
    obj: FloatArray,
    img_l: Sequence[FloatArray],
    img_r: Sequence[FloatArray],
    K_l: FloatArray,
    d_l: FloatArray,
    K_r: FloatArray,
    d_r: FloatArray,
    R: FloatArray,
    T: FloatArray,
    rvecs: Sequence[FloatArray],
    tvecs: Sequence[FloatArray],
    model: str,
) -> _Stereo:
    """Joint refinement of both cameras *with* the skew γ of eq. 2, the rig (R, T) and every
    board pose, by sparse least squares (scipy), started from OpenCV's skew-free result.

    This restores the parameter the paper's calibration (Zhang's method) estimates and
    OpenCV's model lacks.
    """
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    n_dist = 2 if model == "paper" else 5
    nc = 5 + n_dist
    n_views = len(img_l)
    obs_l = np.stack([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in img_l])
    obs_r = np.stack([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in img_r])
    n_pts = obs_l.shape[1]
    X = np.asarray(obj, dtype=np.float64).reshape(-1, 3)

    def cam_vec(K: FloatArray, d: FloatArray) -> FloatArray:
        dd = np.zeros(5)
        dd[: min(5, d.size)] = d.ravel()[:5]
        terms = dd[:2] if n_dist == 2 else dd
        return np.concatenate([[K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]], terms])

    x0 = np.concatenate(
        [
            cam_vec(K_l, d_l),
            cam_vec(K_r, d_r),
            cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel(),
            np.asarray(T, dtype=np.float64).ravel(),
            np.concatenate(
                [
                    np.concatenate([np.ravel(rv), np.ravel(tv)])
                    for rv, tv in zip(rvecs, tvecs, strict=True)
                ]
            ),
        ]
    )
    o_rig = 2 * nc
    o_views = o_rig + 6

    def residuals(x: FloatArray) -> FloatArray:
        poses = x[o_views:].reshape(n_views, 6)
        Rv = _rodrigues_many(poses[:, :3])
        Xl = np.einsum("nij,pj->npi", Rv, X) + poses[:, None, 3:]
        R_rig = _rodrigues_many(x[o_rig : o_rig + 3][None])[0]
        Xr = Xl @ R_rig.T + x[o_rig + 3 : o_rig + 6]
        el = _project_skew(x[:nc], n_dist, Xl) - obs_l
        er = _project_skew(x[nc : 2 * nc], n_dist, Xr) - obs_r
        return np.concatenate([el, er], axis=1).ravel()

    n_res = n_views * 2 * n_pts * 2
    sparsity = lil_matrix((n_res, x0.size), dtype=np.int8)
    for i in range(n_views):
        base = i * 4 * n_pts
        left_rows = slice(base, base + 2 * n_pts)
        right_rows = slice(base + 2 * n_pts, base + 4 * n_pts)
        view_cols = slice(o_views + 6 * i, o_views + 6 * i + 6)
        sparsity[left_rows, 0:nc] = 1
        sparsity[left_rows, view_cols] = 1
        sparsity[right_rows, nc : 2 * nc] = 1
        sparsity[right_rows, o_rig : o_rig + 6] = 1
        sparsity[right_rows, view_cols] = 1
    sol = least_squares(
        residuals,
        x0,
        jac_sparsity=sparsity,
        method="trf",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=200,
    )
    x = sol.x
    e = residuals(x).reshape(n_views, 2, n_pts, 2)
    sq = np.sum(e**2, axis=3)  # (views, cam, pts)
    per_view = np.sqrt(np.mean(sq, axis=2))

    def unpack(v: FloatArray) -> tuple[FloatArray, FloatArray]:
        K = np.array([[v[0], v[2], v[3]], [0.0, v[1], v[4]], [0.0, 0.0, 1.0]])
        d = np.zeros(5)
        d[:n_dist] = v[5 : 5 + n_dist]
        return K, d

    Kl, dl = unpack(x[:nc])
    Kr, dr = unpack(x[nc : 2 * nc])
    poses = x[o_views:].reshape(n_views, 6)
    return _Stereo(
        rms=float(np.sqrt(np.mean(sq))),
        K_l=Kl,
        d_l=dl,
        K_r=Kr,
        d_r=dr,
        R=_rodrigues_many(x[o_rig : o_rig + 3][None])[0],
        T=x[o_rig + 3 : o_rig + 6].copy(),
        rvecs=[p[:3].reshape(3, 1) for p in poses],
        tvecs=[p[3:].reshape(3, 1) for p in poses],
        per_view=per_view,
    )


@dataclass
class _Stereo:
    """One joint stereo fit (``stereoCalibrateExtended`` or :func:`refine_with_skew`): RMS
    (px), intrinsics, rig (mm), board poses and per-view RMS (px)."""

    rms: float
    K_l: FloatArray
    d_l: FloatArray
    K_r: FloatArray
    d_r: FloatArray
    R: FloatArray
    T: FloatArray
    rvecs: list[FloatArray]
    tvecs: list[FloatArray]
    per_view: FloatArray  # (n, 2) RMS px

    @property
    def rms_l(self) -> float:
        """Left camera's RMS (px) over all views (equal point counts per view)."""
        return float(np.sqrt(np.mean(self.per_view[:, 0] ** 2)))

    @property
    def rms_r(self) -> float:
        return float(np.sqrt(np.mean(self.per_view[:, 1] ** 2)))


def _opencv_failed(exc: cv2.error) -> CheckerboardError:
    first = str(exc).strip().splitlines()[-1] if str(exc).strip() else "OpenCV error"
    return CheckerboardError(f"calibration failed in OpenCV ({first}); check the views")


def _stereo(
    obj: FloatArray,
    img_l: Sequence[NDArray[np.float32]],
    img_r: Sequence[NDArray[np.float32]],
    K_l: FloatArray,
    d_l: FloatArray,
    K_r: FloatArray,
    d_r: FloatArray,
    size: tuple[int, int],
    flags: int,
    criteria: tuple[int, int, float] = _TERM,
) -> _Stereo:
    o = [obj.astype(np.float32)] * len(img_l)
    try:
        res = cv2.stereoCalibrateExtended(
            o,
            list(img_l),
            list(img_r),
            K_l.copy(),
            d_l.copy(),
            K_r.copy(),
            d_r.copy(),
            size,
            np.eye(3),
            np.zeros((3, 1)),
            flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
            criteria=criteria,
        )
    except cv2.error as exc:
        raise _opencv_failed(exc) from None
    rms, Kl, dl, Kr, dr, R, T, _E, _F, rvecs, tvecs, per_view = res
    return _Stereo(
        float(rms),
        np.asarray(Kl, dtype=np.float64),
        np.asarray(dl, dtype=np.float64).ravel(),
        np.asarray(Kr, dtype=np.float64),
        np.asarray(dr, dtype=np.float64).ravel(),
        np.asarray(R, dtype=np.float64),
        np.asarray(T, dtype=np.float64).ravel(),
        [np.asarray(v, dtype=np.float64) for v in rvecs],
        [np.asarray(v, dtype=np.float64) for v in tvecs],
        np.asarray(per_view, dtype=np.float64).reshape(len(img_l), 2),
    )


def _as_calibration(
    size: tuple[int, int],
    K_l: FloatArray,
    d_l: FloatArray,
    K_r: FloatArray,
    d_r: FloatArray,
    R: FloatArray,
    T: FloatArray,
) -> StereoCalibration:
    data = {
        "image_size": [size[0], size[1]],
        "left": {"K": K_l.tolist(), "dist": d_l[:5].tolist()},
        "right": {"K": K_r.tolist(), "dist": d_r[:5].tolist()},
        "R": np.asarray(R, dtype=np.float64).tolist(),
        "T": np.asarray(T, dtype=np.float64).ravel().tolist(),
        "units": "mm",
    }
    try:
        return StereoCalibration.from_dict(data)
    except CalibrationError as exc:
        raise CheckerboardError(f"calibration result is invalid: {exc}") from None


def board_residuals_mm(
    calib: StereoCalibration, left: NDArray[Any], right: NDArray[Any], board: Board
) -> FloatArray:
    """Triangulate one view's corners (eqs. 15–16 on undistorted pixels) and return the
    distances between neighbouring corners minus the square size (mm)."""
    xl = undistort_pixels(calib.left, np.asarray(left, dtype=np.float64).reshape(-1, 2))
    xr = undistort_pixels(calib.right, np.asarray(right, dtype=np.float64).reshape(-1, 2))
    X = triangulate_linear(calib.P_left, calib.P_right, xl, xr).reshape(board.rows, board.cols, 3)
    d = np.concatenate(
        [
            np.linalg.norm(np.diff(X, axis=1), axis=2).ravel(),
            np.linalg.norm(np.diff(X, axis=0), axis=2).ravel(),
        ]
    )
    return np.asarray(d - board.square_mm, dtype=np.float64)


def held_out_check(
    names: Sequence[str],
    img_l: Sequence[NDArray[np.float32]],
    img_r: Sequence[NDArray[np.float32]],
    fit: _Stereo,
    board: Board,
    size: tuple[int, int],
    flags: int,
    folds: int | None = None,
) -> HeldOutCheck:
    """Cross-validated scale check: split the views into ``folds`` groups (default
    min(views, ``HELD_OUT_MAX_FOLDS``); every ``folds``-th view in a group), recalibrate the
    rig without each group (started from ``fit``) and triangulate the group's boards; the
    residual is neighbouring-corner distance − square size (mm)."""
    n = len(img_l)
    k = max(2, min(n, folds or HELD_OUT_MAX_FOLDS))
    obj = board.object_points().astype(np.float64)
    per_view: dict[str, float] = {}
    all_res = []
    for f in range(k):
        test = list(range(f, n, k))
        train = [i for i in range(n) if i % k != f]
        sub = _stereo(
            obj,
            [img_l[i] for i in train],
            [img_r[i] for i in train],
            fit.K_l,
            fit.d_l,
            fit.K_r,
            fit.d_r,
            size,
            flags,
            _TERM_FOLD,
        )
        calib = _as_calibration(size, sub.K_l, sub.d_l, sub.K_r, sub.d_r, sub.R, sub.T)
        for i in test:
            r = board_residuals_mm(calib, img_l[i], img_r[i], board)
            per_view[names[i]] = float(np.sqrt(np.mean(r**2)))
            all_res.append(r)
    res = np.concatenate(all_res)
    return HeldOutCheck(
        folds=k,
        rms_mm=float(np.sqrt(np.mean(res**2))),
        max_mm=float(np.max(np.abs(res))),
        per_view_rms_mm=per_view,
    )


@dataclass
class CheckerboardCalibration:
    """Result of :func:`calibrate_from_detections`: the validated calibration and its report.

    ``detections`` are as used (a reversed right grid corrected, rig-check rejections set);
    ``used``: indices into ``detections`` of the views in the final calibration."""

    calibration: StereoCalibration
    report: CalibrationReport
    detections: list[PairDetection]
    used: list[int]

    def save(self, path: str | Path) -> None:
        self.calibration.save(path)


def _too_few_message(detections: Sequence[PairDetection], n_ok: int) -> str:
    counts: dict[str, int] = {}
    for det in detections:
        r = det.reason
        if r is not None:
            key = r.split(":")[0] if det.rejected else r
            counts[key] = counts.get(key, 0) + 1
    why = "; ".join(f"{n} {r}" for r, n in sorted(counts.items(), key=lambda kv: -kv[1]))
    return (
        f"too few usable views: {n_ok} of {len(detections)} pairs have the board in both images, "
        f"need at least {MIN_VIEWS}" + (f" ({why})" if why else "")
    )


def calibrate_from_detections(
    detections: Sequence[PairDetection],
    board: Board,
    model: Model | str = "paper",
    max_stereo_rms_px: float = DEFAULT_MAX_STEREO_RMS_PX,
    hint: Callable[[], str | None] | None = None,
    estimate_skew: bool = False,
    drop_outliers: bool = True,
    held_out_folds: int | None = None,
) -> CheckerboardCalibration:
    """Calibrate both cameras, check the pairs, then the rig (steps 1–6 of the module doc).

    ``estimate_skew``: refine everything jointly with the skew γ of eq. 2 at the end
    (:func:`refine_with_skew`; OpenCV alone writes γ = 0). ``drop_outliers``: the robust view
    dropping of step 4. ``held_out_folds``: 0 skips the held-out check. ``hint`` is called
    when too few views are usable to add e.g. a board-size suggestion."""
    if model not in MODEL_FLAGS:
        raise CheckerboardError(f"model {model!r}: expected one of {sorted(MODEL_FLAGS)}")
    if not detections:
        raise CheckerboardError("no images given")
    flags = MODEL_FLAGS[model]
    dets = list(detections)
    both = [k for k, d in enumerate(dets) if d.usable]
    if len(both) < MIN_VIEWS:
        msg = _too_few_message(dets, len(both))
        extra = hint() if hint is not None else None
        raise CheckerboardError(msg + (f"; {extra}" if extra else ""))
    size = dets[0].image_size
    obj = board.object_points()

    def pts(k: int, side: str) -> NDArray[np.float32]:
        p = dets[k].left if side == "left" else dets[k].right
        return np.asarray(p, dtype=np.float32).reshape(-1, 1, 2)

    # 1. each camera alone
    try:
        rms_l, K_l0, d_l0, rv_l, tv_l = cv2.calibrateCamera(
            [obj] * len(both), [pts(k, "left") for k in both], size, None, None,
            flags=flags, criteria=_TERM,
        )  # fmt: skip
        rms_r, K_r0, d_r0, rv_r, tv_r = cv2.calibrateCamera(
            [obj] * len(both), [pts(k, "right") for k in both], size, None, None,
            flags=flags, criteria=_TERM,
        )  # fmt: skip
    except cv2.error as exc:
        raise _opencv_failed(exc) from None
    warnings: list[str] = []
    # 2. rig check: the two grids of a pair are the same corners in the same order
    verdicts, inconclusive, seed = rig_check(
        [_pose(r, t) for r, t in zip(rv_l, tv_l, strict=True)],
        [_pose(r, t) for r, t in zip(rv_r, tv_r, strict=True)],
        board,
        (
            (np.asarray(K_l0, dtype=np.float64), np.asarray(d_l0, dtype=np.float64)),
            (np.asarray(K_r0, dtype=np.float64), np.asarray(d_r0, dtype=np.float64)),
        ),
        [
            (
                np.asarray(dets[k].left, dtype=np.float64),
                np.asarray(dets[k].right, dtype=np.float64),
            )
            for k in both
        ],
        size,
        flags,
    )
    if inconclusive:
        warnings.append(inconclusive)
    flipped = []
    for k, verdict in zip(both, verdicts, strict=True):
        if verdict.action == "flipped":
            right = np.asarray(dets[k].right)[::-1].copy()
            dets[k] = replace(dets[k], right=right)
            flipped.append(dets[k].name)
        elif verdict.action == "rejected":
            dets[k] = replace(dets[k], rejected=verdict.reason)
    if flipped:
        warnings.append(
            f"right grid reversed to match the left one in pair(s) {', '.join(flipped)}"
        )
    used = [k for k in both if dets[k].usable]
    if len(used) < MIN_VIEWS:
        raise CheckerboardError(_too_few_message(dets, len(used)))
    K_l = np.asarray(K_l0, dtype=np.float64)
    K_r = np.asarray(K_r0, dtype=np.float64)
    d_l = np.asarray(d_l0, dtype=np.float64).ravel()
    d_r = np.asarray(d_r0, dtype=np.float64).ravel()
    # 3.-4. joint refinement, dropping outlier views one at a time
    objd = obj.astype(np.float64)
    dropped: list[DroppedView] = []
    max_drops = int(MAX_DROP_FRACTION * len(used))
    # the rig check's calibration is the first fit when it used exactly these pairs
    reuse = seed is not None and [both[i] for i in seed[0]] == used and not flipped
    while True:
        if reuse and seed is not None:
            fit, reuse = seed[1], False
        else:
            fit = _stereo(
                objd, [pts(k, "left") for k in used], [pts(k, "right") for k in used],
                K_l, d_l, K_r, d_r, size, flags,
            )  # fmt: skip
        if not drop_outliers or len(dropped) >= max_drops or len(used) <= MIN_VIEWS:
            break
        err = np.sqrt(np.mean(fit.per_view**2, axis=1))
        out = robust_outlier(err)
        if out is None:
            break
        i, z = out
        k = used.pop(i)
        med = float(np.median(err))
        dropped.append(
            DroppedView(
                dets[k].name,
                f"reprojection outlier: RMS {err[i]:.3f} px vs median {med:.3f} px "
                f"(robust z {z:.1f} > {OUTLIER_Z})",
                float(err[i]),
                float(z),
            )
        )
        K_l, d_l, K_r, d_r = fit.K_l, fit.d_l, fit.K_r, fit.d_r
    K_l, d_l, K_r, d_r, R, T = fit.K_l, fit.d_l, fit.K_r, fit.d_r, fit.R, fit.T
    stereo_rms, per_view = fit.rms, fit.per_view
    K_l[0, 1] = K_r[0, 1] = 0.0
    img_l = [pts(k, "left") for k in used]
    img_r = [pts(k, "right") for k in used]
    # 6. held-out scale check (OpenCV's model; before the skew refinement)
    names = [dets[k].name for k in used]
    held = (
        None
        if held_out_folds == 0
        else held_out_check(names, img_l, img_r, fit, board, size, flags, held_out_folds)
    )
    # 5. skew
    if estimate_skew:
        sk = refine_with_skew(
            objd,
            [np.asarray(p, dtype=np.float64) for p in img_l],
            [np.asarray(p, dtype=np.float64) for p in img_r],
            K_l, d_l, K_r, d_r, R, T, fit.rvecs, fit.tvecs, str(model),
        )  # fmt: skip
        K_l, d_l, K_r, d_r, R, T = sk.K_l, sk.d_l, sk.K_r, sk.d_r, sk.R, sk.T
        stereo_rms, per_view, rms_l, rms_r = sk.rms, sk.per_view, sk.rms_l, sk.rms_r
    calib = _as_calibration(size, K_l, d_l, K_r, d_r, R, T)

    views = [
        ViewReport(
            dets[k].name,
            float(per_view[i, 0]),
            float(per_view[i, 1]),
            None if held is None else held.per_view_rms_mm[dets[k].name],
        )
        for i, k in enumerate(used)
    ]
    rejected = [RejectedView(d.name, d.reason or "") for d in dets if d.reason is not None]
    if stereo_rms > max_stereo_rms_px:
        warnings.append(
            f"stereo RMS {stereo_rms:.3f} px is above {max_stereo_rms_px:.3f} px: check focus, "
            "board flatness, that left/right pairs were taken at the same instant, and the worst views"
        )
    med = float(np.median(per_view))
    for v in views:
        worst = max(v.left_rms_px, v.right_rms_px)
        if worst > max(3 * med, max_stereo_rms_px):
            warnings.append(f"view {v.name} fits poorly ({worst:.3f} px vs median {med:.3f} px)")
    for r in rejected:
        warnings.append(f"pair {r.name} rejected: {r.reason}")
    for dv in dropped:
        warnings.append(f"pair {dv.name} dropped: {dv.reason}")
    if len(used) < 10:
        warnings.append(f"only {len(used)} usable views; 10-20 varied views are recommended")
    cov = coverage_map(
        [np.asarray(dets[k].left) for k in used], [np.asarray(dets[k].right) for k in used], size
    )
    warnings.extend(coverage_warnings(cov))
    detectors: dict[str, int] = {}
    for d in dets:
        for m in (d.left_method, d.right_method):
            if m is not None:
                detectors[m] = detectors.get(m, 0) + 1
    rot_deg = float(np.degrees(np.linalg.norm(cv2.Rodrigues(calib.R)[0])))
    report = CalibrationReport(
        board=f"{board.cols}x{board.rows}",
        square_mm=float(board.square_mm),
        model=str(model),
        image_size=(int(size[0]), int(size[1])),
        pairs_given=len(dets),
        views_used=len(used),
        views=views,
        rejected=rejected,
        left_rms_px=float(rms_l),
        right_rms_px=float(rms_r),
        stereo_rms_px=float(stereo_rms),
        max_stereo_rms_px=float(max_stereo_rms_px),
        baseline_mm=calib.baseline_mm,
        convergence_deg=calib.convergence_deg,
        T_mm=[float(x) for x in calib.T],
        rotation_deg=rot_deg,
        intrinsics={"left": intrinsics_summary(K_l, d_l), "right": intrinsics_summary(K_r, d_r)},
        warnings=warnings,
        notes=[
            SKEW_REFINED_NOTE if estimate_skew else SKEW_NOTE,
            "Distortion model: "
            + ("k1, k2 only (the paper's eq. 7)" if model == "paper" else "k1, k2, p1, p2, k3"),
            "Convention: X_right = R * X_left + T (mm); left camera frame = world frame.",
            f"Outlier rule: a view is dropped when its RMS has robust z-score "
            f"0.6745*(e - median)/MAD > {OUTLIER_Z}, e > {OUTLIER_RATIO} x median and "
            f"e > median + {OUTLIER_MIN_EXCESS_PX} px "
            f"(at most {int(100 * MAX_DROP_FRACTION)} % of the views).",
        ],
        dropped=dropped,
        coverage=cov,
        held_out=held,
        detectors=detectors,
    )
    return CheckerboardCalibration(calib, report, dets, used)


def calibrate_checkerboard(
    names: Sequence[str],
    lefts: Sequence[NDArray[Any]],
    rights: Sequence[NDArray[Any]],
    board: Board,
    model: Model | str = "paper",
    max_stereo_rms_px: float = DEFAULT_MAX_STEREO_RMS_PX,
    progress: bool = False,
    estimate_skew: bool = False,
    workers: int | None = None,
    drop_outliers: bool = True,
    held_out_folds: int | None = None,
) -> CheckerboardCalibration:
    """Whole workflow on in-memory images: size checks, detection, calibration, report."""
    if model not in MODEL_FLAGS:
        raise CheckerboardError(f"model {model!r}: expected one of {sorted(MODEL_FLAGS)}")
    if len(names) < MIN_VIEWS:
        check_image_sizes(names, lefts, rights)
        raise CheckerboardError(
            f"too few usable views: only {len(names)} pairs given, need at least {MIN_VIEWS} "
            "(10-20 varied board poses are recommended)"
        )
    detections = detect_pairs(
        names, lefts, rights, board.pattern_size, progress=progress, workers=workers
    )

    def hint() -> str | None:
        if any(d.left is not None or d.right is not None for d in detections):
            return None
        cand = suggest_board(lefts[0], board.pattern_size)
        if cand is None:
            return (
                f"no {board.cols}x{board.rows} board was found in any image; --board counts "
                "inner corners (squares - 1 per side)"
            )
        return (
            f"board size does not match: no {board.cols}x{board.rows} board found, but a "
            f"{cand[0]}x{cand[1]} board is visible in pair {names[0]} (--board counts inner corners)"
        )

    kwargs: dict[str, Any] = {
        "estimate_skew": estimate_skew,
        "drop_outliers": drop_outliers,
        "held_out_folds": held_out_folds,
    }
    result = calibrate_from_detections(detections, board, model, max_stereo_rms_px, hint, **kwargs)
    dets, fixed = redetect_rejected(result, lefts, rights, board)
    if not fixed:
        return result
    again = calibrate_from_detections(dets, board, model, max_stereo_rms_px, hint, **kwargs)
    again.report.warnings.append(
        "rig check: grids re-detected with another detector, now consistent: " + "; ".join(fixed)
    )
    return again


def redetect_rejected(
    result: CheckerboardCalibration,
    lefts: Sequence[NDArray[Any]],
    rights: Sequence[NDArray[Any]],
    board: Board,
) -> tuple[list[PairDetection], list[str]]:
    """Correct pairs the rig check rejected: their images are searched again with the other
    detectors (a detector can lock onto a grid offset by a column); the first combination of
    grids (new left, new right, both) that :func:`pair_verdict` accepts under ``result``'s
    rig replaces the pair. Returns the detections and one line per corrected pair."""
    dets = list(result.detections)
    fixed: list[str] = []
    if not any(d.rejected is not None for d in dets):
        return dets, fixed
    kept = [dets[k] for k in result.used]
    as_detected = [
        mapping_fits_mm(result.calibration, np.asarray(d.left), np.asarray(d.right), board)[0]
        for d in kept
    ]
    tol = rig_tolerance_mm([float(f) for f in as_detected], board)
    for k, d in enumerate(dets):
        if d.rejected is None or d.left is None or d.right is None:
            continue
        alt = []
        for img, used in ((lefts[k], d.left_method), (rights[k], d.right_method)):
            others = [m for m in METHODS if used is None or not used.startswith(m)]
            alt.append(detect_corners_detail(img, board.pattern_size, others))
        alt_l, alt_r = alt
        combos: list[tuple[CornerResult | None, CornerResult | None]]
        combos = [(alt_l, None)] if alt_l is not None else []
        combos += [(None, alt_r)] if alt_r is not None else []
        combos += [(alt_l, alt_r)] if alt_l is not None and alt_r is not None else []
        for cl, cr in combos:
            left = d.left if cl is None else cl.corners
            right = d.right if cr is None else cr.corners
            right = match_orientation(left, right)
            fit = mapping_fits_mm(result.calibration, left, right, board)
            verdict = pair_verdict(fit, tol, board)
            if verdict.action == "rejected":
                continue
            if verdict.action == "flipped":
                right = right[::-1].copy()
            dets[k] = PairDetection(
                d.name,
                d.image_size,
                left,
                right,
                d.left_method if cl is None else cl.method,
                d.right_method if cr is None else cr.method,
            )
            sides = [f"{side} by {r.method}" for side, r in (("left", cl), ("right", cr)) if r]
            fixed.append(f"pair {d.name} ({', '.join(sides)})")
            break
    return dets, fixed
