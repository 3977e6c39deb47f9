"""The stereo matcher's compiled loops (numba, cached on disk; paper §4.4, eq. 14).

* :func:`descriptor_kernel` — eq. 14's descriptor distance of every left/right pair, summed
  in numpy's pairwise order (numpy's distances to the bit);
* :func:`epipolar_kernel` — the symmetric point-to-epipolar-line distance (px) of every pair;
* :func:`gated_cost` — our matcher's epipolar/depth gate and the assignment cost inside it.

:mod:`app.vision.matching` wraps them; ``tests/vision/test_matching_kernels.py`` keeps the numpy
formulations they replaced as the reference.
"""

from __future__ import annotations

import numpy as np
from numba import njit

DISJOINT_COST_MAX = 1e3  # a pair's cost bound for the disjoint-gate shortcut (≪ the gate's big)


@njit(cache=True, nogil=True)
def descriptor_kernel(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Eq. 14 for every pair, summed as numpy sums a row (pairwise: eight running partial sums
    combined as a tree, then the remainder), so that the distances are numpy's to the bit.
    The partial sums run over all right descriptors at once (vectorised)."""
    nl, nr, d = a.shape[0], b.shape[0], a.shape[1]
    out = np.empty((nl, nr))
    if d < 8:
        for i in range(nl):
            for j in range(nr):
                s = 0.0
                for k in range(d):
                    t = a[i, k] - b[j, k]
                    s += t * t
                out[i, j] = np.sqrt(s)
        return out
    bt = np.ascontiguousarray(b.T)  # (d, NR)
    acc = np.empty((8, nr))  # the eight partial sums of every right descriptor
    head = d - d % 8
    for i in range(nl):
        for k in range(8):
            aik, bk, ak = a[i, k], bt[k], acc[k]
            for j in range(nr):
                t = aik - bk[j]
                ak[j] = t * t
        for k0 in range(8, head, 8):
            for k in range(8):
                aik, bk, ak = a[i, k0 + k], bt[k0 + k], acc[k]
                for j in range(nr):
                    t = aik - bk[j]
                    ak[j] += t * t
        for j in range(nr):
            s = ((acc[0, j] + acc[1, j]) + (acc[2, j] + acc[3, j])) + (
                (acc[4, j] + acc[5, j]) + (acc[6, j] + acc[7, j])
            )
            for k in range(head, d):
                t = a[i, k] - bt[k, j]
                s += t * t
            out[i, j] = np.sqrt(s)
    return out


@njit(cache=True, nogil=True)
def epipolar_kernel(
    F: np.ndarray, xl: np.ndarray, xr: np.ndarray
) -> np.ndarray:  # pragma: no cover
    out = np.empty((xl.shape[0], xr.shape[0]))
    lr = np.empty((xl.shape[0], 3))  # epipolar lines in the right image, F·x_l
    for i in range(xl.shape[0]):
        for k in range(3):
            lr[i, k] = F[k, 0] * xl[i, 0] + F[k, 1] * xl[i, 1] + F[k, 2]
    for j in range(xr.shape[0]):
        ll = np.empty(3)  # the epipolar line in the left image, Fᵀ·x_r
        for k in range(3):
            ll[k] = F[0, k] * xr[j, 0] + F[1, k] * xr[j, 1] + F[2, k]
        inv_l = 1.0 / np.hypot(ll[0], ll[1])
        for i in range(xl.shape[0]):
            alg = lr[i, 0] * xr[j, 0] + lr[i, 1] * xr[j, 1] + lr[i, 2]  # x_rᵀ F x_l
            out[i, j] = 0.5 * abs(alg) * (1.0 / np.hypot(lr[i, 0], lr[i, 1]) + inv_l)
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def gated_cost(
    desc_dist: np.ndarray,
    epi: np.ndarray,
    depth: np.ndarray,
    tol_px: float,
    z_lo: float,
    z_hi: float,
    big: float,
) -> tuple[np.ndarray, np.ndarray, bool]:  # pragma: no cover - compiled
    """The epipolar/depth gate and the cost ``desc + epi / tol`` inside it (``big`` outside),
    and whether the gated pairs are disjoint (no two share a row or a column) with finite
    costs below ``DISJOINT_COST_MAX``."""
    nl, nr = desc_dist.shape
    gate = np.empty((nl, nr), np.bool_)
    cost = np.empty((nl, nr))
    col_count = np.zeros(nr, np.int64)
    disjoint = True
    for i in range(nl):
        row_count = 0
        for j in range(nr):
            z = depth[i, j]
            g = epi[i, j] <= tol_px and z >= z_lo and z <= z_hi and np.isfinite(z)
            gate[i, j] = g
            if g:
                c = desc_dist[i, j] + epi[i, j] / tol_px
                cost[i, j] = c
                row_count += 1
                col_count[j] += 1
                if row_count > 1 or col_count[j] > 1 or not c < DISJOINT_COST_MAX:
                    disjoint = False
            else:
                cost[i, j] = big
    return gate, cost, disjoint
