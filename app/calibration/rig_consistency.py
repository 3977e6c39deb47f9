"""The rig check of a checkerboard calibration: do a pair's two grids hold the same physical
corners in the same order?

Every pair's two board poses imply a rig (R, T); the rig most pairs agree on is calibrated
from them, and each pair's corners are then triangulated with it under every index mapping
(as detected, reversed, offset by ±1 column/row: :data:`MAPPINGS`) and fitted to the flat
board (:func:`mapping_fits_mm`). A pair whose right grid is the left one reversed is
corrected; a pair whose grids are offset by a column or row (not the same physical corners),
or that fits no mapping, is rejected with the reason (:func:`pair_verdict`,
:func:`rig_check`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.calibration.board import Board, CheckerboardError
from app.calibration.opencv_fit import StereoFit, as_calibration, stereo_fit
from app.geometry.calibration import StereoCalibration
from app.geometry.projection import undistort_pixels
from app.geometry.triangulation import triangulate_linear
from app.types import FloatArray

RIG_TOL_SQUARES = 0.4  # rig check: |ΔT| tolerance, in squares (candidates are 1 square apart)
RIG_TOL_DEG = 3.0  # rig check: rotation tolerance (deg)
RIG_MAX_FIT_SQUARES = 0.1  # rig check: worst accepted board-fit RMS, in squares ...
RIG_FIT_SPREAD = 5.0  # ... or this multiple of the median pair's fit (noisy corners)


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
) -> tuple[list[RigVerdict], str | None, tuple[list[int], StereoFit] | None]:
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
        st = stereo_fit(
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
        calib = as_calibration(image_size, st.K_l, st.d_l, st.K_r, st.d_r, st.R, st.T)
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
