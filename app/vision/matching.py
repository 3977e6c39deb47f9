"""Stereo matching of feature points (paper §4.4) and our gated global assignment.

* :func:`match_min_distance` — the paper: each left FP takes the right FP with the minimum
  Euclidean descriptor distance (eq. 14); no geometric check.
* :func:`match_epipolar` — ours: candidate pairs must lie within ``tol_px`` of each other's
  epipolar lines (undistorted px) and triangulate in front of the rig; the pairing is a global
  one-to-one assignment (``scipy.optimize.linear_sum_assignment``) on descriptor distance plus
  epipolar error, re-run with a depth-coherence term (the LEDs of one ring lie at similar
  depth, which resolves LEDs that share an epipolar line); pairs that neither side prefers
  (assignment leftovers) are dropped (mutual consistency). A pair that violates the epipolar
  gate is never matched.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.optimize import linear_sum_assignment

from app.geometry.calibration import FloatArray
from app.vision.types import Match

_BIG = 1e6


def descriptor_distances(desc_left: FloatArray, desc_right: FloatArray) -> FloatArray:
    """Eq. 14 for every pair: (NL, NR) Euclidean distances."""
    diff = desc_left[:, None, :] - desc_right[None, :, :]
    return np.asarray(np.sqrt(np.sum(diff * diff, axis=-1)))


@njit(cache=True, nogil=True)
def _epipolar_kernel(
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


def epipolar_distances(F: FloatArray, x_left: FloatArray, x_right: FloatArray) -> FloatArray:
    """Symmetric point-to-epipolar-line distance (px) for every pair, (NL, NR).

    ``x_rᵀ F x_l = 0``; the distance is the mean of d(x_r, F x_l) and d(x_l, Fᵀ x_r)
    (compiled loop).
    """
    fm = np.array(F, dtype=np.float64)  # a writable copy whatever F was (one compiled type)
    xl = np.ascontiguousarray(np.asarray(x_left, dtype=np.float64).reshape(-1, 2))
    xr = np.ascontiguousarray(np.asarray(x_right, dtype=np.float64).reshape(-1, 2))
    return np.asarray(_epipolar_kernel(fm, xl, xr))


def _match(i: int, j: int, desc_dist: FloatArray, epi: FloatArray) -> Match:
    return Match(
        left_index=i,
        right_index=j,
        descriptor_distance=float(desc_dist[i, j]),
        epipolar_px=float(epi[i, j]),
    )


def match_min_distance(desc_dist: FloatArray, epi: FloatArray) -> list[Match]:
    """The paper's matcher: per left FP, the right FP at minimum descriptor distance."""
    if desc_dist.size == 0:
        return []
    return [_match(i, int(np.argmin(row)), desc_dist, epi) for i, row in enumerate(desc_dist)]


def _assign(cost: FloatArray, gate: np.ndarray) -> list[tuple[int, int]]:
    c = np.where(gate, cost, _BIG)
    rows, cols = linear_sum_assignment(c)
    return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if gate[i, j]]


def match_epipolar(
    desc_dist: FloatArray,
    epi: FloatArray,
    depth_mm: FloatArray,
    tol_px: float = 2.0,
    depth_range_mm: tuple[float, float] = (100.0, 50_000.0),
    depth_coherence: float = 0.1,
) -> list[Match]:
    """Our matcher (see module docstring). ``depth_mm`` is the (NL, NR) depth of each candidate
    pair's linear triangulation; ``depth_coherence`` is the relative depth deviation that costs
    as much as a unit descriptor distance."""
    if desc_dist.size == 0:
        return []
    gate = (epi <= tol_px) & (depth_mm >= depth_range_mm[0]) & (depth_mm <= depth_range_mm[1])
    gate &= np.isfinite(depth_mm)
    cost = desc_dist + epi / tol_px
    pairs = _assign(cost, gate)
    if len(pairs) >= 2:
        z_ref = float(np.median([depth_mm[i, j] for i, j in pairs]))
        with np.errstate(divide="ignore", invalid="ignore"):
            dev = np.abs(np.log(np.where(gate, depth_mm, z_ref) / z_ref))
        cost = cost + dev / depth_coherence
        pairs = _assign(cost, gate)
    masked = np.where(gate, cost, _BIG)
    best_for_left = np.argmin(masked, axis=1)
    best_for_right = np.argmin(masked, axis=0)
    # Drop leftovers of the assignment that neither side prefers (mutual consistency).
    return [
        _match(i, j, desc_dist, epi)
        for i, j in pairs
        if best_for_left[i] == j or best_for_right[j] == i
    ]
