"""Improved Haar wavelet transform descriptor (paper §4.3, eqs. 12–13).

Window-size rule: the square window centred on a feature point has side
``W = max(min_window_px, window_factor · r_eq)`` with ``r_eq = sqrt(area / π)`` the blob's
equivalent radius (default factor 8: four LED diameters, so the window holds the LED, its
blurred fringe and the surrounding background, scaling with range). It is split into 4×4
sub-squares (the Haar template size of the paper); inside each, Haar responses are sampled on
a 5×5 grid (as SURF does) so that Σ|dx| and Σ|dy| carry information beyond Σdx and Σdy.
Each sub-square contributes (Σdx, Σ|dx|, Σdy, Σ|dy|) → a 64-D vector, normalised to unit length.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.types import FloatArray, UInt8Array
from app.vision.ihwt_kernels import DESCRIPTOR_SIZE, SAMPLES_PER_SUBSQUARE, describe_kernel
from app.vision.types import Blob


def integral_image(gray: UInt8Array) -> FloatArray:
    """Eq. 12: I_Σ(x, y) = Σ_{i≤x, j≤y} I(i, j), with a leading zero row/column ((H+1)×(W+1))."""
    return np.asarray(cv2.integral(gray, sdepth=cv2.CV_64F), dtype=np.float64)


def box_sum(ii: FloatArray, x0: NDArray, y0: NDArray, x1: NDArray, y1: NDArray) -> FloatArray:
    """Eq. 13: S_D = I_1 + I_4 − I_2 − I_3 for boxes [x0, x1) × [y0, y1) (px, clipped)."""
    h, w = ii.shape[0] - 1, ii.shape[1] - 1
    x0c, x1c = np.clip(x0, 0, w), np.clip(x1, 0, w)
    y0c, y1c = np.clip(y0, 0, h), np.clip(y1, 0, h)
    return np.asarray(ii[y0c, x0c] + ii[y1c, x1c] - ii[y0c, x1c] - ii[y1c, x0c], dtype=np.float64)


def window_side_px(area_px: float, window_factor: float = 8.0, min_window_px: int = 16) -> float:
    """Descriptor window side W (px) for a blob of this area (see the module docstring)."""
    r_eq = math.sqrt(max(float(area_px), 1.0) / math.pi)
    return max(float(min_window_px), window_factor * r_eq)


def describe_points(ii: NDArray[Any], centers_px: FloatArray, windows_px: FloatArray) -> FloatArray:
    """64-D IHWT descriptors of P feature points at once, (P, 64), each unit length (or zeros
    if flat). ``centers_px`` (P, 2) in the integral image's pixel frame, ``windows_px`` (P,)."""
    centers = np.asarray(centers_px, dtype=np.float64).reshape(-1, 2)
    win = np.asarray(windows_px, dtype=np.float64).reshape(-1)
    n = 4 * SAMPLES_PER_SUBSQUARE  # samples per window side
    step = win / n  # (P,)
    half = np.maximum(1, np.floor(step + 0.5)).astype(np.int64)[:, None, None]  # Haar half-size
    offsets = (np.arange(n) + 0.5)[None, :] * step[:, None] - win[:, None] / 2.0  # (P, n)
    # The grid is anchored on the FP's pixel so that equal patches give equal descriptors.
    cu = np.floor(centers[:, 0] + 0.5)[:, None]
    cv = np.floor(centers[:, 1] + 0.5)[:, None]
    xs = (cu + np.floor(offsets + 0.5)).astype(np.int64)[:, None, :]  # (P, 1, n): u
    ys = (cv + np.floor(offsets + 0.5)).astype(np.int64)[:, :, None]  # (P, n, 1): v
    h, w = ii.shape[0] - 1, ii.shape[1] - 1
    # Clipped corner coordinates (minus, centre, plus half a template), then eq. 13 on the
    # 3×3 corner values: horizontal Haar = right half − left half, vertical = bottom − top.
    xm, xc, xp = (np.clip(xs + d, 0, w) for d in (-half, 0, half))
    ym, yc, yp = (np.clip(ys + d, 0, h) for d in (-half, 0, half))
    flat = ii.reshape(-1)  # gathers through flat indices (row offset + column)
    stride = ii.shape[1]
    rm, rc, rp = ym * stride, yc * stride, yp * stride
    mm, mc, mp = flat[rm + xm], flat[rm + xc], flat[rm + xp]
    cm, cp = flat[rc + xm], flat[rc + xp]
    pm, pc, pp = flat[rp + xm], flat[rp + xc], flat[rp + xp]
    dx = (mc + pp - mp - pc) - (mm + pc - mc - pm)
    dy = (cm + pp - cp - pm) - (mm + cp - mp - cm)
    s = SAMPLES_PER_SUBSQUARE
    dx4 = dx.reshape(-1, 4, s, 4, s)
    dy4 = dy.reshape(-1, 4, s, 4, s)
    desc = (
        np.stack(
            [
                dx4.sum(axis=(2, 4)),
                np.abs(dx4).sum(axis=(2, 4)),
                dy4.sum(axis=(2, 4)),
                np.abs(dy4).sum(axis=(2, 4)),
            ],
            axis=-1,
        )
        .reshape(-1, DESCRIPTOR_SIZE)
        .astype(np.float64)
    )
    norm = np.linalg.norm(desc, axis=1, keepdims=True)
    return np.asarray(np.where(norm > 0, desc / np.where(norm > 0, norm, 1.0), desc))


def describe_point(ii: FloatArray, center_px: tuple[float, float], window_px: float) -> FloatArray:
    """The 64-D IHWT descriptor of one feature point (unit length, or zeros if flat)."""
    return describe_points(ii, np.array([center_px]), np.array([window_px]))[0]


def describe(
    gray: UInt8Array,
    blobs: list[Blob],
    window_factor: float = 8.0,
    min_window_px: int = 16,
    ii: NDArray[Any] | None = None,
) -> FloatArray:
    """IHWT descriptors of all blobs: (N, 64) array (rows aligned with ``blobs``).

    Without ``ii``, each point's integral image covers only its own templates (compiled,
    :func:`~app.vision.ihwt_kernels.describe_kernel`); the result is the same as :func:`describe_points` on the full
    frame's integral image ``ii`` (eq. 12), which is used when given.
    """
    if not blobs:
        return np.zeros((0, DESCRIPTOR_SIZE))
    # window_side_px for all blobs at once (the same operations)
    areas = np.array([b.area_px for b in blobs], dtype=np.float64)
    r_eq = np.sqrt(np.maximum(areas, 1.0) / math.pi)
    windows = np.maximum(float(min_window_px), window_factor * r_eq)
    centers = np.array([b.centroid_px for b in blobs], dtype=np.float64)
    if ii is not None:
        return describe_points(ii, centers, windows)
    return np.asarray(describe_kernel(gray, centers, windows))
