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
# array, origin (ox, oy) of that box in the image
CAND_COLUMNS = 12


@njit(cache=True, nogil=True)
def gate_mask(
    stats: np.ndarray,
    width: int,
    height: int,
    min_area: int,
    max_area: int,
    max_aspect: float,
    min_fill: float,
) -> np.ndarray:  # pragma: no cover - compiled
    """Which (x, y, w, h, area) rows (image px) pass the area, aspect (long/short side of the
    box), fill (area/box) and image-border gate (``app.vision.features.BlobGate``)."""
    ok = np.zeros(stats.shape[0], np.bool_)
    for k in range(stats.shape[0]):
        x, y, w, h, area = stats[k, 0], stats[k, 1], stats[k, 2], stats[k, 3], stats[k, 4]
        aspect = max(w, h) / max(1, min(w, h))
        fill = area / max(1, w * h)
        border = x == 0 or y == 0 or x + w >= width or y + h >= height
        ok[k] = (
            min_area <= area <= max_area
            and aspect <= max_aspect
            and fill >= min_fill
            and not border
        )
    return ok


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
    # scratch images, allocated once for the largest window (w, h + 2·pad ≤ w, h + 2·pad_max)
    big = 0
    for c in range(k):
        pad = max(2, int(np.rint(0.5 * np.sqrt(cands[c, 5]))))
        big = max(big, max(cands[c, 3], cands[c, 4]) + 2 * pad)
    comp_buf = np.empty((big, big), np.uint8)
    horiz_buf = np.empty((big, big), np.uint8)
    support_buf = np.empty((big, big), np.uint8)
    for c in range(k):
        lab_id = cands[c, 0]
        x, y, w, h, area = cands[c, 1], cands[c, 2], cands[c, 3], cands[c, 4], cands[c, 5]
        lx, ly, lx1, ly1 = cands[c, 6], cands[c, 7], cands[c, 8], cands[c, 9]
        ox, oy = cands[c, 10], cands[c, 11]
        pad = max(2, int(np.rint(0.5 * np.sqrt(area))))  # the centroid margin (px)
        # the window, in box coordinates (as the OpenCV formulation crops it)
        wx0 = max(0, x - ox - pad)
        wy0 = max(0, y - oy - pad)
        wx1 = min(lx1 - lx, x - ox + w + pad)
        wy1 = min(ly1 - ly, y - oy + h + pad)
        ww, wh = wx1 - wx0, wy1 - wy0
        # dilation of the component: rows, then columns (separable square kernel)
        comp = comp_buf[:wh, :ww]  # every element written below
        for j in range(wh):
            for i in range(ww):
                comp[j, i] = 1 if labels[ly + wy0 + j, lx + wx0 + i] == lab_id else 0
        # running counts over (2·pad+1) px: O(window) whatever the pad
        horiz = horiz_buf[:wh, :ww]
        for j in range(wh):
            count = 0
            for i in range(min(pad, ww)):
                count += comp[j, i]
            for i in range(ww):
                if i + pad < ww:
                    count += comp[j, i + pad]
                if i - pad - 1 >= 0:
                    count -= comp[j, i - pad - 1]
                horiz[j, i] = count > 0
        support = support_buf[:wh, :ww]
        for i in range(ww):
            count = 0
            for j in range(min(pad, wh)):
                count += horiz[j, i]
            for j in range(wh):
                if j + pad < wh:
                    count += horiz[j + pad, i]
                if j - pad - 1 >= 0:
                    count -= horiz[j - pad - 1, i]
                support[j, i] = count > 0
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
    return out


@njit(cache=True, nogil=True)
def _find(parent: np.ndarray, p: int) -> int:  # pragma: no cover - compiled
    root = p
    while parent[root] != root:
        root = parent[root]
    while parent[p] != root:  # path compression
        nxt = parent[p]
        parent[p] = root
        p = nxt
    return root


@njit(cache=True, nogil=True)
def foreground_pixels(
    flat: np.ndarray, words: np.ndarray, width: int
) -> np.ndarray:  # pragma: no cover
    """(k, 2) int64 (x, y) of the nonzero pixels of a C-contiguous image, in row-major order
    (as ``cv2.findNonZero``): ``flat`` is the image as one uint8 row, ``words`` its first
    8·⌊size/8⌋ bytes seen as uint64 (eight pixels tested at once)."""
    count = 0
    for i in range(words.shape[0]):
        if words[i] != 0:
            for b in range(8):
                if flat[8 * i + b] != 0:
                    count += 1
    for i in range(8 * words.shape[0], flat.shape[0]):
        if flat[i] != 0:
            count += 1
    out = np.empty((count, 2), np.int64)
    k = 0
    for i in range(words.shape[0]):
        if words[i] != 0:
            for b in range(8):
                j = 8 * i + b
                if flat[j] != 0:
                    out[k, 0], out[k, 1] = j % width, j // width
                    k += 1
    for j in range(8 * words.shape[0], flat.shape[0]):
        if flat[j] != 0:
            out[k, 0], out[k, 1] = j % width, j // width
            k += 1
    return out


@njit(cache=True, nogil=True)
def label_pixels(xy: np.ndarray, labels: np.ndarray) -> np.ndarray:  # pragma: no cover
    """8-connected components of the foreground pixels ``xy`` ((k, 2) x, y in row-major order,
    as ``cv2.findNonZero`` lists them): writes labels 1..n−1 (numbered in raster order of each
    component's first pixel) into the zeroed int32 image ``labels`` and returns the (n, 5)
    int64 stats rows (x, y, w, h, area), row 0 unused — Algorithm 2's one-pass labelling by
    union–find over the foreground only, O(foreground pixels)."""
    k = xy.shape[0]
    h, w = labels.shape
    parent = np.arange(k)
    for p in range(k):
        labels[xy[p, 1], xy[p, 0]] = p + 1
    for p in range(k):
        x, y = xy[p, 0], xy[p, 1]
        root = p
        # the neighbours already seen: (x−1, y) and the three above
        for q in (
            labels[y, x - 1] - 1 if x > 0 else -1,
            labels[y - 1, x - 1] - 1 if y > 0 and x > 0 else -1,
            labels[y - 1, x] - 1 if y > 0 else -1,
            labels[y - 1, x + 1] - 1 if y > 0 and x + 1 < w else -1,
        ):
            if q < 0:
                continue
            b = _find(parent, q)
            if b != root:  # the earlier pixel stays the root
                if root < b:
                    parent[b] = root
                else:
                    parent[root] = b
                    root = b
    # final labels in raster order of each component's first pixel, and the stats
    new = np.zeros(k, np.int64)
    big = np.int64(1) << 40
    st = np.zeros((k + 1, 5), np.int64)
    x1 = np.full(k + 1, -1, np.int64)
    y1 = np.full(k + 1, -1, np.int64)
    n = 1
    for p in range(k):
        r = _find(parent, p)
        lab = new[r]
        if lab == 0:
            lab = new[r] = n
            st[n, 0] = st[n, 1] = big
            n += 1
        x, y = xy[p, 0], xy[p, 1]
        labels[y, x] = lab
        st[lab, 4] += 1
        if x < st[lab, 0]:
            st[lab, 0] = x
        if y < st[lab, 1]:
            st[lab, 1] = y
        if x > x1[lab]:
            x1[lab] = x
        if y > y1[lab]:
            y1[lab] = y
    for lab in range(1, n):
        st[lab, 2] = x1[lab] - st[lab, 0] + 1
        st[lab, 3] = y1[lab] - st[lab, 1] + 1
    return st[:n].copy()


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
    hot = np.zeros((nb, nt), np.int64)  # 0: cold, −1: hot unvisited, k ≥ 1: cluster k
    for by in range(nb):
        for tx in range(nt):
            m = 0
            for x in range(tx * t, min(w, tx * t + t)):
                if bands[by, x] > m:
                    m = bands[by, x]
            if m >= threshold:
                hot[by, tx] = -1
    boxes = np.zeros((nb * nt, 4), np.int64)
    stack = np.empty((nb * nt, 2), np.int64)
    k = 0
    for by in range(nb):
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
            x0, y0 = tx0 * t, ty0 * t
            x1, y1 = min(w, (tx1 + 1) * t), min(h, (ty1 + 1) * t)
            bx0, by0, bx1, by1 = x1, y1, -1, -1
            for y in range(y0, y1):
                row = gray[y]
                for x in range(x0, x1):
                    if row[x] >= threshold:
                        if x < bx0:
                            bx0 = x
                        if x > bx1:
                            bx1 = x
                        if y < by0:
                            by0 = y
                        by1 = y
            boxes[k - 1, 0], boxes[k - 1, 1] = bx0, by0
            boxes[k - 1, 2], boxes[k - 1, 3] = bx1 + 1, by1 + 1
    return boxes[:k]


@njit(cache=True, nogil=True)
def pack_boxes(
    gray: np.ndarray, boxes: np.ndarray, places: np.ndarray, ring: int, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """The mosaic of the image boxes (k, 4: x0, y0, x1, y1) at ``places`` (k, 2: x, y), each
    with a ``ring``-px border replicated from its edge (``cv2.BORDER_REPLICATE``), and the
    owner map (the box index of each mosaic pixel that is an image pixel, else −1)."""
    mosaic = np.zeros(shape, np.uint8)
    owner = np.full(shape, -1, np.int32)
    for k in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        px, py = places[k, 0], places[k, 1]
        for j in range(-ring, y1 - y0 + ring):
            sy = min(max(y0 + j, y0), y1 - 1)
            for i in range(-ring, x1 - x0 + ring):
                sx = min(max(x0 + i, x0), x1 - 1)
                mosaic[py + j, px + i] = gray[sy, sx]
        for j in range(y1 - y0):
            for i in range(x1 - x0):
                owner[py + j, px + i] = k
    return mosaic, owner


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
        m = max(2, int(np.ceil(0.5 * np.sqrt(area)))) + reach
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
