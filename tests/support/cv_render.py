"""An independent, OpenCV-only stereo renderer of small bright spheres (test helper).

The project's renderer (:mod:`app.sim.stereo_render`) shares its projection code with the
navigation pipeline, so a mistake there would be invisible to tests that render with it.
This module re-does the image formation with nothing but OpenCV and numpy: points are
projected with ``cv2.projectPoints`` (left camera: rvec = tvec = 0; right camera:
``cv2.Rodrigues(calib.R)`` and ``calib.T``), each sphere is a filled ``cv2.circle`` of
radius f·r/Z drawn with fractional ``shift`` bits on an 8×-supersampled patch, reduced with
``cv2.resize(INTER_AREA)`` (see FILL_BIAS_SUBPX), blurred with ``cv2.GaussianBlur`` and put on a noisy background.

``cv2.projectPoints`` has no skew term, so only skew-free calibrations are accepted (use
:func:`skew_free` to make one). The disc ignores the small stretch by the lens distortion
(the project's renderer models it), so the two renderers agree on centres, not on shapes.

It must not import ``app.geometry.projection`` or ``app.sim``.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import CameraIntrinsics, StereoCalibration

SUPERSAMPLE = 8  # sub-pixels per pixel side
SHIFT = 8  # fractional bits of the circle centre / radius given to cv2.circle
# A filled cv2.circle covers about as much as a disc 0.45 sub-pixel wider than its radius
# (boundary pixels are filled; measured over radii 16–96 sub-px): drawn that much smaller,
# the disc's area is right to < 1 % for LED images ≥ 2 px in radius.
FILL_BIAS_SUBPX = 0.45
_MIN_DEPTH_MM = 1.0


def skew_free(calib: StereoCalibration) -> StereoCalibration:
    """A copy of ``calib`` with the skew γ (K[0, 1]) of both cameras set to 0."""

    def flat(cam: CameraIntrinsics) -> CameraIntrinsics:
        K = np.array(cam.K, dtype=np.float64)
        K[0, 1] = 0.0
        return CameraIntrinsics(K=K, dist=np.array(cam.dist, dtype=np.float64))

    return replace(calib, left=flat(calib.left), right=flat(calib.right))


def _camera_matrix(cam: CameraIntrinsics, name: str) -> NDArray[np.float64]:
    if cam.skew != 0.0:
        raise ValueError(
            f"render_pair_cv: {name} camera has skew {cam.skew} px; cv2.projectPoints cannot "
            "model it (use skew_free(calib))"
        )
    return np.array([[cam.fx, 0.0, cam.u0], [0.0, cam.fy, cam.v0], [0.0, 0.0, 1.0]])


def project_cv(
    calib: StereoCalibration, xyz_mm: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(left px, right px, left depth mm, right depth mm) of world (= left camera) points.

    Pixel rows are NaN for a point behind (or within 1 mm of) that camera.
    """
    pts = np.asarray(xyz_mm, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        empty = np.zeros((0, 2))
        return empty, empty.copy(), np.zeros(0), np.zeros(0)
    K_l = _camera_matrix(calib.left, "left")
    K_r = _camera_matrix(calib.right, "right")
    dist_l = np.asarray(calib.left.dist, dtype=np.float64)
    dist_r = np.asarray(calib.right.dist, dtype=np.float64)
    rvec, _ = cv2.Rodrigues(np.asarray(calib.R, dtype=np.float64))
    tvec = np.asarray(calib.T, dtype=np.float64).reshape(3, 1)
    pl, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K_l, dist_l)
    pr, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), rvec, tvec, K_r, dist_r)
    pl = pl.reshape(-1, 2).astype(np.float64)
    pr = pr.reshape(-1, 2).astype(np.float64)
    z_l = pts[:, 2].copy()
    z_r = (np.asarray(calib.R) @ pts.T).T[:, 2] + float(calib.T[2])
    pl[z_l < _MIN_DEPTH_MM] = np.nan
    pr[z_r < _MIN_DEPTH_MM] = np.nan
    return pl, pr, z_l, z_r


def _draw_discs(
    size: tuple[int, int],
    centers_px: NDArray[np.float64],
    radii_px: NDArray[np.float64],
) -> NDArray[np.float32]:
    """Coverage (0..1, float32, H×W) of filled discs, each supersampled on its own patch."""
    w, h = size
    cover = np.zeros((h, w), dtype=np.float32)
    s, one = SUPERSAMPLE, 1 << SHIFT
    for (cx, cy), r in zip(centers_px, radii_px, strict=True):
        if not (np.isfinite(cx) and np.isfinite(cy) and np.isfinite(r) and r > 0):
            continue
        half = int(np.ceil(r)) + 2
        x0, y0 = int(round(cx)) - half, int(round(cy)) - half
        n = 2 * half + 1
        if x0 + n <= 0 or y0 + n <= 0 or x0 >= w or y0 >= h:
            continue
        patch = np.zeros((n * s, n * s), dtype=np.float32)
        # sub-pixel j of the patch has its centre at original x = x0 + (j + 0.5)/s − 0.5
        X = (cx - x0 + 0.5) * s - 0.5
        Y = (cy - y0 + 0.5) * s - 0.5
        centre = (int(round(X * one)), int(round(Y * one)))
        radius = int(round(max(r * s - FILL_BIAS_SUBPX, 0.5) * one))
        cv2.circle(patch, centre, radius, 1.0, -1, cv2.LINE_AA, SHIFT)
        small = cv2.resize(patch, (n, n), interpolation=cv2.INTER_AREA)
        xa, ya = max(x0, 0), max(y0, 0)
        xb, yb = min(x0 + n, w), min(y0 + n, h)
        cover[ya:yb, xa:xb] += small[ya - y0 : yb - y0, xa - x0 : xb - x0]
    return cover


def render_pair_cv(
    calib: StereoCalibration,
    led_xyz_mm: NDArray[np.float64],
    extra_xyz_mm: NDArray[np.float64] | None = None,
    led_diameter_mm: float = 5.0,
    peak: float = 235.0,
    background: float = 12.0,
    noise_sigma: float = 2.0,
    blur_sigma_px: float = 0.7,
    seed: int | None = 0,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.float64], NDArray[np.float64]]:
    """Grey stereo pair of spheres (diameter ``led_diameter_mm``) at the given points (mm).

    ``led_xyz_mm`` (N×3) and ``extra_xyz_mm`` (M×3, e.g. glints; optional) are drawn alike:
    a disc of radius f·r/Z (f = (fx + fy)/2 of that camera, Z its depth) and ``peak`` DN
    above ``background``, blurred by ``blur_sigma_px``, plus Gaussian noise
    ``noise_sigma`` (seeded by ``seed``). Returns (left, right, left px, right px), the px
    arrays (N+M)×2 with the LEDs first: the projection of each centre, NaN behind a camera.
    Points out of an image are simply not drawn there.
    """
    leds = np.asarray(led_xyz_mm, dtype=np.float64).reshape(-1, 3)
    extra = (
        np.zeros((0, 3))
        if extra_xyz_mm is None
        else np.asarray(extra_xyz_mm, dtype=np.float64).reshape(-1, 3)
    )
    pts = np.vstack([leds, extra])
    pl, pr, z_l, z_r = project_cv(calib, pts)
    r_mm = 0.5 * float(led_diameter_mm)
    w, h = calib.image_size
    rng = np.random.default_rng(seed)
    images = []
    for cam, px, z in ((calib.left, pl, z_l), (calib.right, pr, z_r)):
        f = 0.5 * (cam.fx + cam.fy)
        with np.errstate(divide="ignore", invalid="ignore"):
            radii = np.where(z >= _MIN_DEPTH_MM, f * r_mm / z, np.nan)
        img = _draw_discs((w, h), px, radii) * np.float32(peak)
        if blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), sigmaX=blur_sigma_px, sigmaY=blur_sigma_px)
        img = img + np.float32(background)
        if noise_sigma > 0:
            img = img + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(noise_sigma)
        images.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return images[0], images[1], pl, pr
