"""Compiled inner loops of feature extraction (paper §4.2): label statistics and eq. 11 centroids.

The per-blob work of :mod:`app.vision.features` (a dilated support, weights, moments, the peak)
is a handful of small array operations per LED; from Python each costs a call's overhead
(≈ 10–15 µs per blob in all), which dominated a tracked frame. Here the same arithmetic runs in
one compiled loop per frame (numba, cached on disk after the first call). The results are the
same numbers: integer weights are summed exactly in float64, so the centroids equal OpenCV
``moments`` on the same weights bit for bit when the background level is an integer.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# columns of the candidate table passed to :func:`centroid_table`
# label, x, y, w, h, area (image px), region (lx, ly, lx1, ly1) of its box in the label
# array, origin (ox, oy) of that box in the image, pad (centroid margin, px)
CAND_COLUMNS = 13


@njit(cache=True, nogil=True)
def label_stats(labels: np.ndarray, n: int) -> np.ndarray:  # pragma: no cover - compiled
    """(n, 5) int64 rows (x, y, w, h, area) of labels 0..n−1 over a label image (row 0 unused),
    the values of ``cv2.connectedComponentsWithStats`` for the foreground labels."""
    h, w = labels.shape
    big = np.int64(1) << 40
    x0 = np.full(n, big, np.int64)
    y0 = np.full(n, big, np.int64)
    x1 = np.full(n, -1, np.int64)
    y1 = np.full(n, -1, np.int64)
    area = np.zeros(n, np.int64)
    for y in range(h):
        row = labels[y]
        for x in range(w):
            lab = row[x]
            if lab > 0:
                area[lab] += 1
                if x < x0[lab]:
                    x0[lab] = x
                if x > x1[lab]:
                    x1[lab] = x
                if y < y0[lab]:
                    y0[lab] = y
                y1[lab] = y
    out = np.zeros((n, 5), np.int64)
    for k in range(1, n):
        if area[k] > 0:
            out[k, 0] = x0[k]
            out[k, 1] = y0[k]
            out[k, 2] = x1[k] - x0[k] + 1
            out[k, 3] = y1[k] - y0[k] + 1
            out[k, 4] = area[k]
    return out


@njit(cache=True, nogil=True)
def centroid_table(
    gray: np.ndarray, labels: np.ndarray, cands: np.ndarray, background: float
) -> np.ndarray:  # pragma: no cover - compiled
    """Eq. 11 for every candidate row (see ``CAND_COLUMNS``): (k, 4) float64 rows
    (u px, v px, mass, peak).

    Weights ``P_i = max(gray − background, 0)`` over the component dilated by ``pad`` px (a
    (2·pad+1)² square), never on a neighbouring component's pixels; (u, v) are pixel centres
    in the image. ``peak`` is the brightest gray value on the component itself; a component
    of zero mass gets its bounding-box centre.
    """
    k = cands.shape[0]
    out = np.zeros((k, 4), np.float64)
    for c in range(k):
        lab_id = cands[c, 0]
        x, y, w, h, area = cands[c, 1], cands[c, 2], cands[c, 3], cands[c, 4], cands[c, 5]
        lx, ly, lx1, ly1 = cands[c, 6], cands[c, 7], cands[c, 8], cands[c, 9]
        ox, oy, pad = cands[c, 10], cands[c, 11], cands[c, 12]
        # the window, in box coordinates (as the OpenCV formulation crops it)
        wx0 = max(0, x - ox - pad)
        wy0 = max(0, y - oy - pad)
        wx1 = min(lx1 - lx, x - ox + w + pad)
        wy1 = min(ly1 - ly, y - oy + h + pad)
        ww, wh = wx1 - wx0, wy1 - wy0
        # dilation of the component: rows, then columns (separable square kernel)
        comp = np.zeros((wh, ww), np.uint8)
        for j in range(wh):
            for i in range(ww):
                if labels[ly + wy0 + j, lx + wx0 + i] == lab_id:
                    comp[j, i] = 1
        horiz = np.zeros((wh, ww), np.uint8)
        for j in range(wh):
            for i in range(ww):
                if comp[j, i]:
                    a = max(0, i - pad)
                    b = min(ww, i + pad + 1)
                    for q in range(a, b):
                        horiz[j, q] = 1
        support = np.zeros((wh, ww), np.uint8)
        for j in range(wh):
            for i in range(ww):
                if horiz[j, i]:
                    a = max(0, j - pad)
                    b = min(wh, j + pad + 1)
                    for q in range(a, b):
                        support[q, i] = 1
        mass = 0.0
        m10 = 0.0
        m01 = 0.0
        peak = 0.0
        for j in range(wh):
            for i in range(ww):
                g = float(gray[oy + wy0 + j, ox + wx0 + i])
                if comp[j, i] and g > peak:
                    peak = g
                if not support[j, i]:
                    continue
                lab = labels[ly + wy0 + j, lx + wx0 + i]
                if lab != 0 and lab != lab_id:
                    continue
                wgt = g - background
                if wgt <= 0.0:
                    continue
                mass += wgt
                m10 += wgt * i
                m01 += wgt * j
        if mass <= 0.0:
            out[c, 0] = x + (w - 1) / 2.0
            out[c, 1] = y + (h - 1) / 2.0
        else:
            out[c, 0] = m10 / mass + wx0 + ox
            out[c, 1] = m01 / mass + wy0 + oy
        out[c, 2] = mass
        out[c, 3] = peak
        _ = area
    return out
