"""The held-out scale check of a checkerboard calibration: each view's board is triangulated
with a calibration made without it (k-fold cross-validation) and the distances between its
neighbouring corners are compared with the true square size (mm).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.calibration.board import Board
from app.calibration.opencv_fit import TERM_FOLD, StereoFit, as_calibration, stereo_fit
from app.calibration.report import HeldOutCheck
from app.geometry.calibration import StereoCalibration
from app.geometry.projection import undistort_pixels
from app.geometry.triangulation import triangulate_linear
from app.types import FloatArray

HELD_OUT_MAX_FOLDS = 3


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
    fit: StereoFit,
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
        sub = stereo_fit(
            obj,
            [img_l[i] for i in train],
            [img_r[i] for i in train],
            fit.K_l,
            fit.d_l,
            fit.K_r,
            fit.d_r,
            size,
            flags,
            TERM_FOLD,
        )
        calib = as_calibration(size, sub.K_l, sub.d_l, sub.K_r, sub.d_r, sub.R, sub.T)
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
