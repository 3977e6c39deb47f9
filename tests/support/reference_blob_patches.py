"""The renderer's former NumPy formulation of a blob's patch and its compositing, kept as a
reference: :mod:`app.sim.stereo_render.patch_kernels` must give the same bits (the held-out
campaigns quoted in docs/control.md were flown on this formulation).

Blobs of equal patch size are computed together with element-wise arithmetic, the sub-sample
mean by NumPy's own reduction and the blur as T_nᵀ · P · T_n matrix products."""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from app.sim.stereo_render.blobs import LightSpot
from app.types import FloatArray


def _spectral_norm(M: FloatArray) -> float:
    a, b, c, d = float(M[0, 0]), float(M[0, 1]), float(M[1, 0]), float(M[1, 1])
    s1 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return math.sqrt(0.5 * (s1 + math.sqrt(max(s1 * s1 - 4 * det * det, 0.0))))


def _patch_half(blob: LightSpot, blur_sigma: float) -> int:
    kr = int(math.ceil(4.0 * blur_sigma)) if blur_sigma > 0 else 0
    return int(math.ceil(_spectral_norm(blob.shape_px))) + 2 + kr


def _spectral_norms(m: FloatArray) -> FloatArray:
    """Largest singular values of a stack of 2×2 matrices (B×2×2)."""
    a, b, c, d = m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1]
    s1 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return np.asarray(np.sqrt(0.5 * (s1 + np.sqrt(np.maximum(s1 * s1 - 4 * det * det, 0.0)))))


def _blur_taps(blur_sigma: float) -> NDArray[np.float64]:
    """Normalised Gaussian taps (2·kr + 1, kr = ⌈4σ⌉), as ``cv2.getGaussianKernel``."""
    kr = int(math.ceil(4.0 * blur_sigma))
    return np.asarray(cv2.getGaussianKernel(2 * kr + 1, blur_sigma, cv2.CV_64F), float).ravel()


@lru_cache(maxsize=64)
def _blur_matrix(blur_sigma: float, n: int) -> NDArray[np.float64]:
    """n×n banded matrix T with (P·T)[i, j] = Σ_k taps[k] P[i, j + k − kr] (zero outside)."""
    taps = _blur_taps(blur_sigma)
    kr = (len(taps) - 1) // 2
    t = np.zeros((n, n))
    for j in range(n):
        for k in range(-kr, kr + 1):
            if 0 <= j + k < n:
                t[j + k, j] = taps[k + kr]
    t.setflags(write=False)
    return t


def reference_blob_patches(
    blobs: list[LightSpot], supersample: int, blur_sigma: float
) -> list[tuple[int, int, NDArray[np.float32]]]:
    """Rendered blobs (float32 DN), each on its own square patch: [(x0, y0, patch)].

    Coverage is evaluated on ``supersample``² sub-samples per pixel with an anti-aliased
    edge (signed distance along the ray from the centre, one sub-sample wide), then blurred
    with a symmetric Gaussian (zero outside the patch). All steps are point-symmetric about
    the centre. Blobs of equal patch size are computed together, with element-wise
    arithmetic only (no reductions across pixels except the fixed s² sub-sample mean and the
    fixed-order blur taps), so a blob's patch is bit-identical whichever other blobs share
    the call — a windowed render (a subset of the blobs) equals the full render there.
    """
    out: list[tuple[int, int, NDArray[np.float32]] | None] = [None] * len(blobs)
    blurred = blur_sigma > 0
    s = supersample
    off = (np.arange(s, dtype=np.float64) + 0.5) / s - 0.5
    off_x, off_y = np.tile(off, s), np.repeat(off, s)  # sub-sample offsets, px
    groups: dict[int, list[int]] = {}
    for i, b in enumerate(blobs):
        groups.setdefault(_patch_half(b, blur_sigma), []).append(i)
    for half, idx in groups.items():
        n = 2 * half + 1
        sel = [blobs[i] for i in idx]
        ainv = np.linalg.inv(np.array([b.shape_px for b in sel], dtype=np.float64))  # (B,2,2)
        g = _spectral_norms(ainv)  # max change of u per px
        cx = np.array([float(b.center_px[0]) for b in sel])
        cy = np.array([float(b.center_px[1]) for b in sel])
        x0 = np.rint(cx).astype(np.int64) - half  # round half to even, like round()
        y0 = np.rint(cy).astype(np.int64) - half
        ar = np.arange(n, dtype=np.float64)
        dx = (x0[:, None] + ar[None, :]) - cx[:, None]  # (B, n)
        dy = (y0[:, None] + ar[None, :]) - cy[:, None]
        a00, a01 = ainv[:, 0, 0, None, None], ainv[:, 0, 1, None, None]
        a10, a11 = ainv[:, 1, 0, None, None], ainv[:, 1, 1, None, None]
        ddx, ddy = dx[:, None, :], dy[:, :, None]
        # pixel centres: the ellipse "radius" u (1 = edge) decides fully inside / outside
        qx, qy = a00 * ddx + a01 * ddy, a10 * ddx + a11 * ddy
        u_c = np.sqrt(qx * qx + qy * qy)  # (B, n, n)
        # sub-sample offsets (s², row-major) and their images under A⁻¹ per blob (B, s²)
        q_off = (
            ainv[:, 0, 0, None] * off_x + ainv[:, 0, 1, None] * off_y,
            ainv[:, 1, 0, None] * off_x + ainv[:, 1, 1, None] * off_y,
        )
        band = (g * (0.75 + 0.5 / s))[:, None, None]  # sub-samples ≤ √2/2 px away; AA width
        cov = (u_c < 1.0 - band).astype(np.float64)
        eb, ey, ex = np.nonzero(np.abs(u_c - 1.0) <= band)
        if len(eb):
            # supersample only the edge pixels: s² sub-samples each, anti-aliased edge
            px, py = dx[eb, ex], dy[eb, ey]  # (E,) pixel centre − blob centre
            # in-place arithmetic on (E, s²) arrays (fewer large temporaries)
            qx = (ainv[eb, 0, 0] * px + ainv[eb, 0, 1] * py)[:, None] + q_off[0][eb]
            qy = (ainv[eb, 1, 0] * px + ainv[eb, 1, 1] * py)[:, None] + q_off[1][eb]
            np.multiply(qx, qx, out=qx)
            np.multiply(qy, qy, out=qy)
            u = np.sqrt(np.add(qx, qy, out=qx), out=qx)  # (E, s²)
            sx = np.add(px[:, None], off_x, out=qy)
            np.multiply(sx, sx, out=sx)
            sy = py[:, None] + off_y
            np.multiply(sy, sy, out=sy)
            d = np.sqrt(np.add(sx, sy, out=sx), out=sx)  # px distance from the centre
            ok = u > 1e-12  # (u = 0 only at the centre itself: inside, coverage 1)
            sd = np.full_like(u, np.inf)
            np.divide(d, u, out=sd, where=ok)
            np.subtract(sd, d, out=sd, where=ok)  # signed distance to the edge along the ray, px
            np.multiply(sd, s, out=sd)
            np.add(sd, 0.5, out=sd)
            np.clip(sd, 0.0, 1.0, out=sd)
            cov[eb, ey, ex] = sd.mean(axis=1)
        peaks = np.array([float(np.float32(b.peak)) for b in sel])
        patch = cov * peaks[:, None, None]
        if blurred:
            # separable blur with a zero border as T_nᵀ · P · T_n (one matrix product per blob
            # of the same shape: the same arithmetic whichever other blobs share the batch)
            t_n = _blur_matrix(blur_sigma, n)
            patch = np.matmul(np.matmul(t_n.T, patch), t_n)
        p32 = patch.astype(np.float32)
        for j, i in enumerate(idx):
            out[i] = (int(x0[j]), int(y0[j]), p32[j])
    return [o for o in out if o is not None]


def reference_paste(
    canvas: NDArray[np.uint8],
    x0: int,
    y0: int,
    patch: NDArray[np.float32],
    bgr: NDArray[np.float32] | None,
    rects: list[tuple[int, int, int, int]] | None,
) -> None:
    """The former compositing of one patch: clipped to the canvas, (× bgr,) added in float32,
    rounded, clipped to 0..255, written where a window (``rects``, clipped; None: all) is."""
    h, w = canvas.shape[:2]
    ph, pw = patch.shape
    xa, ya = max(x0, 0), max(y0, 0)
    xb, yb = min(x0 + pw, w), min(y0 + ph, h)
    if xa >= xb or ya >= yb:
        return
    p = patch[ya - y0 : yb - y0, xa - x0 : xb - x0]
    if bgr is not None:
        p = p[:, :, None] * bgr[None, None, :]
    region = canvas[ya:yb, xa:xb].astype(np.float32) + p
    new = np.clip(np.rint(region), 0, 255).astype(np.uint8)
    if rects is None:
        canvas[ya:yb, xa:xb] = new
        return
    mask = np.zeros((yb - ya, xb - xa), dtype=bool)
    for rx0, ry0, rx1, ry1 in rects:
        mask[max(ry0 - ya, 0) : max(ry1 - ya, 0), max(rx0 - xa, 0) : max(rx1 - xa, 0)] = True
    np.copyto(canvas[ya:yb, xa:xb], new, where=mask[:, :, None] if canvas.ndim == 3 else mask)
