"""Pinhole projection with radial/tangential distortion and skew (paper eqs. 1–2, 7).

OpenCV's ``projectPoints``/``undistortPoints`` ignore the skew term ``K[0, 1]``; the paper's
rig has γ ≠ 0, so OpenCV does the distortion on normalised coordinates (identity camera
matrix) and the full ``K`` (with γ) is applied here.
"""

from __future__ import annotations

import cv2
import numpy as np

from app.geometry.calibration import CameraIntrinsics, StereoCalibration
from app.types import FloatArray

_EYE = np.eye(3)
_ZERO3 = np.zeros(3)


def _as_points(points: FloatArray, dim: int) -> FloatArray:
    arr = np.asarray(points, dtype=np.float64).reshape(-1, dim)
    return arr


def project_camera(cam: CameraIntrinsics, xyz_cam_mm: FloatArray) -> FloatArray:
    """Project points given in this camera's frame (mm) to distorted pixels (N×2, px)."""
    pts = _as_points(xyz_cam_mm, 3)
    if len(pts) == 0:
        return np.zeros((0, 2))
    xd, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), _ZERO3, _ZERO3, _EYE, cam.dist)
    xd = xd.reshape(-1, 2)
    homog = np.column_stack([xd, np.ones(len(xd))])
    return np.asarray((cam.K @ homog.T).T[:, :2], dtype=np.float64)


def undistort_pixels(cam: CameraIntrinsics, px: FloatArray) -> FloatArray:
    """Distorted pixels → ideal (undistorted) pixels in the same K (N×2, px), inverse of eq. 7."""
    pts = _as_points(px, 2)
    if len(pts) == 0:
        return np.zeros((0, 2))
    k_inv, k = cam.K_inv, cam.K
    norm_d = pts @ k_inv[:2, :2].T + k_inv[:2, 2]  # K⁻¹ (last row 0 0 1)
    norm = cv2.undistortPoints(
        norm_d.reshape(-1, 1, 2),
        _EYE,
        cam.dist,
        None,
        None,
        None,
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12),
    ).reshape(-1, 2)
    return np.asarray(norm @ k[:2, :2].T + k[:2, 2], dtype=np.float64)


def project_stereo(calib: StereoCalibration, xyz_mm: FloatArray) -> tuple[FloatArray, FloatArray]:
    """World (= left camera) points in mm → (left px, right px), distorted, N×2 each."""
    pts = _as_points(xyz_mm, 3)
    right_cam = (calib.R @ pts.T).T + calib.T
    return project_camera(calib.left, pts), project_camera(calib.right, right_cam)


def project_ideal(P: FloatArray, xyz_mm: FloatArray) -> FloatArray:
    """Project with a 3×4 matrix (eqs. 4–5) to ideal (undistorted) pixels, N×2."""
    pts = _as_points(xyz_mm, 3)
    h = (P @ np.column_stack([pts, np.ones(len(pts))]).T).T
    return np.asarray(h[:, :2] / h[:, 2:3], dtype=np.float64)
