"""Where to look for blobs: the compiled loops that bound the bright pixels of a frame
(numba, cached on disk; paper §4.1–§4.2).

The acquisition labels and centroids only around the pixels that reach eq. 10's threshold:
:func:`hot_tile_boxes` finds them from the band maxima (square tiles whose maximum reaches
the threshold, grouped into 8-connected clusters, each shrunk to its bright pixels:
:func:`bright_box`), and :func:`grow_and_merge_boxes` widens each box by the largest
centroid margin a blob inside it can need (:func:`grow_margin_px`) plus the median filter's
reach, merging boxes that overlap. :mod:`app.vision.blob_kernels` then labels and measures
the blobs inside them.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def touch_rows(gray: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> int:  # pragma: no cover
    """Load the first and last pixel of each row of [x0, x1) × [y0, y1) (clipped to the
    image) and return their sum: independent loads, so the rows' cache misses overlap before
    a loop that reads the rows one after the other (a frame just read from a camera is not in
    the cache). The caller must use the sum, or the compiler drops the loads: ``sum >> 62``
    is 0 (the sum is ≥ 0 and < 2⁶²) and keeps them."""
    h, w = gray.shape
    x0, x1 = max(0, x0), min(w, x1)
    touch = 0
    if x1 <= x0:
        return touch
    for y in range(max(0, y0), min(h, y1)):
        touch += gray[y, x0] + gray[y, x1 - 1]
    return touch


@njit(cache=True, nogil=True)
def bright_box(
    gray: np.ndarray, rect: np.ndarray, threshold: int, out: np.ndarray
) -> bool:  # pragma: no cover - compiled
    """The box (x0, y0, x1, y1, half-open, px) of the pixels ≥ ``threshold`` inside ``rect``
    (same form) into ``out``; ``False`` when there is none. Rows first: a uint8 SIMD count
    per row, the columns only on rows that have such pixels."""
    x0, y0, x1, y1 = rect[0], rect[1], rect[2], rect[3]
    if threshold > 255:
        return False  # nothing can reach it
    thr8 = np.uint8(max(threshold, 0))
    bx0, by0, bx1, by1 = x1 + (touch_rows(gray, x0, y0, x1, y1) >> 62), y1, -1, -1
    for y in range(y0, y1):
        row = gray[y, x0:x1]
        hits = np.int32(0)
        for x in range(x1 - x0):
            hits += np.int32(row[x] >= thr8)
        if hits == 0:
            continue
        by0 = min(by0, y)
        by1 = y
        for x in range(x1 - x0):
            if row[x] >= thr8:
                bx0 = min(bx0, x0 + x)
                bx1 = max(bx1, x0 + x)
    out[0], out[1], out[2], out[3] = bx0, by0, bx1 + 1, by1 + 1
    return by1 >= 0


@njit(cache=True, nogil=True)
def grow_margin_px(area: int, reach: int) -> int:  # pragma: no cover - compiled
    """How far a box of bright pixels (``area`` px) is grown: the largest centroid margin a
    blob inside it can need, max(2, ⌈½√area⌉), plus ``reach`` px (the median filter's)."""
    return max(2, int(np.ceil(0.5 * np.sqrt(area)))) + reach


@njit(cache=True, nogil=True)
def hot_tile_boxes(
    gray: np.ndarray, bands: np.ndarray, band_rows: int, threshold: int
) -> np.ndarray:  # pragma: no cover - compiled
    """Boxes (k, 4: x0, y0, x1, y1 half-open, px) holding every pixel ≥ ``threshold``: the
    ``band_rows``-px square tiles whose maximum (from the band maxima ``bands``) reaches it,
    grouped into 8-connected clusters (raster order of each cluster's first tile), each
    cluster's box shrunk to its bright pixels."""
    h, w = gray.shape
    t = band_rows
    nb = bands.shape[0]
    nt = (w + t - 1) // t
    if threshold > 255:
        return np.zeros((0, 4), np.int64)  # nothing can reach it
    hot = np.zeros((nb, nt), np.int32)  # 0: cold, −1: hot unvisited, k ≥ 1: cluster k
    # a tile is hot when one of its band maxima reaches the threshold; a band row with none
    # (most of a frame) is passed over after one uint8 SIMD max
    thr8 = np.uint8(max(threshold, 0))
    hot_rows = np.zeros(nb, np.bool_)
    for by in range(nb):
        row = bands[by]
        m = np.uint8(0)
        for x in range(w):
            m = max(m, row[x])
        if m < thr8:
            continue
        hot_rows[by] = True
        for tx in range(nt):
            mt = np.uint8(0)
            for x in range(tx * t, min(w, tx * t + t)):
                mt = max(mt, row[x])
            if mt >= thr8:
                hot[by, tx] = -1
    boxes = np.empty((nb * nt, 4), np.int64)  # (bright_box writes every row it is given)
    stack = np.empty((nb * nt, 2), np.int64)
    rect = np.empty(4, np.int64)
    k = 0
    for by in range(nb):
        if not hot_rows[by]:
            continue
        for tx in range(nt):
            if hot[by, tx] != -1:
                continue
            k += 1  # flood fill one cluster (8-connected tiles)
            hot[by, tx] = k
            top = 0
            stack[0, 0], stack[0, 1] = by, tx
            ty0, ty1, tx0, tx1 = by, by, tx, tx
            while top >= 0:
                cy, cx = stack[top, 0], stack[top, 1]
                top -= 1
                ty0, ty1 = min(ty0, cy), max(ty1, cy)
                tx0, tx1 = min(tx0, cx), max(tx1, cx)
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        ny, nx = cy + dy, cx + dx
                        if 0 <= ny < nb and 0 <= nx < nt and hot[ny, nx] == -1:
                            hot[ny, nx] = k
                            top += 1
                            stack[top, 0], stack[top, 1] = ny, nx
            # the cluster's tile box in px, shrunk to its pixels ≥ threshold
            rect[0], rect[1] = tx0 * t, ty0 * t
            rect[2], rect[3] = min(w, (tx1 + 1) * t), min(h, (ty1 + 1) * t)
            bright_box(gray, rect, threshold, boxes[k - 1])
    return boxes[:k]


@njit(cache=True, nogil=True)
def grow_and_merge_boxes(
    boxes: np.ndarray, width: int, height: int, reach: int
) -> np.ndarray:  # pragma: no cover - compiled
    """Each box (k, 4: x0, y0, x1, y1, half-open) widened by the largest centroid margin a blob
    inside it can need (max(2, ⌈0.5·√area⌉), area ≤ the box's) plus ``reach`` px, clipped to the
    image; overlapping boxes merged into their bounding box, repeated until none overlap
    (groups numbered by their first member, in order)."""
    n = boxes.shape[0]
    g = np.empty((n, 4), np.int64)
    for i in range(n):
        area = (boxes[i, 2] - boxes[i, 0]) * (boxes[i, 3] - boxes[i, 1])
        m = grow_margin_px(area, reach)
        g[i, 0] = max(0, boxes[i, 0] - m)
        g[i, 1] = max(0, boxes[i, 1] - m)
        g[i, 2] = min(width, boxes[i, 2] + m)
        g[i, 3] = min(height, boxes[i, 3] + m)
    while g.shape[0] > 1:
        n = g.shape[0]
        group = np.arange(n)
        merged = False
        for i in range(n):
            for j in range(i + 1, n):
                if (
                    g[i, 0] < g[j, 2]
                    and g[j, 0] < g[i, 2]
                    and g[i, 1] < g[j, 3]
                    and g[j, 1] < g[i, 3]
                ):
                    merged = True
                    gi, gj = group[i], group[j]
                    if gi != gj:
                        for t in range(n):
                            if group[t] == gj:
                                group[t] = gi
        if not merged:
            break
        ids = np.unique(group)
        out = np.empty((ids.shape[0], 4), np.int64)
        for k in range(ids.shape[0]):
            out[k, 0] = out[k, 1] = np.int64(1) << 40
            out[k, 2] = out[k, 3] = -1
            for t in range(n):
                if group[t] == ids[k]:
                    out[k, 0] = min(out[k, 0], g[t, 0])
                    out[k, 1] = min(out[k, 1], g[t, 1])
                    out[k, 2] = max(out[k, 2], g[t, 2])
                    out[k, 3] = max(out[k, 3], g[t, 3])
        g = out
    return g
