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
    # scratch, allocated once for the largest window (w + 2·pad ≤ its side)
    big = 0
    for c in range(k):
        pad = max(2, int(np.rint(0.5 * np.sqrt(cands[c, 5]))))
        big = max(big, max(cands[c, 3], cands[c, 4]) + 2 * pad)
    horiz_buf = np.empty((big, big), np.uint8)  # the component's rows dilated horizontally
    comp_row = np.empty(big, np.uint8)
    cover = np.empty(big, np.int32)  # dilated rows within ±pad of the current row
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
        # the component's rows (window rows r0..r1−1) dilated horizontally by a running
        # count over (2·pad+1) px, and its peak; rows outside r0..r1 hold no component pixel
        r0, r1 = y - oy - wy0, y - oy - wy0 + h
        peak = 0.0
        for j in range(r0, r1):
            lrow = labels[ly + wy0 + j]
            grow = gray[oy + wy0 + j]
            for i in range(ww):
                on = lrow[lx + wx0 + i] == lab_id
                comp_row[i] = on
                if on:
                    g = float(grow[ox + wx0 + i])
                    if g > peak:
                        peak = g
            hz = horiz_buf[j - r0]
            count = 0
            for i in range(min(pad, ww)):
                count += comp_row[i]
            for i in range(ww):
                if i + pad < ww:
                    count += comp_row[i + pad]
                if i - pad - 1 >= 0:
                    count -= comp_row[i - pad - 1]
                hz[i] = count > 0
        # vertical dilation as a running count per column, row by row; weights where dilated
        for i in range(ww):
            cover[i] = 0
        for j in range(min(r1, pad)):  # rows r0.. up to (the first window row) + pad
            if j >= r0:
                hz = horiz_buf[j - r0]
                for i in range(ww):
                    cover[i] += hz[i]
        mass = 0.0
        m10 = 0.0
        m01 = 0.0
        for j in range(wh):
            add, sub = j + pad, j - pad - 1
            if add < wh and r0 <= add < r1:
                hz = horiz_buf[add - r0]
                for i in range(ww):
                    cover[i] += hz[i]
            if sub >= 0 and r0 <= sub < r1:
                hz = horiz_buf[sub - r0]
                for i in range(ww):
                    cover[i] -= hz[i]
            lrow = labels[ly + wy0 + j]
            grow = gray[oy + wy0 + j]
            for i in range(ww):
                if cover[i] == 0:
                    continue
                lab = lrow[lx + wx0 + i]
                if lab != 0 and lab != lab_id:
                    continue
                wgt = float(grow[ox + wx0 + i]) - background
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


@njit(cache=True, nogil=True)
def median_foreground(
    gray: np.ndarray,
    box: np.ndarray,
    threshold: int,
    radius: int,
    xy: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Eq. 10 binarisation (I ≥ T) and the (2·radius+1)² median filter of §4.1 (3) inside the
    image ``box`` (x0, y0, x1, y1, half-open), with ``cv2.BORDER_REPLICATE`` at the box's edge
    (as ``cv2.medianBlur``): writes the (x, y) box coordinates of the filtered image's
    foreground pixels, in raster order, into ``xy`` and returns their count. On a binary image
    the median is 1 where at least half the window (rounded up) is 1."""
    x0, y0, x1, y1 = box[0], box[1], box[2], box[3]
    bh, bw = y1 - y0, x1 - x0
    side = 2 * radius + 1
    need = (side * side + 1) // 2
    col = np.empty((bh, bw), np.int32)  # ones in the window's column through each pixel
    if radius == 1:  # the default 3×3 filter, unrolled (≈ 2× the general loop)
        for j in range(bh):
            ra, rb, rc = gray[y0 + max(j - 1, 0)], gray[y0 + j], gray[y0 + min(j + 1, bh - 1)]
            for i in range(bw):
                x = x0 + i
                col[j, i] = (
                    np.int32(ra[x] >= threshold)
                    + np.int32(rb[x] >= threshold)
                    + np.int32(rc[x] >= threshold)
                )
        count = 0
        for j in range(bh):
            for i in range(bw):
                if col[j, max(i - 1, 0)] + col[j, i] + col[j, min(i + 1, bw - 1)] >= 5:
                    xy[count, 0], xy[count, 1] = i, j
                    count += 1
        return count
    for j in range(bh):
        for i in range(bw):
            s = 0
            for d in range(-radius, radius + 1):
                jj = min(max(j + d, 0), bh - 1)
                if gray[y0 + jj, x0 + i] >= threshold:
                    s += 1
            col[j, i] = s
    count = 0
    for j in range(bh):
        for i in range(bw):
            s = 0
            for d in range(-radius, radius + 1):
                s += col[j, min(max(i + d, 0), bw - 1)]
            if s >= need:
                xy[count, 0], xy[count, 1] = i, j
                count += 1
    return count


@njit(cache=True, nogil=True)
def detect_in_boxes(
    gray: np.ndarray,
    bands: np.ndarray,
    band_rows: int,
    threshold: int,
    ksize: int,
    background: float,
    min_area: int,
    max_area: int,
    max_aspect: float,
    min_fill: float,
    max_blobs: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:  # pragma: no cover - compiled
    """The whole lean acquisition of one image in one compiled call: the bright tiles
    (:func:`hot_tile_boxes`) grown and merged (:func:`grow_and_merge_boxes`), then in each box
    eq. 10 + the median filter (:func:`median_foreground`), Algorithm 2's labelling
    (:func:`label_pixels`), the gate (:func:`gate_mask`) and eq. 11 (:func:`centroid_table`).

    Returns (kept (k, 5) int64 x, y, w, h, area in image px; their (k, 4) float64 u px, v px,
    mass, peak; rejected (r, 5) int64 rows; the number of kept components). Boxes in order,
    components in raster order within a box. Past ``max_blobs`` kept components no more
    centroids are computed (the frame is refused)."""
    h, w = gray.shape
    tiles = hot_tile_boxes(gray, bands, band_rows, threshold)
    if tiles.shape[0] == 0:
        return np.zeros((0, 5), np.int64), np.zeros((0, 4)), np.zeros((0, 5), np.int64), 0
    boxes = grow_and_merge_boxes(tiles, w, h, ksize // 2 + 2)
    big = 0
    for b in range(boxes.shape[0]):
        big = max(big, (boxes[b, 2] - boxes[b, 0]) * (boxes[b, 3] - boxes[b, 1]))
    xy = np.empty((big, 2), np.int64)
    kept_parts = [np.zeros((0, 5), np.int64)]  # typed by their first (empty) part
    cent_parts = [np.zeros((0, 4))]
    rej_parts = [np.zeros((0, 5), np.int64)]
    total = 0
    for b in range(boxes.shape[0]):
        x0, y0 = boxes[b, 0], boxes[b, 1]
        bw, bh = boxes[b, 2] - x0, boxes[b, 3] - y0
        count = median_foreground(gray, boxes[b], threshold, ksize // 2, xy)
        if count == 0:
            continue
        labels = np.zeros((bh, bw), np.int32)
        st = label_pixels(xy[:count], labels)[1:]
        st[:, 0] += x0
        st[:, 1] += y0
        ok = gate_mask(st, w, h, min_area, max_area, max_aspect, min_fill)
        n_ok = 0
        for c in range(st.shape[0]):
            if ok[c]:
                n_ok += 1
        rej_parts.append(st[~ok])
        if n_ok == 0:
            continue
        cands = np.empty((n_ok, 12), np.int64)
        k = 0
        for c in range(st.shape[0]):
            if ok[c]:
                cands[k, 0] = c + 1
                cands[k, 1:6] = st[c]
                cands[k, 6], cands[k, 7], cands[k, 8], cands[k, 9] = 0, 0, bw, bh
                cands[k, 10], cands[k, 11] = x0, y0
                k += 1
        total += n_ok
        kept_parts.append(cands[:, 1:6].copy())
        if total <= max_blobs:
            cent_parts.append(centroid_table(gray, labels, cands, background))
    if total > max_blobs:
        kept_parts = [np.zeros((0, 5), np.int64)]
        cent_parts = [np.zeros((0, 4))]
    return _stack(kept_parts, 5), _stack(cent_parts, 4), _stack(rej_parts, 5), total


@njit(cache=True, nogil=True)
def _stack(parts, ncols):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Rows of a non-empty list of (k_i, ncols) arrays, one after the other."""
    n = 0
    for a in parts:
        n += a.shape[0]
    out = np.empty((n, ncols), parts[0].dtype)
    r = 0
    for a in parts:
        out[r : r + a.shape[0]] = a
        r += a.shape[0]
    return out
