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

The per-candidate work runs in compiled loops (:mod:`app.vision.matching_kernels`: descriptor
distances in numpy's summation order, the gate and its cost), so that the results equal the
numpy formulations to the bit (``tests/vision/test_matching_kernels.py`` keeps those as the
reference); ``*_indices`` give the matches as index arrays, :class:`MatchArrays` /
:class:`~app.vision.types.Match` as records.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from app.types import FloatArray, IntArray
from app.vision.matching_kernels import (
    DISJOINT_COST_MAX,
    descriptor_kernel,
    epipolar_kernel,
    gated_cost,
)
from app.vision.types import Match

_BIG = 1e6
_PAIRWISE_BLOCK = 128  # numpy's pairwise-summation block (rows up to this are one block)


def descriptor_distances(desc_left: FloatArray, desc_right: FloatArray) -> FloatArray:
    """Eq. 14 for every pair: (NL, NR) Euclidean distances (compiled loop; equal to the
    numpy formulation ``sqrt(sum((l − r)², axis=-1))`` to the bit)."""
    a = np.ascontiguousarray(desc_left, dtype=np.float64)
    b = np.ascontiguousarray(desc_right, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(f"descriptor arrays of shapes {a.shape} and {b.shape} do not pair")
    if a.shape[1] > _PAIRWISE_BLOCK:  # numpy splits longer rows recursively
        diff = a[:, None, :] - b[None, :, :]
        return np.asarray(np.sqrt(np.sum(diff * diff, axis=-1)))
    return np.asarray(descriptor_kernel(a, b))


def epipolar_distances(F: FloatArray, x_left: FloatArray, x_right: FloatArray) -> FloatArray:
    """Symmetric point-to-epipolar-line distance (px) for every pair, (NL, NR).

    ``x_rᵀ F x_l = 0``; the distance is the mean of d(x_r, F x_l) and d(x_l, Fᵀ x_r)
    (compiled loop).
    """
    fm = np.array(F, dtype=np.float64)  # a writable copy whatever F was (one compiled type)
    xl = np.ascontiguousarray(np.asarray(x_left, dtype=np.float64).reshape(-1, 2))
    xr = np.ascontiguousarray(np.asarray(x_right, dtype=np.float64).reshape(-1, 2))
    return np.asarray(epipolar_kernel(fm, xl, xr))


@dataclass(frozen=True)
class MatchArrays:
    """Stereo matches as arrays: pair k is left blob ``left[k]`` ↔ right blob ``right[k]``,
    with its descriptor distance (eq. 14) and epipolar distance (px)."""

    left: IntArray
    right: IntArray
    descriptor_distance: FloatArray
    epipolar_px: FloatArray

    @classmethod
    def of(
        cls, left: IntArray, right: IntArray, desc_dist: FloatArray, epi: FloatArray
    ) -> MatchArrays:
        """The pairs ``left[k] ↔ right[k]`` of the (NL, NR) distance matrices."""
        return cls(left, right, desc_dist[left, right], epi[left, right])

    def __len__(self) -> int:
        return len(self.left)

    def records(self) -> list[Match]:
        """One :class:`Match` per pair."""
        return [
            Match(left_index=i, right_index=j, descriptor_distance=d, epipolar_px=e)
            for i, j, d, e in zip(
                self.left.tolist(),
                self.right.tolist(),
                self.descriptor_distance.tolist(),
                self.epipolar_px.tolist(),
                strict=True,
            )
        ]


def matches_from_indices(
    left: IntArray, right: IntArray, desc_dist: FloatArray, epi: FloatArray
) -> list[Match]:
    """:class:`Match` records of the index pairs ``left[k] ↔ right[k]``."""
    return MatchArrays.of(left, right, desc_dist, epi).records()


def match_min_distance_indices(desc_dist: FloatArray) -> tuple[IntArray, IntArray]:
    """The paper's matcher as index arrays (left, right): every left FP, in order, with the
    right FP at minimum descriptor distance (the first one on a tie)."""
    nl = desc_dist.shape[0] if desc_dist.size else 0
    right = np.argmin(desc_dist, axis=1) if nl else np.zeros(0, np.int64)
    return np.arange(nl, dtype=np.int64), np.asarray(right, dtype=np.int64)


def match_min_distance(desc_dist: FloatArray, epi: FloatArray) -> list[Match]:
    """The paper's matcher: per left FP, the right FP at minimum descriptor distance."""
    return matches_from_indices(*match_min_distance_indices(desc_dist), desc_dist, epi)


def _median(values: list[float]) -> float:
    """``np.median`` of a few finite values (the middle one, or the mean of the two middle
    ones: the same float), without its overhead."""
    v = sorted(values)
    m = len(v) // 2
    return v[m] if len(v) % 2 else (v[m - 1] + v[m]) / 2.0


def _coherence_bounded(z_lo: float, z_hi: float, depth_coherence: float) -> bool:
    """Whether the depth-coherence term stays below ``DISJOINT_COST_MAX`` for any pair in
    the depth range (|log(z / z_ref)| ≤ log(z_hi / z_lo), z_ref being a gated depth)."""
    if not (0.0 < z_lo <= z_hi and depth_coherence > 0.0):
        return False
    return math.log(z_hi / z_lo) / depth_coherence < DISJOINT_COST_MAX


def _assign(cost: FloatArray, gate: np.ndarray) -> tuple[IntArray, IntArray]:
    rows, cols = linear_sum_assignment(cost)
    ok = gate[rows, cols]
    return np.asarray(rows[ok], dtype=np.int64), np.asarray(cols[ok], dtype=np.int64)


def match_epipolar_indices(
    desc_dist: FloatArray,
    epi: FloatArray,
    depth_mm: FloatArray,
    tol_px: float = 2.0,
    depth_range_mm: tuple[float, float] = (100.0, 50_000.0),
    depth_coherence: float = 0.1,
) -> tuple[IntArray, IntArray]:
    """:func:`match_epipolar` as index arrays (left, right), in increasing left index."""
    if desc_dist.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if epi.shape != desc_dist.shape or depth_mm.shape != desc_dist.shape:
        raise ValueError(
            f"distance matrices of shapes {desc_dist.shape}, {epi.shape}, {depth_mm.shape} "
            "do not pair"
        )
    z_lo, z_hi = float(depth_range_mm[0]), float(depth_range_mm[1])
    gate, cost, disjoint = gated_cost(
        np.ascontiguousarray(desc_dist, dtype=np.float64),
        np.ascontiguousarray(epi, dtype=np.float64),
        np.ascontiguousarray(depth_mm, dtype=np.float64),
        float(tol_px),
        z_lo,
        z_hi,
        _BIG,
    )
    if disjoint and _coherence_bounded(z_lo, z_hi, depth_coherence):
        # No two gated pairs compete and every cost (with the depth term) is far below _BIG:
        # both assignments take every gated pair and each is its row's best (the result of
        # the general path below, without running it).
        rows, cols = np.nonzero(gate)
        return rows.astype(np.int64), cols.astype(np.int64)
    rows, cols = _assign(cost, gate)
    if len(rows) >= 2:
        # depth coherence, on the gated pairs only (the others stay at _BIG)
        z_ref = _median(depth_mm[rows, cols].tolist())
        gl, gr = np.nonzero(gate)
        dev = np.abs(np.log(depth_mm[gl, gr] / z_ref))
        cost[gl, gr] += dev / depth_coherence
        rows, cols = _assign(cost, gate)
    best_for_left = np.argmin(cost, axis=1)
    best_for_right = np.argmin(cost, axis=0)
    # Drop leftovers of the assignment that neither side prefers (mutual consistency).
    keep = (best_for_left[rows] == cols) | (best_for_right[cols] == rows)
    return rows[keep], cols[keep]


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
    left, right = match_epipolar_indices(
        desc_dist, epi, depth_mm, tol_px, depth_range_mm, depth_coherence
    )
    return matches_from_indices(left, right, desc_dist, epi)
