"""The image of one emitting sphere (an LED, a glint): its disc through the full camera model
(centre by :func:`app.geometry.projection.project_stereo`, shape by the local Jacobian of the
distorted projection, eqs. 2 and 7) and its rendered patch — anti-aliased supersampled coverage
blurred by a symmetric Gaussian, every step point-symmetric about the projected centre, so an
intensity-weighted centroid (eq. 11) of the noise-free blob returns the truth pixel."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import CameraIntrinsics, StereoCalibration
from app.geometry.projection import project_camera
from app.sim.stereo_render.patch_kernels import (
    render_spots,
    spectral_norm_2x2,
    spot_patch,
)
from app.sim.stereo_render.scene import MIN_DEPTH_MM, RenderSettings
from app.types import FloatArray


@dataclass(frozen=True)
class LightSpot:
    center_px: FloatArray  # (2,) distorted px
    shape_px: FloatArray  # 2×2 A: unit disc → px ellipse around the centre
    peak: float  # DN
    bgr: NDArray[np.float32]  # colour weights (B, G, R)


def spectral_norm(M: FloatArray) -> float:
    """Largest singular value of a 2×2 matrix."""
    return float(spectral_norm_2x2(float(M[0, 0]), float(M[0, 1]), float(M[1, 0]), float(M[1, 1])))


def _blur_reach(blur_sigma: float) -> int:
    """How far (px) the blur spreads a pixel: ⌈4σ⌉ (0 without blur)."""
    return int(math.ceil(4.0 * blur_sigma)) if blur_sigma > 0 else 0


def _blur_taps(blur_sigma: float) -> NDArray[np.float64]:
    """Normalised Gaussian taps (2·kr + 1, kr = ⌈4σ⌉), as ``cv2.getGaussianKernel``."""
    kr = int(math.ceil(4.0 * blur_sigma))
    return np.asarray(cv2.getGaussianKernel(2 * kr + 1, blur_sigma, cv2.CV_64F), float).ravel()


def blob_patches(
    blobs: list[LightSpot], supersample: int, blur_sigma: float
) -> list[tuple[int, int, NDArray[np.float32]]]:
    """Rendered blobs (float32 DN), each on its own square patch: [(x0, y0, patch)].

    Coverage is evaluated on ``supersample``² sub-samples per pixel with an anti-aliased
    edge (signed distance along the ray from the centre, one sub-sample wide), then blurred
    with a symmetric Gaussian (zero outside the patch). All steps are point-symmetric about
    the centre. Each blob is computed on its own (:func:`~app.sim.stereo_render.patch_kernels.
    spot_patch`, element-wise arithmetic and sums in a fixed order), so a blob's patch is
    bit-identical whichever other blobs share the call — a windowed render (a subset of the
    blobs) equals the full render there.
    """
    if not blobs:
        return []
    taps = _blur_taps(blur_sigma) if blur_sigma > 0 else np.zeros(0)
    reach = _blur_reach(blur_sigma)
    shapes = np.array([b.shape_px for b in blobs], dtype=np.float64)  # (B,2,2)
    ainv = np.linalg.inv(shapes)
    out = []
    for b, a, ai in zip(blobs, shapes, ainv, strict=True):
        c = b.center_px
        x0, y0, patch = spot_patch(
            a, ai, float(c[0]), float(c[1]), reach, supersample, float(np.float32(b.peak)), taps
        )
        out.append((int(x0), int(y0), patch))
    return out


def draw_spots(
    canvas: NDArray[np.uint8],
    blobs: list[LightSpot],
    settings: RenderSettings,
    rects: NDArray[np.int64],
    everywhere: bool,
    color: bool,
) -> None:
    """Draw ``blobs`` in order into ``canvas`` (uint8, h × w × channels): each one's patch (as
    :func:`blob_patches` makes it) added in float32 and rounded, only inside ``rects``
    (R × 4, clipped) unless ``everywhere`` — one compiled loop
    (:func:`~app.sim.stereo_render.patch_kernels.render_spots`)."""
    if not blobs:
        return
    blur = settings.blur_sigma_px
    shapes = np.array([b.shape_px for b in blobs], dtype=np.float64)
    centres = np.array([b.center_px[:2] for b in blobs], dtype=np.float64)
    peaks = np.array([np.float32(b.peak) for b in blobs], dtype=np.float64)
    if color:
        weights = np.array([b.bgr for b in blobs], dtype=np.float32)
    else:
        weights = np.ones((len(blobs), 1), dtype=np.float32)
    taps = _blur_taps(blur) if blur > 0 else np.zeros(0)
    render_spots(
        canvas,
        shapes,
        np.linalg.inv(shapes),
        centres,
        peaks,
        weights,
        _blur_reach(blur),
        settings.supersample,
        taps,
        rects,
        everywhere,
    )


def to_right(calib: StereoCalibration, xyz: FloatArray) -> FloatArray:
    return np.asarray((calib.R @ xyz.T).T + calib.T, dtype=np.float64)


_JACOBIAN_STEP = 1e-5  # normalised units: the finite-difference step of the projection's Jacobian


def _jacobian_points(xyz_cam: FloatArray) -> FloatArray:
    """The four offset points (normalised, z = 1: ±h in x, ±h in y) around each sphere centre's
    normalised image (4·N × 3, offset-major)."""
    n = len(xyz_cam)
    xn = xyz_cam[:, 0] / xyz_cam[:, 2]
    yn = xyz_cam[:, 1] / xyz_cam[:, 2]
    h = _JACOBIAN_STEP
    pts = np.ones((4, n, 3))
    for k, (ddx, ddy) in enumerate(((h, 0.0), (-h, 0.0), (0.0, h), (0.0, -h))):
        pts[k, :, 0] = xn + ddx
        pts[k, :, 1] = yn + ddy
    return pts.reshape(-1, 3)


def _shapes_from(px4: FloatArray, xyz_cam: FloatArray, radius_mm: FloatArray) -> FloatArray:
    """The 2×2 maps (N×2×2) from the projected offset points (4·N × 2 px)."""
    n = len(xyz_cam)
    h = _JACOBIAN_STEP
    px = px4.reshape(4, n, 2)
    jx = (px[0] - px[1]) / (2 * h)  # d(px)/d(xn)
    jy = (px[2] - px[3]) / (2 * h)  # d(px)/d(yn)
    rho = radius_mm / xyz_cam[:, 2]
    out = np.zeros((n, 2, 2))
    out[:, :, 0] = jx * rho[:, None]
    out[:, :, 1] = jy * rho[:, None]
    return out


def sphere_shapes(cam: CameraIntrinsics, xyz_cam: FloatArray, radius_mm: FloatArray) -> FloatArray:
    """2×2 maps (N×2×2) from the unit disc to the px image of spheres at ``xyz_cam``.

    The sphere subtends a disc of radius r/Z in normalised coordinates; it is mapped with
    the local Jacobian of the distorted projection (K with skew, eq. 2; distortion, eq. 7).
    """
    if len(xyz_cam) == 0:
        return np.zeros((0, 2, 2))
    return _shapes_from(project_camera(cam, _jacobian_points(xyz_cam)), xyz_cam, radius_mm)


@dataclass(frozen=True)
class SphereImages:
    """Spheres seen by one camera: centres (N×2 distorted px) and 2×2 image ellipses (N×2×2,
    :func:`sphere_shapes`); NaN for spheres behind (or within 1 mm of) the camera."""

    center_px: FloatArray
    shape_px: FloatArray


def project_spheres(
    cam: CameraIntrinsics, xyz_cam: FloatArray, radius_mm: FloatArray
) -> SphereImages:
    """Centres and image ellipses of spheres (``xyz_cam``, this camera's frame, mm; radii mm)
    with one projection of all the points (:func:`project_checked` + :func:`sphere_shapes`)."""
    n = len(xyz_cam)
    center = np.full((n, 2), np.nan)
    shape = np.full((n, 2, 2), np.nan)
    front = xyz_cam[:, 2] >= MIN_DEPTH_MM
    m = int(np.count_nonzero(front))
    if m:
        xyz = xyz_cam[front]
        px = project_camera(cam, np.vstack([xyz, _jacobian_points(xyz)]))
        center[front] = px[:m]
        shape[front] = _shapes_from(px[m:], xyz, radius_mm[front])
    return SphereImages(center_px=center, shape_px=shape)


def in_frame(px: FloatArray, size: tuple[int, int]) -> NDArray[np.bool_]:
    w, h = size
    ok = np.all(np.isfinite(px), axis=1)
    with np.errstate(invalid="ignore"):
        ok &= (px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
    return np.asarray(ok, dtype=bool)


def project_checked(
    calib: StereoCalibration, xyz: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Project; NaN where a point is behind (or within 1 mm of) a camera. Returns
    (left px, right px, left depth mm, right depth mm)."""
    zl = xyz[:, 2].copy()
    if len(xyz):
        xyz_r = to_right(calib, xyz)  # as project_stereo does
        zr = xyz_r[:, 2]
        pl, pr = project_camera(calib.left, xyz), project_camera(calib.right, xyz_r)
    else:
        zr, pl, pr = np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2))
    pl[zl < MIN_DEPTH_MM] = np.nan
    pr[zr < MIN_DEPTH_MM] = np.nan
    return pl, pr, zl, zr
