"""Compiled inner loops of the renderer: one emitting sphere's patch and its compositing.

A blob's patch is a few dozen small array operations; run from Python, each costs a call's
overhead, and the camera would be the larger part of a closed-loop tick. Here the arithmetic
runs in compiled loops (numba, cached on disk):

* :func:`spot_patch` — the blob's anti-aliased coverage (``s``² sub-samples on the edge pixels,
  their mean summed in NumPy's pairwise order), times the peak, blurred by the separable
  Gaussian with a zero border (T_nᵀ · P · T_n, each output a sum over the taps in index order);
* :func:`paste_patch` — the patch added to a uint8 image in float32, rounded half to even,
  clipped to 0..255, written only inside the given windows (all of them: the whole image);
* :func:`render_spots` — one image's blobs in order, each sized, tested against the windows,
  made and pasted (the closed loop's renders: one call per image).

Every step is element-wise or a sum in a fixed order, so a blob's patch does not depend on the
other blobs of a frame (a windowed render equals the full render inside its windows), and the
patches equal the NumPy formulation's bit for bit (``tests/support/reference_blob_patches.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _pairwise_mean(v: np.ndarray, n: int) -> float:
    """Mean of ``v[:n]`` summed as NumPy sums a contiguous row (pairwise: eight partial sums
    for 8 ≤ n ≤ 128, then ((r0+r1)+(r2+r3)) + ((r4+r5)+(r6+r7)), then the remainder), divided
    by n — bit for bit ``v[:n].mean()``."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += v[i]
        return res / n
    r0, r1, r2, r3 = v[0], v[1], v[2], v[3]
    r4, r5, r6, r7 = v[4], v[5], v[6], v[7]
    i = 8
    while i < n - (n % 8):
        r0 += v[i]
        r1 += v[i + 1]
        r2 += v[i + 2]
        r3 += v[i + 3]
        r4 += v[i + 4]
        r5 += v[i + 5]
        r6 += v[i + 6]
        r7 += v[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += v[i]
        i += 1
    return res / n


@njit(cache=True, nogil=True)
def spectral_norm_2x2(a: float, b: float, c: float, d: float) -> float:
    """Largest singular value of [[a, b], [c, d]]."""
    s1 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return math.sqrt(0.5 * (s1 + math.sqrt(max(s1 * s1 - 4 * det * det, 0.0))))


@njit(cache=True, nogil=True)
def patch_half(shape: np.ndarray, reach: int) -> int:
    """Half size (px) of a blob's square patch: the longest semi-axis of its ellipse (``shape``
    A, 2×2, maps the unit disc to px), rounded up, + 2 px + the blur's ``reach`` (px)."""
    a = spectral_norm_2x2(shape[0, 0], shape[0, 1], shape[1, 0], shape[1, 1])
    return int(math.ceil(a)) + 2 + reach


@njit(cache=True, nogil=True)
def spot_patch(
    shape: np.ndarray,
    ainv: np.ndarray,
    cx: float,
    cy: float,
    reach: int,
    s: int,
    peak: float,
    taps: np.ndarray,
) -> tuple[int, int, np.ndarray]:
    """(x0, y0, patch float32 (2·half+1)²) of one blob centred at (``cx``, ``cy``) px whose
    ellipse is the unit disc under A (``shape``, 2×2; ``ainv`` = A⁻¹), ``s``² sub-samples per
    edge pixel, ``peak`` DN, blurred with the normalised ``taps`` (none: no blur). The half
    size: A's longest semi-axis, rounded up, + 2 px + the blur's ``reach`` (px)."""
    half = patch_half(shape, reach)
    n = 2 * half + 1
    a00, a01, a10, a11 = ainv[0, 0], ainv[0, 1], ainv[1, 0], ainv[1, 1]
    g = spectral_norm_2x2(a00, a01, a10, a11)  # the most u changes per px
    band = g * (0.75 + 0.5 / s)  # sub-samples ≤ √2/2 px away; the anti-aliasing width
    inner = 1.0 - band
    x0 = int(np.rint(cx)) - half
    y0 = int(np.rint(cy)) - half
    ss = s * s
    off = np.empty(s)
    for k in range(s):
        off[k] = (k + 0.5) / s - 0.5
    qox = np.empty(ss)  # the sub-sample offsets' images under A⁻¹ (row-major: x fastest)
    qoy = np.empty(ss)
    for k in range(ss):
        ox, oy = off[k % s], off[k // s]
        qox[k] = a00 * ox + a01 * oy
        qoy[k] = a10 * ox + a11 * oy
    sub = np.empty(ss)
    patch = np.empty((n, n))
    for i in range(n):
        dy = (y0 + float(i)) - cy
        for j in range(n):
            dx = (x0 + float(j)) - cx
            qx = a00 * dx + a01 * dy
            qy = a10 * dx + a11 * dy
            u_c = math.sqrt(qx * qx + qy * qy)
            if abs(u_c - 1.0) <= band:
                # an edge pixel: s² sub-samples, the signed distance to the edge along the ray
                bx = a00 * dx + a01 * dy
                by = a10 * dx + a11 * dy
                for k in range(ss):
                    ux = bx + qox[k]
                    uy = by + qoy[k]
                    u = math.sqrt(ux * ux + uy * uy)
                    sx = dx + off[k % s]
                    sy = dy + off[k // s]
                    d = math.sqrt(sx * sx + sy * sy)
                    sd = (d / u - d) if u > 1e-12 else np.inf
                    sd = sd * s + 0.5
                    sub[k] = min(max(sd, 0.0), 1.0)
                cov = _pairwise_mean(sub, ss)
            else:
                cov = 1.0 if u_c < inner else 0.0
            patch[i, j] = cov * peak
    kt = len(taps)
    if kt == 0:
        return x0, y0, patch.astype(np.float32)
    kr = (kt - 1) // 2
    # separable blur, zero outside the patch: down the columns, then along the rows
    col = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(kt):
                m = i + k - kr
                if 0 <= m < n:
                    acc += taps[k] * patch[m, j]
            col[i, j] = acc
    out = np.empty((n, n), dtype=np.float32)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(kt):
                m = j + k - kr
                if 0 <= m < n:
                    acc += col[i, m] * taps[k]
            out[i, j] = np.float32(acc)
    return x0, y0, out


@njit(cache=True, nogil=True)
def paste_patch(
    canvas: np.ndarray,
    x0: int,
    y0: int,
    patch: np.ndarray,
    weights: np.ndarray,
    rects: np.ndarray,
    everywhere: bool,
) -> None:
    """Add ``patch`` (float32 DN) × ``weights`` (float32, one per channel) to ``canvas`` (uint8,
    h × w × channels) at (``x0``, ``y0``) in float32, rounded half to even and clipped to
    0..255 — only inside the rectangles ``rects`` (R × 4: x0, y0, x1, y1, half-open, clipped to
    the canvas) unless ``everywhere``. Pixels outside the canvas are dropped."""
    h, w, nc = canvas.shape
    ph, pw = patch.shape
    xa, ya = max(x0, 0), max(y0, 0)
    xb, yb = min(x0 + pw, w), min(y0 + ph, h)
    for y in range(ya, yb):
        for x in range(xa, xb):
            if not everywhere:
                inside = False
                for r in range(rects.shape[0]):
                    if rects[r, 0] <= x < rects[r, 2] and rects[r, 1] <= y < rects[r, 3]:
                        inside = True
                        break
                if not inside:
                    continue
            p = patch[y - y0, x - x0]
            for c in range(nc):
                v = np.float32(canvas[y, x, c]) + p * weights[c]
                v = np.rint(v)
                if v < 0:
                    v = np.float32(0.0)
                elif v > 255:
                    v = np.float32(255.0)
                canvas[y, x, c] = np.uint8(v)


@njit(cache=True, nogil=True)
def render_spots(
    canvas: np.ndarray,
    shapes: np.ndarray,
    ainvs: np.ndarray,
    centres: np.ndarray,
    peaks: np.ndarray,
    weights: np.ndarray,
    reach: int,
    s: int,
    taps: np.ndarray,
    rects: np.ndarray,
    everywhere: bool,
) -> None:
    """Draw blobs into ``canvas`` in order: each one's :func:`spot_patch` (``shapes``/``ainvs``
    B×2×2, ``centres`` B×2 px, ``peaks`` B DN) pasted by :func:`paste_patch` with its channel
    ``weights`` (B × channels). A blob whose patch reaches no rectangle is skipped (it would
    write nothing)."""
    h, w, _ = canvas.shape
    for b in range(shapes.shape[0]):
        cx, cy = centres[b, 0], centres[b, 1]
        half = patch_half(shapes[b], reach)
        x0 = int(np.rint(cx)) - half
        y0 = int(np.rint(cy)) - half
        x1, y1 = x0 + 2 * half + 1, y0 + 2 * half + 1
        if not everywhere:
            reached = False
            for r in range(rects.shape[0]):
                if x0 < rects[r, 2] and rects[r, 0] < x1 and y0 < rects[r, 3] and rects[r, 1] < y1:
                    reached = True
                    break
            if not reached:
                continue
        if x1 <= 0 or y1 <= 0 or x0 >= w or y0 >= h:
            continue
        px0, py0, patch = spot_patch(shapes[b], ainvs[b], cx, cy, reach, s, peaks[b], taps)
        paste_patch(canvas, px0, py0, patch, weights[b], rects, everywhere)
