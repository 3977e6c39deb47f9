"""Local-support LED centroids that survive reflections (a refinement of paper eq. 11).

Eq. 11 weights each pixel by its brightness above the frame's *global* background over the
blob dilated by a margin of ≈ ½√area px (:mod:`app.vision.blob_kernels`). On polished metal
in daylight that margin takes in the LED's own reflection on the rim, glint streaks and bright
sky, and these differ between the two views: a disparity error of a few tenths of a pixel.
Here each detected blob is measured again on its own terms:

* **local background** ``b``: the median of a one-pixel ring of pixels just outside a window
  around the blob (the blob's box grown by ``pad`` = max(3, ⌈½·max(w, h)⌉) px);
* **local peak** ``p``: the brightest pixel of the blob's box (``saturated_dn`` and above
  count as saturated: a flat top);
* **support**: the pixels ≥ ``b + support_frac·(p − b)`` 8-connected to the peak pixel inside
  the window — relative to the blob's own peak, so the same rule holds in both images whatever
  their exposure, and a reflection or glint dimmer than the level, or separated from the LED by
  a darker gap, is not part of it. A saturated blob's level is taken from the saturation level
  (its flat top and the flanks above the level);
* **centroid**: Σ wᵢ·xᵢ / Σ wᵢ with wᵢ = Iᵢ − level over the support (pixel centres, px);
* **noise** (the error bound's input, :mod:`app.geometry.uncertainty`): first-order
  propagation of independent pixel noise through the weighted mean,
  σ_u² = Σ σᵢ²·(uᵢ − ū)² / (Σ wᵢ)² with σᵢ² = σ_read² + k_shot·max(Iᵢ − b, 0) (DN²; a saturated
  pixel carries no noise), plus a floor ``floor_px`` in quadrature for what the model does not
  describe (demosaicing, blur, sub-pixel structure).

A support that reaches the window's edge (a blob merged with something larger) or a blob with
no contrast keeps its eq. 11 centroid and gets σ = NaN: the caller treats it as unmeasured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from app.vision.types import Blob

# columns of :func:`local_centroids`' output
OUT_U, OUT_V, OUT_SIGMA_U, OUT_SIGMA_V, OUT_BACKGROUND, OUT_LEVEL, OUT_SATURATED, OUT_AREA = range(
    8
)
OUT_X0, OUT_Y0, OUT_X1, OUT_Y1 = range(8, 12)  # the pixels read (the background ring included)
OUT_COLUMNS = 12
# (support fraction at least, window pad multiple) tried in turn until the support is bounded:
# a wider window for an LED that the threshold cut down to its core, then higher levels for
# an LED next to something brighter than its own low level (a sunlit rim, the canopy)
ATTEMPTS = np.array([[0.0, 1], [0.0, 2], [0.35, 1], [0.5, 1], [0.5, 2], [0.5, 4]], np.float64)


@dataclass(frozen=True)
class LocalCentroidConfig:
    """Parameters of the local-support centroid (DN, px)."""

    enabled: bool = True  # False: the paper's eq. 11 centroid as is
    support_frac: float = 0.2  # support: pixels ≥ b + frac·(peak − b)
    saturated_dn: float = 250.0  # a pixel at or above this is saturated (flat top)
    read_sigma_dn: float = 1.5  # pixel noise floor (DN, 1σ)
    shot_var_per_dn: float = 0.032  # shot-noise variance per DN of signal (DN²/DN ≈ 255/full well)
    floor_px: float = 0.03  # centroid error the noise model leaves out (px, 1σ)
    weights_from_level: bool = True  # weights I − level (True) or I − local background

    def params(self) -> NDArray[np.float64]:
        return np.array(
            [
                self.support_frac,
                self.saturated_dn,
                self.read_sigma_dn,
                self.shot_var_per_dn,
                self.floor_px,
                1.0 if self.weights_from_level else 0.0,
            ],
            dtype=np.float64,
        )


def window_pad_px(w: int, h: int) -> int:
    """Margin (px) of the local window around a blob box of w × h px."""
    return max(3, (max(w, h) + 1) // 2)


@njit(cache=True, nogil=True)
def _pad(w: int, h: int) -> int:  # pragma: no cover - compiled
    return max(3, (max(w, h) + 1) // 2)


@njit(cache=True, nogil=True)
def _ring_median(gray: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> float:  # pragma: no cover
    """Median of the pixels on the one-pixel border just outside [x0, x1) × [y0, y1),
    clipped to the image (NaN when none is inside)."""
    h, w = gray.shape
    vals = np.empty(2 * (x1 - x0 + 2) + 2 * (y1 - y0), np.float64)
    n = 0
    for y in (y0 - 1, y1):
        if 0 <= y < h:
            for x in range(max(0, x0 - 1), min(w, x1 + 1)):
                vals[n] = gray[y, x]
                n += 1
    for x in (x0 - 1, x1):
        if 0 <= x < w:
            for y in range(max(0, y0), min(h, y1)):
                vals[n] = gray[y, x]
                n += 1
    if n == 0:
        return np.nan
    return float(np.median(vals[:n]))


@njit(cache=True, nogil=True)
def _ring_median_counts(
    gray: np.ndarray, x0: int, y0: int, x1: int, y1: int, counts: np.ndarray
) -> float:  # pragma: no cover - compiled
    """:func:`_ring_median` from a 256-bin count of the border's values (uint8 ``gray``; the
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
    seen_buf: np.ndarray,
    stack: np.ndarray,
    counts: np.ndarray,
) -> bool:  # pragma: no cover - compiled
    """The local centroid of one blob box in a window grown by ``pad`` px into ``out`` (a row
    of ``OUT_COLUMNS``); False when the support reaches the window's edge. ``seen_buf`` and
    ``stack``: scratch of at least the window's pixel count (bool; int64, 2 rows), ``counts``:
    (256,) int64 zeros (:func:`_ring_median_counts`)."""
    frac, sat, read_sigma, shot_k, floor_px = params[0], params[1], params[2], params[3], params[4]
    height, width = gray.shape
    x0, y0 = max(0, bx - pad), max(0, by - pad)
    x1, y1 = min(width, bx + bw + pad), min(height, by + bh + pad)
    out[OUT_X0], out[OUT_Y0], out[OUT_X1], out[OUT_Y1] = x0 - 1, y0 - 1, x1 + 1, y1 + 1
    bg = _ring_median_counts(gray, x0, y0, x1, y1, counts)
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
    # seen[j + 1, i + 1]: window pixel (j, i) taken; a border of True keeps the fill inside
    seen = seen_buf[: (ww + 2) * (wh + 2)].reshape(wh + 2, ww + 2)
    seen[:] = False
    seen[0, :] = True
    seen[wh + 1, :] = True
    seen[:, 0] = True
    seen[:, ww + 1] = True
    # a pixel value g (an integer) is ≥ level ⇔ g ≥ ⌈level⌉
    ilevel = int(math.ceil(level))
    sp = 0
    stack[0, sp] = py - y0
    stack[1, sp] = px - x0
    sp += 1
    seen[py - y0 + 1, px - x0 + 1] = True
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
        for dj in (-1, 0, 1):
            for di in (-1, 0, 1):
                jj, ii = j + dj, i + di
                if not seen[jj + 1, ii + 1]:
                    if gray[y0 + jj, x0 + ii] >= ilevel:
                        seen[jj + 1, ii + 1] = True
                        stack[0, sp] = jj
                        stack[1, sp] = ii
                        sp += 1
    out[OUT_LEVEL] = level
    out[OUT_SATURATED] = n_sat
    out[OUT_AREA] = count
    if edge:
        return False
    if sw <= 0.0:
        return True
    cu, cv = swu / sw, swv / sw
    # first-order noise of the weighted mean (the level held fixed)
    vu = vv = 0.0
    for j in range(j_lo, j_hi + 1):  # (in raster order, as over the whole window)
        for i in range(i_lo, i_hi + 1):
            if seen[j + 1, i + 1]:
                g = float(gray[y0 + j, x0 + i])
                if g >= sat:
                    continue
                var = read_sigma * read_sigma + shot_k * max(g - bg, 0.0)
                du, dv = x0 + i - cu, y0 + j - cv
                vu += var * du * du
                vv += var * dv * dv
    out[OUT_U] = cu
    out[OUT_V] = cv
    out[OUT_SIGMA_U] = np.sqrt(vu / (sw * sw) + floor_px * floor_px)
    out[OUT_SIGMA_V] = np.sqrt(vv / (sw * sw) + floor_px * floor_px)
    return True


@njit(cache=True, nogil=True)
def local_centroids(
    gray: np.ndarray, boxes: np.ndarray, params: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """For each (x, y, w, h) row of ``boxes`` (a blob's bounding box, image px) the local
    centroid (module docstring): rows of ``OUT_COLUMNS`` (u, v, σ_u, σ_v px, local background
    DN, support level DN, saturated pixels, support area px, the pixels read: x0, y0, x1, y1
    half-open); u, v NaN when not measured. A support that reaches its window's edge is
    measured again as ``ATTEMPTS`` lists (wider windows, higher levels) before it is given
    up."""
    n = boxes.shape[0]
    out = np.full((n, OUT_COLUMNS), np.nan)
    params = params.copy()
    frac0 = params[0]
    # scratch for the largest window an attempt may read
    grow = 0
    for a in range(ATTEMPTS.shape[0]):
        grow = max(grow, int(ATTEMPTS[a, 1]))
    big = 0
    for k in range(n):
        bw, bh = boxes[k, 2], boxes[k, 3]
        pad = _pad(bw, bh) * grow
        big = max(big, (bw + 2 * pad + 2) * (bh + 2 * pad + 2))
    seen = np.empty(big, np.bool_)
    stack = np.empty((2, big), np.int64)
    counts = np.zeros(256, np.int64)
    for k in range(n):
        bx, by, bw, bh = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        pad = _pad(bw, bh)
        for a in range(ATTEMPTS.shape[0]):
            out[k, :] = np.nan
            params[0] = max(frac0, ATTEMPTS[a, 0])
            grown = pad * int(ATTEMPTS[a, 1])
            if _measure(gray, bx, by, bw, bh, grown, params, out[k], seen, stack, counts):
                break
    params[0] = frac0
    return out


def measure_blobs(
    gray: NDArray[np.uint8], blobs: list[Blob], cfg: LocalCentroidConfig
) -> NDArray[np.float64]:
    """:func:`local_centroids` for these blobs (rows aligned with ``blobs``)."""
    if not blobs:
        return np.zeros((0, OUT_COLUMNS))
    boxes = np.array([b.bbox for b in blobs], dtype=np.int64).reshape(-1, 4)
    return np.asarray(local_centroids(gray, boxes, cfg.params()))


def local_blob(
    centroid_px: tuple[float, float],
    area_px: int,
    bbox: tuple[int, int, int, int],
    peak: float,
    mass: float,
    color_bgr: tuple[float, ...] | None,
    row: list[float],
) -> Blob:
    """A blob with its local centroid, σ and local background from ``row`` (a
    :func:`local_centroids` row as a list); eq. 11's ``centroid_px`` and σ = NaN where the
    local centroid is not measured."""
    u = row[OUT_U]
    if u == u:  # not NaN: measured
        return Blob(
            (u, row[OUT_V]),
            area_px,
            bbox,
            peak,
            mass,
            color_bgr,
            (row[OUT_SIGMA_U], row[OUT_SIGMA_V]),
            row[OUT_BACKGROUND],
        )
    nan = float("nan")
    return Blob(centroid_px, area_px, bbox, peak, mass, color_bgr, (nan, nan), row[OUT_BACKGROUND])


def with_local_centroids(blobs: list[Blob], table: NDArray[np.float64]) -> list[Blob]:
    """The blobs with the local centroids, σ and local background of ``table``
    (:func:`measure_blobs`; eq. 11's centroid and σ = NaN where it is not measured)."""
    # the constructor, not dataclasses.replace (≈ 4× cheaper per blob; same fields)
    return [
        local_blob(b.centroid_px, b.area_px, b.bbox, b.peak, b.mass, b.color_bgr, row)
        for b, row in zip(blobs, table.tolist(), strict=True)
    ]


def box_table(boxes: NDArray[np.int64]) -> NDArray[np.int64]:
    """The (x, y, w, h) columns of (k, ≥ 4) int64 box rows, as :func:`local_centroids` takes
    them (C-contiguous)."""
    return np.ascontiguousarray(boxes[:, :4])


def refine_blobs(
    gray: NDArray[np.uint8], blobs: list[Blob], cfg: LocalCentroidConfig
) -> list[Blob]:
    """The blobs with their local centroids (:func:`with_local_centroids`);
    ``cfg.enabled`` False: unchanged (the paper's eq. 11)."""
    if not cfg.enabled or not blobs:
        return blobs
    return with_local_centroids(blobs, measure_blobs(gray, blobs, cfg))
