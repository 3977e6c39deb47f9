"""The local-support centroid's compiled loops (numba, cached on disk).

:func:`local_centroids` measures every blob again on its own terms (local background from
the median of a one-pixel ring around its window, support relative to its own peak, the
weighted mean and its noise): the algorithm is described in :mod:`app.vision.local_centroid`,
which holds its configuration (``LocalCentroidConfig.params()`` gives ``params``' order) and
turns the output rows into blobs. :func:`measure_box` measures one blob: the acquisition's and
the tracker's labelling calls (:mod:`app.vision.blob_kernels`) call it for each blob they keep.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.vision.bright_region_kernels import touch_rows

# columns of :func:`local_centroids`' output
OUT_U, OUT_V, OUT_SIGMA_U, OUT_SIGMA_V, OUT_BACKGROUND, OUT_LEVEL, OUT_SATURATED, OUT_AREA = range(
    8
)
OUT_X0, OUT_Y0, OUT_X1, OUT_Y1 = range(8, 12)  # the pixels read (the background ring included)
# the sensor model's σ alone (u, v px; equal to OUT_SIGMA_U/V unless the image's noise is on)
OUT_MODEL_SIGMA_U, OUT_MODEL_SIGMA_V = 12, 13
OUT_COLUMNS = 14
# (support fraction at least, window pad multiple) tried in turn until the support is bounded:
# a wider window for an LED that the threshold cut down to its core, then higher levels for
# an LED next to something brighter than its own low level (a sunlit rim, the canopy)
ATTEMPTS = np.array([[0.0, 1], [0.0, 2], [0.35, 1], [0.5, 1], [0.5, 2], [0.5, 4]], np.float64)


@njit(cache=True, nogil=True)
def _pad(w: int, h: int) -> int:  # pragma: no cover - compiled
    return max(3, (max(w, h) + 1) // 2)


@njit(cache=True, nogil=True)
def ring_median_counts(
    gray: np.ndarray, x0: int, y0: int, x1: int, y1: int, counts: np.ndarray
) -> float:  # pragma: no cover - compiled
    """The median of the pixels on the one-pixel border just outside [x0, x1) × [y0, y1),
    clipped to the image (NaN when none is inside), from a 256-bin count of the border's values (uint8 ``gray``; the
    same number: the middle value, or the mean of the two middle ones, exact for integers).
    ``counts``: (256,) int64 scratch, all zero on entry and on return."""
    h, w = gray.shape
    n = 0
    for y in (y0 - 1, y1):
        if 0 <= y < h:
            row = gray[y]
            for x in range(max(0, x0 - 1), min(w, x1 + 1)):
                counts[row[x]] += 1
                n += 1
    for x in (x0 - 1, x1):
        if 0 <= x < w:
            for y in range(max(0, y0), min(h, y1)):
                counts[gray[y, x]] += 1
                n += 1
    if n == 0:
        return np.nan
    # the values of rank (n − 1) // 2 and n // 2 (0-based), then clear the counts
    lo = hi = -1
    cum = 0
    for v in range(256):
        c = counts[v]
        if c == 0:
            continue
        counts[v] = 0
        if cum + c >= n:  # the last value present: the counts above are all zero
            if lo < 0:
                lo = v
            if hi < 0:
                hi = v
            break
        if lo < 0 and cum + c > (n - 1) // 2:
            lo = v
        if hi < 0 and cum + c > n // 2:
            hi = v
        cum += c
    return 0.5 * (lo + hi) if lo != hi else float(lo)


@njit(cache=True, nogil=True)
def _measure(
    gray: np.ndarray,
    bx: int,
    by: int,
    bw: int,
    bh: int,
    pad: int,
    params: np.ndarray,
    out: np.ndarray,
    state_buf: np.ndarray,
    stack: np.ndarray,
    counts: np.ndarray,
) -> bool:  # pragma: no cover - compiled
    """The local centroid of one blob box in a window grown by ``pad`` px into ``out`` (a row
    of ``OUT_COLUMNS``); False when the support reaches the window's edge. ``state_buf`` and
    ``stack``: scratch of at least the window's pixel count (uint8; int64, 2 rows), ``counts``:
    (256,) int64 zeros (:func:`ring_median_counts`)."""
    frac, sat, read_sigma, shot_k, floor_px = params[0], params[1], params[2], params[3], params[4]
    height, width = gray.shape
    x0, y0 = max(0, bx - pad), max(0, by - pad)
    x1, y1 = min(width, bx + bw + pad), min(height, by + bh + pad)
    # the window's rows loaded first, their cache misses overlapped (0 added)
    x0 += touch_rows(gray, x0 - 1, y0 - 1, x1 + 1, y1 + 1) >> 62
    out[OUT_X0], out[OUT_Y0], out[OUT_X1], out[OUT_Y1] = x0 - 1, y0 - 1, x1 + 1, y1 + 1
    bg = ring_median_counts(gray, x0, y0, x1, y1, counts)
    # the peak on the blob's own box
    peak = -1.0
    px = py = 0
    for y in range(by, by + bh):
        for x in range(bx, bx + bw):
            if gray[y, x] > peak:
                peak = float(gray[y, x])
                px, py = x, y
    out[OUT_BACKGROUND] = bg
    if not (peak - bg >= 2.0):
        return True  # no contrast: nothing to grow for
    top = sat if peak >= sat else peak
    level = bg + frac * (top - bg)
    wbase = level if params[5] > 0 else bg
    # 8-connected flood fill from the peak over pixels ≥ level, inside the window
    ww, wh = x1 - x0, y1 - y0
    # a pixel value g (an integer) is ≥ level ⇔ g ≥ ⌈level⌉
    ilevel = int(math.ceil(level))
    # state[j + 1, i + 1] of window pixel (j, i): 1 at or above the level and not yet taken,
    # 2 taken (the support), 0 below the level; a border of 0 keeps the fill inside
    w2 = ww + 2
    state = state_buf[: w2 * (wh + 2)]
    state[:w2] = 0
    state[(wh + 1) * w2 :] = 0
    for j in range(wh):
        row = gray[y0 + j]
        base = (j + 1) * w2
        state[base] = 0
        state[base + w2 - 1] = 0
        for i in range(ww):
            state[base + 1 + i] = 1 if row[x0 + i] >= ilevel else 0
    sp = 0
    stack[0, sp] = py - y0
    stack[1, sp] = px - x0
    sp += 1
    state[(py - y0 + 1) * w2 + px - x0 + 1] = 2
    edge = False
    sw = swu = swv = 0.0
    count = 0
    n_sat = 0
    # the support's box (window px): the noise sum below reads only its rows and columns
    j_lo, j_hi, i_lo, i_hi = wh, -1, ww, -1
    while sp > 0:
        sp -= 1
        j, i = stack[0, sp], stack[1, sp]
        j_lo, j_hi = min(j_lo, j), max(j_hi, j)
        i_lo, i_hi = min(i_lo, i), max(i_hi, i)
        g = float(gray[y0 + j, x0 + i])
        wgt = g - wbase
        sw += wgt
        swu += wgt * (x0 + i)
        swv += wgt * (y0 + j)
        count += 1
        if g >= sat:
            n_sat += 1
        if i == 0 or j == 0 or i == ww - 1 or j == wh - 1:
            edge = True
        # the neighbours in the order (dj, di) = (−1, −1), (−1, 0), … (1, 1)
        for dj in (-1, 0, 1):
            k = (j + dj + 1) * w2 + i
            for di in (0, 1, 2):
                if state[k + di] == 1:
                    state[k + di] = 2
                    stack[0, sp] = j + dj
                    stack[1, sp] = i + di - 1
                    sp += 1
    out[OUT_LEVEL] = level
    out[OUT_SATURATED] = n_sat
    out[OUT_AREA] = count
    if edge:
        return False
    if sw <= 0.0:
        return True
    cu, cv = swu / sw, swv / sw
    # first-order noise of the weighted mean (the level held fixed): the sensor model's pixel
    # variance (vu, vv), and the pixel errors the image itself shows (au, av): each support
    # pixel's difference from the blob's own profile mirrored through the centroid, A, whose
    # half-square estimates that pixel's variance whatever made it (compression, blur,
    # demosaicing, a saturated edge) — an LED's image is point-symmetric about its centre
    vu = vv = au = av = 0.0
    image_noise = params[6] > 0
    for j in range(j_lo, j_hi + 1):  # (in raster order, as over the whole window)
        for i in range(i_lo, i_hi + 1):
            if state[(j + 1) * w2 + i + 1] == 2:
                g = float(gray[y0 + j, x0 + i])
                du, dv = x0 + i - cu, y0 + j - cv
                if image_noise:
                    a = g - bilinear(gray, cu - du, cv - dv)
                    au += 0.5 * a * a * du * du
                    av += 0.5 * a * a * dv * dv
                if g >= sat:
                    continue
                var = read_sigma * read_sigma + shot_k * max(g - bg, 0.0)
                vu += var * du * du
                vv += var * dv * dv
    floor2 = floor_px * floor_px
    out[OUT_MODEL_SIGMA_U] = np.sqrt(vu / (sw * sw) + floor2)
    out[OUT_MODEL_SIGMA_V] = np.sqrt(vv / (sw * sw) + floor2)
    if image_noise:  # the larger of the model's and the image's
        vu, vv = max(vu, au), max(vv, av)
    out[OUT_U] = cu
    out[OUT_V] = cv
    out[OUT_SIGMA_U] = np.sqrt(vu / (sw * sw) + floor2)
    out[OUT_SIGMA_V] = np.sqrt(vv / (sw * sw) + floor2)
    return True


@njit(cache=True, nogil=True)
def bilinear(gray: np.ndarray, x: float, y: float) -> float:  # pragma: no cover - compiled
    """``gray`` at (x, y) px (pixel centres at integers), bilinear, clamped to the image."""
    h, w = gray.shape
    x = min(max(x, 0.0), w - 1.0)
    y = min(max(y, 0.0), h - 1.0)
    ix, iy = min(int(x), w - 2), min(int(y), h - 2)
    fx, fy = x - ix, y - iy
    top = (1.0 - fx) * float(gray[iy, ix]) + fx * float(gray[iy, ix + 1])
    bottom = (1.0 - fx) * float(gray[iy + 1, ix]) + fx * float(gray[iy + 1, ix + 1])
    return (1.0 - fy) * top + fy * bottom


@njit(cache=True, nogil=True)
def scratch_cells(bw: int, bh: int) -> int:  # pragma: no cover - compiled
    """Scratch cells :func:`measure_box` needs for a w × h px box (its widest attempt)."""
    grow = 0
    for a in range(ATTEMPTS.shape[0]):
        grow = max(grow, int(ATTEMPTS[a, 1]))
    pad = _pad(bw, bh) * grow
    return (bw + 2 * pad + 2) * (bh + 2 * pad + 2)


@njit(cache=True, nogil=True)
def scratch(cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """:func:`measure_box`'s scratch for boxes of up to ``cells`` (:func:`scratch_cells`):
    (state uint8, stack (2, cells) int64, 256-bin counts, zero)."""
    return np.empty(cells, np.uint8), np.empty((2, cells), np.int64), np.zeros(256, np.int64)


@njit(cache=True, nogil=True)
def measure_box(
    gray: np.ndarray,
    bx: int,
    by: int,
    bw: int,
    bh: int,
    params: np.ndarray,
    out: np.ndarray,
    state: np.ndarray,
    stack: np.ndarray,
    counts: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The local centroid of one blob box (x, y, w, h, image px) into ``out`` (a row of
    ``OUT_COLUMNS``; u, v NaN when not measured), trying ``ATTEMPTS`` in turn. ``params``:
    :meth:`LocalCentroidConfig.params`, its support fraction restored on return; scratch as
    :func:`_measure` takes it, of at least :func:`scratch_cells` of the box."""
    frac0 = params[0]
    pad = _pad(bw, bh)
    for a in range(ATTEMPTS.shape[0]):
        out[:] = np.nan
        params[0] = max(frac0, ATTEMPTS[a, 0])
        grown = pad * int(ATTEMPTS[a, 1])
        if _measure(gray, bx, by, bw, bh, grown, params, out, state, stack, counts):
            break
    params[0] = frac0


@njit(cache=True, nogil=True)
def local_centroids(
    gray: np.ndarray, boxes: np.ndarray, params: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """For each (x, y, w, h) row of ``boxes`` (a blob's bounding box, image px) the local
    centroid (module docstring): rows of ``OUT_COLUMNS`` (u, v, σ_u, σ_v px, local background
    DN, support level DN, saturated pixels, support area px, the pixels read: x0, y0, x1, y1
    half-open, the sensor model's σ_u, σ_v px); u, v NaN when not measured. A support that reaches its window's edge is
    measured again as ``ATTEMPTS`` lists (wider windows, higher levels) before it is given
    up."""
    n = boxes.shape[0]
    out = np.full((n, OUT_COLUMNS), np.nan)
    params = params.copy()
    # scratch for the largest window an attempt may read
    big = 0
    for k in range(n):
        big = max(big, scratch_cells(boxes[k, 2], boxes[k, 3]))
    state, stack, counts = scratch(big)
    for k in range(n):
        measure_box(
            gray, boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3], params, out[k], state,
            stack, counts,
        )  # fmt: skip
    return out
