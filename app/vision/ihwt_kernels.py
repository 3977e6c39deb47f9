"""The IHWT descriptor's compiled loop (numba, cached on disk; paper §4.3, eqs. 12–13).

:func:`describe_kernel` computes each feature point's 64-D descriptor from the image itself:
eq. 12's integral image over the few px its Haar templates reach, then eq. 13's box sums.
The sums are exact integers, so the descriptor equals
:func:`app.vision.ihwt.describe_points` on the full frame's integral image. The window and
sub-square layout are :mod:`app.vision.ihwt`'s (4×4 sub-squares of 5×5 samples).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from app.vision.bright_region_kernels import touch_rows

DESCRIPTOR_SIZE = 64
SAMPLES_PER_SUBSQUARE = 5


@njit(cache=True, nogil=True)
def describe_kernel(
    gray: np.ndarray, centers: np.ndarray, windows: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`~app.vision.ihwt.describe_points` computed from the image itself: per point, eq. 12's integral
    image over the few px its Haar templates reach only, then eq. 13's box sums (the sums are
    exact integers: the same descriptor as on the full frame's integral image).

    The window's rows are touched once before they are summed: a frame just read from a
    camera is not in the cache, and independent loads let the rows' cache misses overlap
    (summed row after row they come one at a time). The integral image is built from running
    column sums (each row: the column sums, then their prefix), in scratch sized once."""
    h, w = gray.shape
    n = 4 * SAMPLES_PER_SUBSQUARE
    s = SAMPLES_PER_SUBSQUARE
    out = np.zeros((centers.shape[0], DESCRIPTOR_SIZE))
    xs = np.empty((3, n), np.int64)  # clipped corner columns: minus, centre, plus
    ys = np.empty((3, n), np.int64)
    # scratch for the largest point's integral image (grown if a clipped one needs more)
    big_w = big_h = 1
    for p in range(centers.shape[0]):
        win = windows[p]
        step = win / n
        half = max(1, int(np.floor(step + 0.5)))
        ext = int(np.ceil(win)) + 2 * half + 4
        big_w = max(big_w, min(w, ext) + 1)
        big_h = max(big_h, min(h, ext) + 1)
    ii_buf = np.empty(big_w * big_h, np.int64)
    colacc = np.empty(big_w, np.int64)
    desc = np.empty(DESCRIPTOR_SIZE)
    for p in range(centers.shape[0]):
        win = windows[p]
        step = win / n
        half = max(1, int(np.floor(step + 0.5)))
        cu = np.floor(centers[p, 0] + 0.5)
        cv = np.floor(centers[p, 1] + 0.5)
        for k in range(n):
            off = np.floor((k + 0.5) * step - win / 2.0 + 0.5)
            x, y = int(cu + off), int(cv + off)
            xs[0, k], xs[1, k], xs[2, k] = x - half, x, x + half
            ys[0, k], ys[1, k], ys[2, k] = y - half, y, y + half
        for k in range(n):
            for d in range(3):
                xs[d, k] = min(max(xs[d, k], 0), w)
                ys[d, k] = min(max(ys[d, k], 0), h)
        x_lo, x_hi, y_lo, y_hi = xs[0, 0], xs[2, n - 1], ys[0, 0], ys[2, n - 1]
        iw, ih = x_hi - x_lo + 1, y_hi - y_lo + 1
        if iw * ih > ii_buf.shape[0]:
            ii_buf = np.empty(iw * ih, np.int64)
            colacc = np.empty(iw, np.int64)
        ii = ii_buf[: iw * ih].reshape(ih, iw)
        for c in range(iw):
            ii[0, c] = 0
            colacc[c] = 0
        # the window's rows touched first (their cache misses overlapped; 0 added)
        x_lo += touch_rows(gray, x_lo, y_lo, x_hi, y_hi) >> 62
        for r in range(ih - 1):
            g = gray[y_lo + r, x_lo:x_hi]
            for c in range(iw - 1):
                colacc[c] += g[c]
            row = ii[r + 1]
            acc = 0
            row[0] = 0
            for c in range(iw - 1):
                acc += colacc[c]
                row[c + 1] = acc
        for b in range(DESCRIPTOR_SIZE):
            desc[b] = 0.0
        for j in range(n):
            rm, rc, rp = ys[0, j] - y_lo, ys[1, j] - y_lo, ys[2, j] - y_lo
            for i in range(n):
                qm, qc, qp = xs[0, i] - x_lo, xs[1, i] - x_lo, xs[2, i] - x_lo
                mm, mc, mp = ii[rm, qm], ii[rm, qc], ii[rm, qp]
                cm, cp = ii[rc, qm], ii[rc, qp]
                pm, pc, pp = ii[rp, qm], ii[rp, qc], ii[rp, qp]
                dx = (mc + pp - mp - pc) - (mm + pc - mc - pm)  # eq. 13: right − left
                dy = (cm + pp - cp - pm) - (mm + cp - mp - cm)  # bottom − top
                base = ((j // s) * 4 + i // s) * 4
                desc[base] += dx
                desc[base + 1] += abs(dx)
                desc[base + 2] += dy
                desc[base + 3] += abs(dy)
        norm = np.sqrt(np.sum(desc * desc))
        if norm > 0:
            for b in range(DESCRIPTOR_SIZE):
                out[p, b] = desc[b] / norm
        else:
            for b in range(DESCRIPTOR_SIZE):
                out[p, b] = desc[b]
    return out
