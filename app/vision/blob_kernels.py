"""Compiled inner loops of feature extraction (paper §4.2): label statistics and eq. 11 centroids.

The per-blob work of :mod:`app.vision.features` (a dilated support, weights, moments, the peak)
is a handful of small array operations per LED; from Python each costs a call's overhead
(≈ 10–15 µs per blob in all), which dominated a tracked frame. Here the same arithmetic runs in
one compiled loop per frame (numba, cached on disk after the first call). The results are the
same numbers: integer weights are summed exactly in float64, so the centroids equal OpenCV
``moments`` on the same weights bit for bit when the background level is an integer.

The boxes the acquisition searches (the bright tiles, grown and merged) come from
:mod:`app.vision.bright_region_kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from app.vision.bright_region_kernels import (
    bright_box,
    grow_and_merge_boxes,
    grow_margin_px,
    hot_tile_boxes,
    touch_rows,
)
from app.vision.local_centroid_kernels import (
    OUT_COLUMNS,
    OUT_U,
    measure_box,
    scratch,
    scratch_cells,
)

# columns of a candidate row passed to :func:`_centroid`
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
def centroid_margin_px(area: int) -> int:  # pragma: no cover - compiled
    """The centroid's support margin around a component of ``area`` px: max(2, rint(½√area))."""
    return max(2, int(np.rint(0.5 * np.sqrt(area))))


@njit(cache=True, nogil=True)
def _centroid(
    gray: np.ndarray,
    labels: np.ndarray,
    cand: np.ndarray,
    background: float,
    horiz_buf: np.ndarray,
    comp_row: np.ndarray,
    cover: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Eq. 11 for one candidate row (``CAND_COLUMNS``) into ``out`` (u px, v px, mass, peak);
    scratch buffers of at least the window's side.

    Weights ``P_i = max(gray − background, 0)`` over the component dilated by ``pad`` px (a
    (2·pad+1)² square, :func:`centroid_margin_px`), never on a neighbouring component's
    pixels; (u, v) are pixel centres in the image. ``peak`` is the brightest gray value on the
    component itself; a component of zero mass gets its bounding-box centre."""
    lab_id = cand[0]
    x, y, w, h, area = cand[1], cand[2], cand[3], cand[4], cand[5]
    lx, ly, lx1, ly1 = cand[6], cand[7], cand[8], cand[9]
    ox, oy = cand[10], cand[11]
    pad = centroid_margin_px(area)
    # the window, in box coordinates (as the OpenCV formulation crops it)
    wx0 = max(0, x - ox - pad)
    wy0 = max(0, y - oy - pad)
    wx1 = min(lx1 - lx, x - ox + w + pad)
    wy1 = min(ly1 - ly, y - oy + h + pad)
    ww, wh = wx1 - wx0, wy1 - wy0
    # the component's rows (window rows r0..r1−1) dilated horizontally by a running count
    # over (2·pad+1) px, and its peak; rows outside r0..r1 hold no component pixel
    r0, r1 = y - oy - wy0, y - oy - wy0 + h
    peak = 0
    for j in range(r0, r1):
        lrow = labels[ly + wy0 + j]
        grow = gray[oy + wy0 + j]
        for i in range(ww):
            on = lrow[lx + wx0 + i] == lab_id
            comp_row[i] = on
            if on and grow[ox + wx0 + i] > peak:
                peak = grow[ox + wx0 + i]
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
    # vertical dilation as a running count per column, row by row; the weights where dilated
    for i in range(ww):
        cover[i] = 0
    for j in range(r0, min(r1, pad)):  # the rows within pad of the first window row
        hz = horiz_buf[j - r0]
        for i in range(ww):
            cover[i] += hz[i]
    # P_i = g − background > 0 summed as integers (g, g·i, g·j, count, i, j), exact: with an
    # integer background the sums equal float sums of the weights bit for bit. Branch-free
    # per row (SIMD), the rows' sums weighted by their row after
    gthr = int(np.floor(background))  # g > background ⇔ g > ⌊background⌋ (g an integer)
    n = sg = sgi = sgj = si = sj = 0
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
        lrow = labels[ly + wy0 + j, lx + wx0 : lx + wx0 + ww]
        grow = gray[oy + wy0 + j, ox + wx0 : ox + wx0 + ww]
        rn = rg = rgi = ri = 0
        for i in range(ww):
            lab = lrow[i]
            g = int(grow[i])
            # in the support, not on a neighbouring component, above the background
            sel = int((cover[i] != 0) & ((lab == 0) | (lab == lab_id)) & (g > gthr))
            rn += sel
            rg += sel * g
            rgi += sel * g * i
            ri += sel * i
        n += rn
        sg += rg
        sgi += rgi
        si += ri
        sgj += rg * j
        sj += rn * j
    mass = sg - n * background
    if mass <= 0.0:
        out[0] = x + (w - 1) / 2.0
        out[1] = y + (h - 1) / 2.0
    else:
        out[0] = (sgi - si * background) / mass + wx0 + ox
        out[1] = (sgj - sj * background) / mass + wy0 + oy
    out[2] = mass
    out[3] = peak


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
def _row_runs(
    row: np.ndarray, y: int, runs: np.ndarray, k: int, write: bool
) -> int:  # pragma: no cover - compiled
    """Runs of the nonzero bytes of one mask row (eight zero bytes skipped at a time), written
    into ``runs`` from row ``k`` if ``write``; returns the new run count."""
    w = row.shape[0]
    x = 0
    inside = False
    while x < w:
        if not inside and x + 8 <= w:
            zero = True
            for b in range(8):
                if row[x + b] != 0:
                    zero = False
                    break
            if zero:
                x += 8
                continue
        on = row[x] != 0
        if on and not inside:
            if write:
                runs[k, 0], runs[k, 1] = y, x
            inside = True
        elif inside and not on:
            if write:
                runs[k, 2] = x - 1
            k += 1
            inside = False
        x += 1
    if inside:
        if write:
            runs[k, 2] = w - 1
        k += 1
    return k


@njit(cache=True, nogil=True)
def mask_runs(mask: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """(k, 3) int64 runs (row y, first x, last x, px) of the nonzero pixels of ``mask``, in
    raster order."""
    empty = np.empty((0, 3), np.int64)
    count = 0
    for y in range(mask.shape[0]):
        count = _row_runs(mask[y], y, empty, count, False)
    runs = np.empty((count, 3), np.int64)
    k = 0
    for y in range(mask.shape[0]):
        k = _row_runs(mask[y], y, runs, k, True)
    return runs


@njit(cache=True, nogil=True)
def label_runs(runs: np.ndarray, labels: np.ndarray) -> np.ndarray:  # pragma: no cover
    """8-connected components of the foreground given as runs ((k, 3) row, first x, last x,
    in raster order, as :func:`mask_runs` lists them): writes labels 1..n−1 (numbered in
    raster order of each component's first pixel) into the zeroed int32 image ``labels`` and
    returns the (n, 5) int64 stats rows (x, y, w, h, area), row 0 unused — Algorithm 2's
    one-pass labelling, by union–find over the runs (the values of
    ``cv2.connectedComponentsWithStats``)."""
    k = runs.shape[0]
    parent = np.arange(k)
    prev0 = prev1 = 0  # the previous row's runs: prev0..prev1−1
    r = 0
    while r < k:
        y = runs[r, 0]
        cur0 = r
        while r < k and runs[r, 0] == y:
            r += 1
        if cur0 > 0 and runs[cur0 - 1, 0] == y - 1:
            p = prev0
            for q in range(cur0, r):
                a0, a1 = runs[q, 1], runs[q, 2]
                while p < prev1 and runs[p, 2] < a0 - 1:  # ends left of q's reach
                    p += 1
                t = p
                while t < prev1 and runs[t, 1] <= a1 + 1:  # 8-connected: touches diagonally
                    ra, rb = _find(parent, q), _find(parent, t)
                    if ra != rb:  # the earlier run stays the root
                        if ra < rb:
                            parent[rb] = ra
                        else:
                            parent[ra] = rb
                    t += 1
        prev0, prev1 = cur0, r
    new = np.zeros(k, np.int64)
    big = np.int64(1) << 40
    st = np.zeros((k + 1, 5), np.int64)
    x1 = np.full(k + 1, -1, np.int64)
    y1 = np.full(k + 1, -1, np.int64)
    n = 1
    for q in range(k):
        root = _find(parent, q)
        lab = new[root]
        if lab == 0:
            lab = new[root] = n
            st[n, 0] = st[n, 1] = big
            n += 1
        y, a0, a1 = runs[q, 0], runs[q, 1], runs[q, 2]
        labels[y, a0 : a1 + 1] = lab
        st[lab, 4] += a1 - a0 + 1
        st[lab, 0] = min(st[lab, 0], a0)
        st[lab, 1] = min(st[lab, 1], y)
        x1[lab] = max(x1[lab], a1)
        y1[lab] = max(y1[lab], y)
    for lab in range(1, n):
        st[lab, 2] = x1[lab] - st[lab, 0] + 1
        st[lab, 3] = y1[lab] - st[lab, 1] + 1
    return st[:n].copy()


@njit(cache=True, nogil=True)
def median_runs(
    gray: np.ndarray,
    box: np.ndarray,
    bright: np.ndarray,
    threshold: int,
    radius: int,
    runs: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Eq. 10 binarisation (I ≥ T) and the (2·radius+1)² median filter of §4.1 (3) inside the
    image ``box`` (x0, y0, x1, y1, half-open), with ``cv2.BORDER_REPLICATE`` at the box's edge
    (as ``cv2.medianBlur``): writes the runs (row, first x, last x; box px, raster order) of
    the filtered image's foreground into ``runs`` and returns their count. On a binary image
    the median is 1 where at least half the window (rounded up) is 1.

    Only pixels within ``radius`` of ``bright`` (x0, y0, x1, y1: a box in the image holding
    every pixel ≥ T of ``box``) are filtered: any other window holds no pixel ≥ T."""
    x0, y0, x1, y1 = box[0], box[1], box[2], box[3]
    bh, bw = y1 - y0, x1 - x0
    # the region to filter, box coordinates
    fx0, fy0 = max(0, bright[0] - x0 - radius), max(0, bright[1] - y0 - radius)
    fx1, fy1 = min(bw, bright[2] - x0 + radius), min(bh, bright[3] - y0 + radius)
    if fx1 <= fx0 or fy1 <= fy0:
        return 0
    side = 2 * radius + 1
    need = (side * side + 1) // 2
    fw = fx1 - fx0
    col = np.empty(fw + 2 * radius, np.int32)  # ones in each column's window, this row
    count = 0
    for j in range(fy0, fy1):
        for c in range(fw + 2 * radius):  # columns fx0 − radius .. fx1 + radius − 1 (clamped)
            xi = x0 + min(max(fx0 - radius + c, 0), bw - 1)
            s = 0
            for d in range(-radius, radius + 1):
                if gray[y0 + min(max(j + d, 0), bh - 1), xi] >= threshold:
                    s += 1
            col[c] = s
        inside = False
        for i in range(fw):
            s = 0
            for d in range(side):
                s += col[i + d]
            on = s >= need
            if on and not inside:
                runs[count, 0], runs[count, 1] = j, fx0 + i
            elif inside and not on:
                runs[count, 2] = fx0 + i - 1
                count += 1
            inside = on
        if inside:
            runs[count, 2] = fx1 - 1
            count += 1
    return count


@njit(cache=True, nogil=True)
def _component_peak(
    gray: np.ndarray, labels: np.ndarray, cand: np.ndarray
) -> int:  # pragma: no cover
    """The brightest gray value on a candidate's component itself (``CAND_COLUMNS`` row): the
    peak :func:`_centroid` reports."""
    lab_id = cand[0]
    x, y, w, h = cand[1], cand[2], cand[3], cand[4]
    lx, ly, ox, oy = cand[6], cand[7], cand[10], cand[11]
    peak = 0
    for j in range(h):
        lrow = labels[ly + y - oy + j]
        grow = gray[y + j]
        for i in range(w):
            if lrow[lx + x - ox + i] == lab_id and grow[x + i] > peak:
                peak = grow[x + i]
    return peak


@njit(cache=True, nogil=True)
def _blob_centroid(
    gray: np.ndarray,
    labels: np.ndarray,
    cand: np.ndarray,
    background: float,
    eq11_scratch: tuple[np.ndarray, np.ndarray, np.ndarray],
    row: np.ndarray,
    local_params: np.ndarray,
    lrow: np.ndarray,
    local_scratch: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> None:  # pragma: no cover - compiled
    """A kept candidate's centroids (``CAND_COLUMNS`` row ``cand``): with ``local_params``
    (not empty) its local centroid into ``lrow`` first
    (:func:`~app.vision.local_centroid_kernels.measure_box`), and where that is measured
    ``row`` = (NaN, NaN, NaN, the component's peak); else eq. 11 into ``row``
    (:func:`_centroid`: u, v, mass, peak)."""
    if local_params.shape[0] > 0:
        state, stack, counts = local_scratch
        measure_box(gray, cand[1], cand[2], cand[3], cand[4], local_params, lrow, state, stack,
                    counts)  # fmt: skip
        if lrow[OUT_U] == lrow[OUT_U]:  # measured: eq. 11 is not needed
            row[0] = row[1] = row[2] = np.nan
            row[3] = _component_peak(gray, labels, cand)
            return
    horiz_buf, comp_row, cover = eq11_scratch
    _centroid(gray, labels, cand, background, horiz_buf, comp_row, cover, row)


@njit(cache=True, nogil=True)
def _keep_components(
    gray: np.ndarray,
    labels: np.ndarray,
    st: np.ndarray,
    x0: int,
    y0: int,
    background: float,
    gate: np.ndarray,
    kept: np.ndarray,
    cents: np.ndarray,
    rejected: np.ndarray,
    counts: np.ndarray,
    eq11_scratch: tuple[np.ndarray, np.ndarray, np.ndarray],
    local_params: np.ndarray,
    local: np.ndarray,
    local_scratch: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> None:  # pragma: no cover - compiled
    """Gate the components of ``labels`` (a box at (x0, y0) in the image; ``st``: their
    :func:`label_runs` stats, row 0 unused) and compute eq. 11 for those that pass, appending
    to ``kept``/``cents`` (up to their length) and ``rejected`` (idem); ``counts``: (kept,
    rejected, passing) so far; each kept component's centroids by :func:`_blob_centroid`
    (with ``local_params``: its local centroid into ``local``, eq. 11 only where that is not
    measured)."""
    h, w = gray.shape
    bh, bw = labels.shape
    st = st[1:]
    for c in range(st.shape[0]):
        st[c, 0] += x0
        st[c, 1] += y0
    ok = gate_mask(st, w, h, int(gate[0]), int(gate[1]), gate[2], gate[3])
    cand = np.empty(CAND_COLUMNS, np.int64)
    for c in range(st.shape[0]):
        if not ok[c]:
            if counts[1] < rejected.shape[0]:
                rejected[counts[1]] = st[c]
                counts[1] += 1
            continue
        counts[2] += 1
        if counts[0] >= kept.shape[0]:
            continue  # past max_blobs: refused, only counted
        cand[0] = c + 1
        cand[1:6] = st[c]
        cand[6], cand[7], cand[8], cand[9] = 0, 0, bw, bh
        cand[10], cand[11] = x0, y0
        kept[counts[0]] = st[c]
        k = counts[0]
        lrow = local[k] if local.shape[0] > 0 else cents[k]  # (no local rows: not written)
        _blob_centroid(gray, labels, cand, background, eq11_scratch, cents[k], local_params,
                       lrow, local_scratch)  # fmt: skip
        counts[0] += 1


@njit(cache=True, nogil=True)
def extract_in_mask(
    gray: np.ndarray,
    mask: np.ndarray,
    x0: int,
    y0: int,
    background: float,
    gate: np.ndarray,
    max_blobs: int,
    max_rejected: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:  # pragma: no cover - compiled
    """Labelling (:func:`mask_runs`, :func:`label_runs`), the gate and eq. 11 of the
    components of a binary ``mask`` that covers ``gray`` from (x0, y0) px: the outputs of
    :func:`detect_in_boxes`."""
    kept = np.empty((max_blobs, 5), np.int64)
    cents = np.empty((max_blobs, 4))
    rejected = np.empty((max_rejected, 5), np.int64)
    counts = np.zeros(3, np.int64)
    runs = mask_runs(mask)
    if runs.shape[0] > 0:
        labels = np.zeros(mask.shape, np.int32)
        st = label_runs(runs, labels)
        big = 0
        for c in range(1, st.shape[0]):
            big = max(big, max(st[c, 2], st[c, 3]) + 2 * centroid_margin_px(st[c, 4]))
        _keep_components(
            gray, labels, st, x0, y0, background, gate, kept, cents, rejected, counts,
            (np.empty((big, big), np.uint8), np.empty(big, np.uint8), np.empty(big, np.int32)),
            np.empty(0), np.empty((0, OUT_COLUMNS)), scratch(0),
        )  # fmt: skip
    n_kept, n_rej = counts[0], counts[1]
    return kept[:n_kept], cents[:n_kept], rejected[:n_rej], counts[2]


@njit(cache=True, nogil=True)
def detect_in_boxes(
    gray: np.ndarray,
    bands: np.ndarray,
    band_rows: int,
    threshold: int,
    ksize: int,
    background: float,
    gate: np.ndarray,
    max_blobs: int,
    max_rejected: int,
    local_params: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]:  # pragma: no cover - compiled
    """The whole lean acquisition of one image in one compiled call: the bright tiles
    (:func:`hot_tile_boxes`) grown and merged (:func:`grow_and_merge_boxes`), then in each box
    eq. 10 + the median filter (:func:`median_runs`), Algorithm 2's labelling
    (:func:`label_runs`), the gate (:func:`gate_mask`) and eq. 11 (:func:`_centroid`).

    ``gate``: (min area px, max area px, max aspect, min fill) of ``BlobGate``. Returns (kept
    (k, 5) int64 x, y, w, h, area in image px; their (k, 4) float64 u px, v px, mass, peak;
    the first ``max_rejected`` rejected (x, y, w, h, area) rows; the number of components
    passing the gate; their (k, ``OUT_COLUMNS``) local centroids). Boxes in order, components
    in raster order within a box. Past ``max_blobs`` kept components nothing more is kept
    (the frame is refused). ``local_params`` not empty (the local centroid's parameters):
    each kept blob's local centroid is measured here (``local_centroids(gray, kept[:, :4],
    local_params)``, the same rows) and eq. 11 only where that is not measured (elsewhere u,
    v and mass are NaN); empty: eq. 11 for every blob and no local rows."""
    h, w = gray.shape
    kept = np.empty((max_blobs, 5), np.int64)
    cents = np.empty((max_blobs, 4))
    rejected = np.empty((max_rejected, 5), np.int64)
    local_on = local_params.shape[0] > 0
    local = np.empty((max_blobs if local_on else 0, OUT_COLUMNS))  # (rows written when kept)
    tiles = hot_tile_boxes(gray, bands, band_rows, threshold)
    if tiles.shape[0] == 0:
        return kept[:0], cents[:0], rejected[:0], 0, local[:0]
    boxes = grow_and_merge_boxes(tiles, w, h, ksize // 2 + 2)
    # the pixels ≥ T of each box lie in the tile boxes inside it (boxes do not overlap)
    bright = np.empty((boxes.shape[0], 4), np.int64)
    bright[:, 0:2] = np.int64(1) << 40
    bright[:, 2:4] = -1
    for t in range(tiles.shape[0]):
        for b in range(boxes.shape[0]):
            if (
                boxes[b, 0] <= tiles[t, 0]
                and boxes[b, 1] <= tiles[t, 1]
                and tiles[t, 2] <= boxes[b, 2]
                and tiles[t, 3] <= boxes[b, 3]
            ):
                bright[b, 0] = min(bright[b, 0], tiles[t, 0])
                bright[b, 1] = min(bright[b, 1], tiles[t, 1])
                bright[b, 2] = max(bright[b, 2], tiles[t, 2])
                bright[b, 3] = max(bright[b, 3], tiles[t, 3])
                break
    # scratch for the largest box (and the largest centroid window inside it)
    big_area = big_side = 0
    for b in range(boxes.shape[0]):
        bw, bh = boxes[b, 2] - boxes[b, 0], boxes[b, 3] - boxes[b, 1]
        big_area = max(big_area, bw * bh)
        big_side = max(big_side, max(bw, bh) + 2 * centroid_margin_px(bw * bh))
    runs = np.empty((big_area, 3), np.int64)
    label_buf = np.empty(big_area, np.int32)
    horiz_buf = np.empty((big_side, big_side), np.uint8)
    comp_row = np.empty(big_side, np.uint8)
    cover = np.empty(big_side, np.int32)
    counts = np.zeros(3, np.int64)  # kept, rejected, all passing the gate
    # the local centroid's scratch (a component's box lies in its box) and its parameters
    big_local = 0
    if local_on:
        for b in range(boxes.shape[0]):
            cells = scratch_cells(boxes[b, 2] - boxes[b, 0], boxes[b, 3] - boxes[b, 1])
            big_local = max(big_local, cells)
    local_scratch = scratch(big_local)
    lparams = local_params.copy()
    for b in range(boxes.shape[0]):
        x0, y0 = boxes[b, 0], boxes[b, 1]
        bw, bh = boxes[b, 2] - x0, boxes[b, 3] - y0
        # (the rows beyond the bright tiles' are read first here: their misses overlapped)
        x0 += touch_rows(gray, x0, y0, x0 + bw, y0 + bh) >> 62
        count = median_runs(gray, boxes[b], bright[b], threshold, ksize // 2, runs)
        if count == 0:
            continue
        labels = label_buf[: bh * bw].reshape(bh, bw)
        labels[:] = 0
        st = label_runs(runs[:count], labels)
        _keep_components(
            gray, labels, st, x0, y0, background, gate, kept, cents, rejected, counts,
            (horiz_buf, comp_row, cover), lparams, local, local_scratch,
        )  # fmt: skip
    n_kept, n_rej, total = counts[0], counts[1], counts[2]
    return (
        kept[:n_kept],
        cents[:n_kept],
        rejected[:n_rej],
        total,
        local[: n_kept if local_on else 0],
    )


@njit(cache=True, nogil=True)
def window_blobs(
    gray: np.ndarray,
    wins: np.ndarray,
    thresholds: np.ndarray,
    backgrounds: np.ndarray,
    ksize: int,
    gate: np.ndarray,
    local_params: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """A tracker's windows: for each square window (x0, y0, side; px of ``gray``) with its
    eq. 10 threshold and background, the pixels ≥ T, the median filter around them
    (:func:`median_runs`; the window's edge replicated), the labelling (:func:`label_runs`),
    the gate (``gate`` as in :func:`detect_in_boxes`) and eq. 11 of the components that do not
    touch the window's edge (a component cut by the edge belongs to a neighbour or moved out).

    Returns (count (k,) of such components per window, the first one's (k, 5) int64 x, y, w,
    h, area and (k, 4) float64 u px, v px, mass, peak in ``gray`` px, and its (k,
    ``OUT_COLUMNS``) local centroid). Only a box around each window's pixels ≥ T (grown by
    the centroid margin, as the acquisition's boxes) is labelled, so the labels, the supports
    and the centroids are those of the whole window. ``local_params`` as in
    :func:`detect_in_boxes`: the local centroid measured first (on ``gray``), eq. 11 only
    where it is not (elsewhere u, v and mass NaN); empty: eq. 11 only, local rows NaN."""
    h, w = gray.shape
    k_all = wins.shape[0]
    counts = np.zeros(k_all, np.int64)
    stats = np.zeros((k_all, 5), np.int64)
    cents = np.zeros((k_all, 4))
    local = np.full((k_all, OUT_COLUMNS), np.nan)
    local_on = local_params.shape[0] > 0
    lparams = local_params.copy()
    big_local = 0
    if local_on:
        for k in range(k_all):
            big_local = max(big_local, scratch_cells(wins[k, 2], wins[k, 2]))
    local_scratch = scratch(big_local)
    r = ksize // 2
    big = 0
    for k in range(k_all):
        big = max(big, wins[k, 2])
    big_side = big + 2 * centroid_margin_px(big * big)
    runs = np.empty((big * big, 3), np.int64)
    label_buf = np.empty(big * big, np.int32)
    horiz_buf = np.empty((big_side, big_side), np.uint8)
    comp_row = np.empty(big_side, np.uint8)
    cover = np.empty(big_side, np.int32)
    bright = np.empty(4, np.int64)
    box = np.empty(4, np.int64)
    rect = np.empty(4, np.int64)
    cand = np.empty(CAND_COLUMNS, np.int64)
    for k in range(k_all):
        x0, y0, side = wins[k, 0], wins[k, 1], wins[k, 2]
        x1, y1 = x0 + side, y0 + side
        thr = thresholds[k]
        rect[0], rect[1], rect[2], rect[3] = x0, y0, x1, y1
        if not bright_box(gray, rect, thr, bright):
            continue
        m = grow_margin_px((bright[2] - bright[0]) * (bright[3] - bright[1]), r + 2)
        box[0], box[1] = max(x0, bright[0] - m), max(y0, bright[1] - m)
        box[2], box[3] = min(x1, bright[2] + m), min(y1, bright[3] + m)
        count = median_runs(gray, box, bright, thr, r, runs)
        if count == 0:
            continue
        bw, bh = box[2] - box[0], box[3] - box[1]
        labels = label_buf[: bh * bw].reshape(bh, bw)
        labels[:] = 0
        st = label_runs(runs[:count], labels)[1:]
        for c in range(st.shape[0]):
            st[c, 0] += box[0]
            st[c, 1] += box[1]
        ok = gate_mask(st, w, h, int(gate[0]), int(gate[1]), gate[2], gate[3])
        for c in range(st.shape[0]):
            sx, sy, sw, sh = st[c, 0], st[c, 1], st[c, 2], st[c, 3]
            if not ok[c] or sx <= x0 or sy <= y0 or sx + sw >= x1 or sy + sh >= y1:
                continue
            counts[k] += 1
            if counts[k] > 1:
                continue
            cand[0] = c + 1
            cand[1:6] = st[c]
            cand[6], cand[7], cand[8], cand[9] = 0, 0, bw, bh
            cand[10], cand[11] = box[0], box[1]
            stats[k] = st[c]
            _blob_centroid(gray, labels, cand, backgrounds[k], (horiz_buf, comp_row, cover),
                           cents[k], lparams, local[k], local_scratch)  # fmt: skip
    return counts, stats, cents, local
