"""The OpenCV calls of the checkerboard calibration (paper §3.2, Zhang's method [18, 19]),
wrapped: one camera alone (``cv2.calibrateCamera``: Zhang's closed form + LM), the joint
stereo refinement (``cv2.stereoCalibrateExtended``, intrinsics as initial guess) and the
result as a validated :class:`~app.geometry.calibration.StereoCalibration`.

Distortion models (:data:`MODEL_FLAGS`): ``"paper"`` estimates k1, k2 only
(``CALIB_FIX_K3 | CALIB_ZERO_TANGENT_DIST``, the paper's eq. 7); ``"full"`` estimates OpenCV's
five terms k1, k2, p1, p2, k3. OpenCV's model has no skew γ (eq. 2): see
:mod:`app.calibration.skew_refinement`. An OpenCV failure raises
:class:`~app.calibration.board.CheckerboardError` with a one-line message.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from app.calibration.board import CheckerboardError
from app.geometry.calibration import CalibrationError, StereoCalibration
from app.types import FloatArray

Model = Literal["paper", "full"]
MODEL_FLAGS: dict[str, int] = {
    "paper": cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "full": 0,
}
TERM = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-10)
TERM_FOLD = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-8)


def board_pose(rvec: FloatArray, tvec: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(R 3×3, t 3 mm) of a board pose from OpenCV's rotation and translation vectors."""
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return np.asarray(R, dtype=np.float64), np.asarray(tvec, dtype=np.float64).ravel()


@dataclass
class CameraFit:
    """One camera calibrated alone (``cv2.calibrateCamera``): RMS (px), K, distortion and the
    board poses (OpenCV's rotation and translation vectors, mm)."""

    rms: float
    K: FloatArray
    dist: FloatArray
    rvecs: list[FloatArray]
    tvecs: list[FloatArray]


def calibrate_camera(
    obj: NDArray[np.float32],
    img: Sequence[NDArray[np.float32]],
    size: tuple[int, int],
    flags: int,
) -> CameraFit:
    """One camera alone from the board's corners ``obj`` (N×3 mm) seen in ``img`` (one N×1×2
    px array per view): Zhang's closed form + LM (``cv2.calibrateCamera``)."""
    try:
        rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
            [obj] * len(img), list(img), size, None, None, flags=flags, criteria=TERM
        )
    except cv2.error as exc:
        raise opencv_failed(exc) from None
    return CameraFit(
        float(rms),
        np.asarray(K, dtype=np.float64),
        np.asarray(dist, dtype=np.float64),
        [np.asarray(v, dtype=np.float64) for v in rvecs],
        [np.asarray(v, dtype=np.float64) for v in tvecs],
    )


@dataclass
class StereoFit:
    """One joint stereo fit (:func:`stereo_fit` or
    :func:`~app.calibration.skew_refinement.refine_with_skew`): RMS (px), intrinsics, rig
    (X_right = R·X_left + T, mm), board poses and per-view RMS (px)."""

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


def opencv_failed(exc: cv2.error) -> CheckerboardError:
    """The one-line error for an OpenCV failure (its last message line)."""
    first = str(exc).strip().splitlines()[-1] if str(exc).strip() else "OpenCV error"
    return CheckerboardError(f"calibration failed in OpenCV ({first}); check the views")


def stereo_fit(
    obj: FloatArray,
    img_l: Sequence[NDArray[np.float32]],
    img_r: Sequence[NDArray[np.float32]],
    K_l: FloatArray,
    d_l: FloatArray,
    K_r: FloatArray,
    d_r: FloatArray,
    size: tuple[int, int],
    flags: int,
    criteria: tuple[int, int, float] = TERM,
) -> StereoFit:
    """Joint refinement of both cameras and the rig (``cv2.stereoCalibrateExtended``, the
    intrinsics as initial guess) from the board's corners ``obj`` (N×3 mm) seen in each
    view's ``img_l``/``img_r`` (N×1×2 px)."""
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
        raise opencv_failed(exc) from None
    rms, Kl, dl, Kr, dr, R, T, _E, _F, rvecs, tvecs, per_view = res
    return StereoFit(
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


def as_calibration(
    size: tuple[int, int],
    K_l: FloatArray,
    d_l: FloatArray,
    K_r: FloatArray,
    d_r: FloatArray,
    R: FloatArray,
    T: FloatArray,
) -> StereoCalibration:
    """The fit as a validated :class:`~app.geometry.calibration.StereoCalibration`
    (``size`` (w, h) px, mm); an invalid result raises ``CheckerboardError``."""
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
