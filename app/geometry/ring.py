"""Find the drogue's LED ring among triangulated points, with an integrity test (paper §5.2).

The LEDs sit on evenly spaced *slots* of a circle of known radius R. Every candidate point is
considered (no cap):

1. **Pairs** — two LEDs are a chord 2R·sin(πk/N) apart (k = 1..⌊N/2⌋); a table of pairwise
   distances keeps only pairs at a chord length (within the depth-dependent tolerances).
2. **Seeds** — triples whose three pairs are all chords, whose circumcircle has the expected
   radius, faces the cameras and puts the three points on distinct, evenly spaced slots.
3. **Hypotheses** — each seed is refined: plane + circle fit, slot offset, and *slot
   assignment* (one point per slot: the on-circle point nearest the slot's angle, never one
   that fits the slot worse than the point it displaces), iterated until stable.
4. **Integrity** — each hypothesis gets an a-contrario number of false alarms (NFA): the expected
   number of m-point configurations that would fit as well among the n candidates if the
   candidates were unrelated points spread over their bounding volume. The best hypothesis is
   locked only if its NFA is small (stricter with 3 LEDs), no competing hypothesis fits nearly
   as well ("ambiguous"), and the ring does not carry extra points off its slots (a ring of a
   different LED count).

Steps 1–3 run in two compiled loops per frame (:func:`seed_kernel`, :func:`refine_kernel`;
numba, cached on disk); the numpy formulation of each step (:func:`_compatible_pairs`,
:func:`_seed_triples`, :func:`_circumcircles`, :func:`_seed_slots`, :func:`_fit_hypothesis`) is
kept as their reference and gives the same seeds, in the same order, and the same hypotheses.

Slot angles are measured clockwise from the camera's up direction (−y) projected on the ring
plane (:func:`app.geometry.circle_fit.plane_basis`); ids are assigned from the slot offset by
:mod:`app.geometry.led_ids`.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from itertools import combinations
from typing import Any

import numpy as np
from numba import njit

from app.geometry.calibration import FloatArray
from app.geometry.circle_fit import (
    Circle3D,
    FitError,
    circle_kernel,
    circle_points,
    distance_kernel,
    distance_to_circle,
    fit_circle_3d,
    plane_axes,
    run_circle_fit,
)

MAX_SEEDS = 20_000  # refinement budget; seeds are ordered by fit quality (never reached in tests)


@dataclass(frozen=True)
class RingParams:
    """The ring we look for and the tolerances (mm, deg).

    Tolerances grow with the depth noise σ_Z(z) = depth_sigma_per_mm · z² (mm), the stereo
    depth noise for a disparity noise σ_d: σ_Z = z²σ_d/(f·B).
    """

    radius_mm: float = 75.0
    led_count: int = 5
    radius_tol_frac: float = 0.1  # |fitted − R| ≤ frac·R + 2σ_Z
    inlier_tol_mm: float = 2.0  # floor of the distance from the circle (mm); ≥ 4σ_Z
    angle_tol_deg: float = 2.0  # floor of the slot residual (deg); ≥ 2.5σ_Z/R
    max_angle_tol_deg: float = 12.0
    depth_sigma_per_mm: float = 0.0  # σ_Z / z² (1/mm); 0 → the floors only
    min_leds: int = 3
    max_view_angle_deg: float = 85.0  # ring normal vs line of sight (edge-on limit)
    log10_nfa_max: float = -2.0  # lock only if NFA ≤ 10^this
    three_led_log10_margin: float = 1.0  # with 3 LEDs: NFA ≤ 10^(max − margin) (no prior)
    ambiguity_log10: float = 2.0  # a competitor within this many decades of NFA is "as good"
    max_extra_on_ring: int = 2  # more on-circle points off the slots → wrong led_count
    fov_tan: tuple[float, float] | None = None  # (width/fx, height/fy): the cameras' field

    # each takes one range (float: a float back, in scalar arithmetic) or an array of ranges

    def sigma_z(self, z_mm: Any) -> Any:
        if isinstance(z_mm, float):
            return self.depth_sigma_per_mm * (z_mm * z_mm)
        return np.asarray(self.depth_sigma_per_mm * np.square(z_mm), dtype=np.float64)

    def inlier_tol(self, z_mm: Any) -> Any:
        if isinstance(z_mm, float):
            return max(self.inlier_tol_mm, 4.0 * self.sigma_z(z_mm))
        return np.maximum(self.inlier_tol_mm, 4.0 * self.sigma_z(z_mm))

    def radius_tol(self, z_mm: Any) -> Any:
        return self.radius_tol_frac * self.radius_mm + 2.0 * self.sigma_z(z_mm)

    def angle_tol_deg_at(self, z_mm: Any) -> Any:
        if isinstance(z_mm, float):
            a = math.degrees(2.5 * self.sigma_z(z_mm) / self.radius_mm)
            return min(max(a, self.angle_tol_deg), self.max_angle_tol_deg)
        a = np.degrees(2.5 * self.sigma_z(z_mm) / self.radius_mm)
        return np.clip(a, self.angle_tol_deg, self.max_angle_tol_deg)


@dataclass(frozen=True)
class RingPrior:
    """A recent lock used to judge 3-LED hypotheses (mm, unit normal)."""

    center_mm: FloatArray
    normal: FloatArray
    gate_mm: float = 30.0
    gate_deg: float = 15.0

    @classmethod
    def at_range(cls, center_mm: FloatArray, normal: FloatArray, params: RingParams) -> RingPrior:
        """A prior whose gates grow with the depth noise at its range: centre 6σ_Z(z) and
        normal 6σ_Z(z)/R rad, at least the defaults (30 mm, 15°). Up to ≈ 3 m with the paper's
        rig the defaults hold; at 10 m σ_Z ≈ 37 mm per frame, which a fixed 30 mm gate would
        take for a jump of the ring."""
        sz = float(params.sigma_z(float(center_mm[2])))
        gate_mm = max(cls.gate_mm, 6.0 * sz)
        gate_deg = max(cls.gate_deg, math.degrees(min(math.pi / 2, 6.0 * sz / params.radius_mm)))
        return cls(np.asarray(center_mm), np.asarray(normal), gate_mm, gate_deg)


@dataclass(frozen=True)
class RingFit:
    circle: Circle3D  # normal oriented from the drogue towards the cameras
    indices: tuple[int, ...]  # input point indices on the ring
    slots: tuple[int, ...]  # slot of each index, 0..N−1 counted from ``offset_deg``
    offset_deg: float  # angle of slot 0, in [0, 360/N), clockwise from the top
    residual_deg: tuple[float, ...]  # angular residual of each point from its slot
    log10_nfa: float  # the a-contrario number of false alarms of this fit (log10)
    candidates: int  # points considered
    hypotheses: int  # distinct hypotheses found


@dataclass(frozen=True)
class RingRejection:
    reason: str


@dataclass
class _Hypothesis:
    members: np.ndarray  # point indices, one per slot
    points: FloatArray  # their coordinates (mm)
    slots: np.ndarray
    resid_deg: np.ndarray
    circle: Circle3D
    offset_deg: float
    cost: float
    angle_tol: float
    inlier_tol: float
    extra_on_ring: int
    distance_mm: FloatArray | None = None  # of each member from the circle
    log10_nfa: float = math.inf


def oriented(circle: Circle3D) -> Circle3D:
    """The circle with its normal pointing towards the cameras at the origin."""
    n = circle.normal
    if float(n @ (-circle.center)) < 0:
        n = -n
    return Circle3D(circle.center, n, circle.radius, circle.rms, circle.plane_rms)


def _cross_rows(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise a × b of (T, 3) arrays (``np.cross`` costs ~5× more on small arrays)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.column_stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _circumcircles(p: FloatArray, triples: np.ndarray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Centre (T,3), unit normal (T,3), radius (T,) of the circle through each triple."""
    p1, p2, p3 = p[triples[:, 0]], p[triples[:, 1]], p[triples[:, 2]]
    a, b = p1 - p3, p2 - p3
    axb = _cross_rows(a, b)
    n2 = np.sum(axb * axb, axis=1)
    ok = n2 > 1e-9
    n2 = np.where(ok, n2, 1.0)
    num = _cross_rows(np.sum(a * a, axis=1)[:, None] * b - np.sum(b * b, axis=1)[:, None] * a, axb)
    center = p3 + num / (2.0 * n2[:, None])
    radius = np.where(ok, np.linalg.norm(center - p3, axis=1), np.inf)
    normal = axb / np.sqrt(n2)[:, None]
    return center, normal, radius


def view_angle_deg(circle: Circle3D) -> float:
    """Angle (deg) between the ring's normal and the line of sight to its centre (0 = head on,
    90 = edge-on)."""
    c = circle.center
    view = -c / max(math.sqrt(float(c @ c)), 1e-9)
    return math.degrees(math.acos(min(1.0, max(-1.0, float(circle.normal @ view)))))


def agrees_with_prior(circle: Circle3D, prior: RingPrior) -> bool:
    """The circle is where the prior lock predicts it (centre and normal within the gates)."""
    d = circle.center - np.asarray(prior.center_mm)
    dc = math.sqrt(float(d @ d))
    cosang = min(1.0, max(-1.0, float(circle.normal @ np.asarray(prior.normal))))
    return dc <= prior.gate_mm and math.degrees(math.acos(cosang)) <= prior.gate_deg


def prior_volume_mm3(params: RingParams, prior: RingPrior) -> float:
    """The neighbourhood a prior lock confines a ring to (mm³): a cube of side 2(R + gate)."""
    return float((2.0 * (params.radius_mm + prior.gate_mm)) ** 3)


@njit(cache=True, nogil=True)
def _slot_angles(
    points: np.ndarray, center: np.ndarray, normal: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    e_up, e_right = plane_axes(normal)
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        rel = points[p] - center
        out[p] = np.degrees(np.arctan2(rel @ e_right, rel @ e_up)) % 360.0
    return out


def slot_angles_deg(points: FloatArray, circle: Circle3D) -> FloatArray:
    """Angle of each point around the ring, clockwise from the top as seen by the cameras."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    center = np.asarray(circle.center, dtype=np.float64)
    return np.asarray(_slot_angles(pts, center, np.asarray(circle.normal, dtype=np.float64)))


@njit(cache=True, nogil=True)
def _slot_offset(angles_deg: np.ndarray, count: int) -> float:  # pragma: no cover - compiled
    ss, cs = 0.0, 0.0
    for a in angles_deg:
        phase = np.radians(a * count)  # one slot period → 2π
        ss += np.sin(phase)
        cs += np.cos(phase)
    return (np.degrees(np.arctan2(ss, cs)) / count) % (360.0 / count)


@njit(cache=True, nogil=True)
def _slot_residuals(
    angles_deg: np.ndarray, offset_deg: float, count: int
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    spacing = 360.0 / count
    slots = np.empty(angles_deg.shape[0], np.int64)
    resid = np.empty(angles_deg.shape[0])
    for i in range(angles_deg.shape[0]):
        k = np.rint((angles_deg[i] - offset_deg) / spacing)
        resid[i] = angles_deg[i] - offset_deg - k * spacing
        slots[i] = int(k) % count
    return slots, resid


def slot_offset_deg(angles_deg: FloatArray, count: int) -> float:
    """Offset of the evenly spaced slot pattern that best fits ``angles_deg``, in [0, 360/N):
    the circular mean of the angles × N (one slot period → 2π), ÷ N."""
    return float(_slot_offset(np.ascontiguousarray(angles_deg, dtype=np.float64), int(count)))


def slot_residuals(
    angles_deg: FloatArray, offset_deg: float, count: int
) -> tuple[np.ndarray, FloatArray]:
    """(slot index 0..N−1, signed residual deg) of each angle for the given slot offset."""
    slots, resid = _slot_residuals(
        np.ascontiguousarray(angles_deg, dtype=np.float64), float(offset_deg), int(count)
    )
    return np.asarray(slots), np.asarray(resid)


@njit(cache=True, nogil=True)
def _ring_measures(
    points: np.ndarray, count: int
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, float, np.ndarray, np.ndarray
]:  # pragma: no cover - compiled
    fit = circle_kernel(points, 10)
    n = points.shape[0]
    if fit[9] != 0.0:
        empty = np.zeros(n)
        return fit, empty, empty, 0.0, np.zeros(n, np.int64), empty
    center, normal = fit[0:3], fit[3:6]
    if normal @ (-center) < 0.0:  # towards the cameras (as ``oriented``)
        fit[3:6] = -normal
        normal = fit[3:6]
    dist = distance_kernel(points, center, normal, fit[6])
    angles = _slot_angles(points, center, normal)
    offset = _slot_offset(angles, count)
    slots, resid = _slot_residuals(angles, offset, count)
    return fit, dist, angles, offset, slots, resid


@dataclass(frozen=True)
class RingMeasures:
    """One ring fit through all the points and where each point sits on it."""

    circle: Circle3D  # normal oriented towards the cameras
    distance_mm: FloatArray  # 3-D distance of each point from the circle
    angles_deg: FloatArray  # slot angle of each point (clockwise from the top)
    offset_deg: float  # best slot offset, [0, 360/N)
    slots: np.ndarray  # slot of each point, 0..N−1
    resid_deg: FloatArray  # signed residual of each point from its slot


def ring_measures(points: FloatArray, count: int) -> RingMeasures:
    """:func:`~app.geometry.circle_fit.fit_circle_3d` (oriented), :func:`distance_to_circle`,
    :func:`slot_angles_deg`, :func:`slot_offset_deg` and :func:`slot_residuals` of ≥ 3 finite
    points in one compiled call (a tracked frame's ring check). Raises ``FitError``."""
    circle, (_, dist, angles, offset, slots, resid) = run_circle_fit(
        _ring_measures, circle_points(points), int(count)
    )
    return RingMeasures(circle, dist, angles, float(offset), slots, resid)


def _compatible_pairs(p: FloatArray, params: RingParams) -> np.ndarray:
    """(n, n) bool: the two points are one chord of the ring apart (within tolerance)."""
    n = len(p)
    R, N = params.radius_mm, params.led_count
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
    z = np.maximum(p[:, None, 2], p[None, :, 2])
    alpha = np.radians(params.angle_tol_deg_at(z))
    rtol = params.radius_tol(z)
    itol = params.inlier_tol(z)
    ok = np.zeros((n, n), dtype=bool)
    for k in range(1, N // 2 + 1):
        s, c = math.sin(math.pi * k / N), math.cos(math.pi * k / N)
        chord = 2.0 * R * s
        tol = 2.0 * rtol * s + 2.0 * R * abs(c) * alpha + 2.0 * itol
        ok |= np.abs(d - chord) <= tol
    np.fill_diagonal(ok, False)
    return ok


def _seed_triples(adj: np.ndarray) -> np.ndarray:
    """All triples i < j < k whose three pairs are compatible, (T, 3)."""
    out = []
    n = len(adj)
    upper = np.triu(adj, 1)
    for i in range(n - 2):
        js = np.flatnonzero(upper[i])
        if len(js) < 2:
            continue
        sub = upper[js][:, js]
        a, b = np.nonzero(sub)
        if len(a):
            out.append(np.column_stack([np.full(len(a), i), js[a], js[b]]))
    return np.vstack(out) if out else np.zeros((0, 3), dtype=np.int64)


def _seed_slots(
    p: FloatArray, triples: np.ndarray, center: FloatArray, normal: FloatArray, count: int
) -> tuple[FloatArray, np.ndarray]:
    """Vectorised slot check of seed triples on their circumcircles: (T, 3) residuals (deg)
    from the best evenly spaced slots, and whether the three slots are distinct (T,)."""
    n = normal * np.where(np.sum(normal * -center, axis=1) < 0, -1.0, 1.0)[:, None]
    up = np.array([0.0, -1.0, 0.0])
    e_up = up[None, :] - (n @ up)[:, None] * n
    e_up /= np.maximum(np.linalg.norm(e_up, axis=1), 1e-12)[:, None]
    e_right = _cross_rows(e_up, n)
    rel = p[triples] - center[:, None, :]
    ang = np.degrees(
        np.arctan2(np.einsum("tkj,tj->tk", rel, e_right), np.einsum("tkj,tj->tk", rel, e_up))
    )
    spacing = 360.0 / count
    off = np.degrees(np.angle(np.mean(np.exp(1j * np.radians(ang * count)), axis=1))) / count
    k = np.rint((ang - off[:, None]) / spacing)
    res = ang - off[:, None] - k * spacing
    sl = np.mod(k, count)
    distinct = (sl[:, 0] != sl[:, 1]) & (sl[:, 0] != sl[:, 2]) & (sl[:, 1] != sl[:, 2])
    return res, distinct


def _fit_hypothesis(p: FloatArray, members: np.ndarray, params: RingParams) -> _Hypothesis | None:
    """Refine a seed: circle fit, slot offset, slot assignment over all points; iterate (the
    reference of :func:`hypothesis_kernel`)."""
    N = params.led_count
    current = np.sort(members)
    for _ in range(4):
        try:
            circle = oriented(fit_circle_3d(p[current]))
        except FitError:
            return None
        z = float(circle.center[2])
        itol, atol = float(params.inlier_tol(z)), float(params.angle_tol_deg_at(z))
        angles_m = slot_angles_deg(p[current], circle)
        offset = slot_offset_deg(angles_m, N)
        dist = distance_to_circle(p, circle)
        near = np.flatnonzero(dist <= itol)
        angles = slot_angles_deg(p[near], circle)
        slots, resid = slot_residuals(angles, offset, N)
        chosen: dict[int, int] = {}
        for j, (s, r) in enumerate(zip(slots, resid, strict=True)):
            if abs(r) > atol:
                continue
            if s not in chosen or abs(r) < abs(resid[chosen[s]]):
                chosen[int(s)] = j
        new = np.sort(near[list(chosen.values())]) if chosen else np.zeros(0, dtype=np.int64)
        if len(new) < 3:
            return None
        if np.array_equal(new, current):
            break
        current = new
    sel = [j for j in range(len(near)) if near[j] in set(current.tolist())]
    m_slots, m_resid = slots[sel], resid[sel]
    order = np.argsort(near[sel])
    members_sorted = near[sel][order]
    d_m = dist[members_sorted]
    cost = float(np.sum((d_m / itol) ** 2) + np.sum((m_resid[order] / atol) ** 2))
    extra = int(len(near) - len(sel))
    # the fit must still be the ring we look for
    if abs(circle.radius - params.radius_mm) > float(params.radius_tol(z)):
        return None
    if circle.rms > itol:
        return None
    if view_angle_deg(circle) > params.max_view_angle_deg:
        return None
    return _Hypothesis(
        members=members_sorted,
        points=p[members_sorted],
        slots=m_slots[order],
        resid_deg=m_resid[order],
        circle=circle,
        offset_deg=offset,
        cost=cost,
        angle_tol=atol,
        inlier_tol=itol,
        extra_on_ring=extra,
        distance_mm=d_m,
    )


# ---- compiled seed search and refinement (the formulations above are their reference) ----

_DEG = 180.0 / math.pi  # np.degrees' factor
_RAD = math.pi / 180.0  # np.radians' factor


def _ring_consts(params: RingParams) -> FloatArray:
    """The ring and its tolerances as the compiled loops take them, 8 floats: radius (mm), LED
    count, radius_tol_frac, inlier_tol_mm, angle_tol_deg, max_angle_tol_deg,
    depth_sigma_per_mm (1/mm), max_view_angle_deg."""
    return np.array(
        [
            params.radius_mm,
            params.led_count,
            params.radius_tol_frac,
            params.inlier_tol_mm,
            params.angle_tol_deg,
            params.max_angle_tol_deg,
            params.depth_sigma_per_mm,
            params.max_view_angle_deg,
        ],
        dtype=np.float64,
    )


@njit(cache=True, nogil=True)
def _unpack(
    rp: np.ndarray,
) -> tuple[float, int, float, float, float, float, float, float]:  # pragma: no cover - compiled
    """:func:`_ring_consts`' array as (radius, count, radius_tol_frac, inlier_tol, angle_tol,
    max_angle_tol, depth_sigma_per_mm, max_view_deg)."""
    return rp[0], int(rp[1]), rp[2], rp[3], rp[4], rp[5], rp[6], rp[7]


@njit(cache=True, nogil=True)
def _angle_tol_at(
    z: float, radius: float, angle_tol: float, max_angle_tol: float, dsig: float
) -> float:  # pragma: no cover - compiled
    """:meth:`RingParams.angle_tol_deg_at` (deg) at range z (mm)."""
    a = (2.5 * (dsig * (z * z)) / radius) * _DEG
    return min(max(a, angle_tol), max_angle_tol)


@njit(cache=True, nogil=True)
def _circumcircle(p: np.ndarray, i: int, j: int, k: int) -> np.ndarray:  # pragma: no cover
    """:func:`_circumcircles` of one triple (same arithmetic): centre (3), unit normal (3),
    radius (∞ for collinear points), mm."""
    p1, p2, p3 = p[i], p[j], p[k]
    a0, a1, a2 = p1[0] - p3[0], p1[1] - p3[1], p1[2] - p3[2]
    b0, b1, b2 = p2[0] - p3[0], p2[1] - p3[1], p2[2] - p3[2]
    x0, x1, x2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    n2 = x0 * x0 + x1 * x1 + x2 * x2
    out = np.empty(7)
    if not n2 > 1e-9:  # collinear: no circle
        out[:] = 0.0
        out[6] = np.inf
        return out
    aa, bb = a0 * a0 + a1 * a1 + a2 * a2, b0 * b0 + b1 * b1 + b2 * b2
    u0, u1, u2 = aa * b0 - bb * a0, aa * b1 - bb * a1, aa * b2 - bb * a2
    out[0] = p3[0] + (u1 * x2 - u2 * x1) / (2.0 * n2)
    out[1] = p3[1] + (u2 * x0 - u0 * x2) / (2.0 * n2)
    out[2] = p3[2] + (u0 * x1 - u1 * x0) / (2.0 * n2)
    r0, r1, r2 = out[0] - p3[0], out[1] - p3[1], out[2] - p3[2]
    nn = np.sqrt(n2)
    out[3], out[4], out[5] = x0 / nn, x1 / nn, x2 / nn
    out[6] = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    return out


@njit(cache=True, nogil=True)
def seed_kernel(
    p: np.ndarray, rp: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Steps 1–2 of the module docstring in one loop: the chord-compatible triples i < j < k
    (T, 3) in lexicographic order (as :func:`_seed_triples` of :func:`_compatible_pairs`), and
    the rows of those that are seeds (circumcircle of the ring's radius, three distinct evenly
    spaced slots: :func:`_circumcircles`, :func:`_seed_slots`), best slot fit first (stable), with
    their sums of squared slot residuals (deg²). ``rp``: :func:`_ring_consts`."""
    radius, count, rtol_frac, inlier_tol, angle_tol, max_angle_tol, dsig, max_view_deg = _unpack(rp)
    n = p.shape[0]
    adj = np.zeros((n, n), np.bool_)
    half = count // 2
    sin_k, cos_k = np.empty(half + 1), np.empty(half + 1)  # of half the angle between slots
    for k in range(1, half + 1):
        sin_k[k], cos_k[k] = math.sin(math.pi * k / count), math.cos(math.pi * k / count)
    for i in range(n):
        for j in range(i + 1, n):
            d0, d1, d2 = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2]
            d = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            z = max(p[i, 2], p[j, 2])
            sz = dsig * (z * z)
            alpha = _angle_tol_at(z, radius, angle_tol, max_angle_tol, dsig) * _RAD
            rtol = rtol_frac * radius + 2.0 * sz
            itol = max(inlier_tol, 4.0 * sz)
            for k in range(1, half + 1):
                s, c = sin_k[k], cos_k[k]
                tol = 2.0 * rtol * s + 2.0 * radius * abs(c) * alpha + 2.0 * itol
                if abs(d - 2.0 * radius * s) <= tol:
                    adj[i, j] = True
                    adj[j, i] = True
                    break
    total = 0
    for i in range(n):
        for j in range(i + 1, n):
            if adj[i, j]:
                for k in range(j + 1, n):
                    if adj[i, k] and adj[j, k]:
                        total += 1
    triples = np.empty((total, 3), np.int64)
    t = 0
    for i in range(n):
        for j in range(i + 1, n):
            if adj[i, j]:
                for k in range(j + 1, n):
                    if adj[i, k] and adj[j, k]:
                        triples[t, 0], triples[t, 1], triples[t, 2] = i, j, k
                        t += 1
    rows = np.empty(total, np.int64)
    keys = np.empty(total)
    spacing = 360.0 / count
    ang = np.empty(3)
    s_count = 0
    for t in range(total):
        circ = _circumcircle(p, triples[t, 0], triples[t, 1], triples[t, 2])
        c0, c1, c2, n0, n1, nz, r = circ[0], circ[1], circ[2], circ[3], circ[4], circ[5], circ[6]
        if not abs(r - radius) <= rtol_frac * radius + 2.0 * (dsig * (c2 * c2)):
            continue  # not the ring's radius (or no circle: r = ∞)
        # the seed's slots on its circumcircle (normal towards the cameras)
        if n0 * -c0 + n1 * -c1 + nz * -c2 < 0:
            n0, n1, nz = -n0, -n1, -nz
        m = -n1  # n · (0, −1, 0)
        e0, e1, e2 = 0.0 - m * n0, -1.0 - m * n1, 0.0 - m * nz
        en = max(np.sqrt(e0 * e0 + e1 * e1 + e2 * e2), 1e-12)
        e0, e1, e2 = e0 / en, e1 / en, e2 / en
        f0, f1, f2 = e1 * nz - e2 * n1, e2 * n0 - e0 * nz, e0 * n1 - e1 * n0
        ss, cs = 0.0, 0.0
        for q in range(3):
            pq = p[triples[t, q]]
            q0, q1, q2 = pq[0] - c0, pq[1] - c1, pq[2] - c2
            ang[q] = math.atan2(q0 * f0 + q1 * f1 + q2 * f2, q0 * e0 + q1 * e1 + q2 * e2) * _DEG
            phase = ang[q] * count * _RAD
            cs += math.cos(phase)
            ss += math.sin(phase)
        off = math.atan2(ss * (1.0 / 3.0), cs * (1.0 / 3.0)) * _DEG / count  # as np.mean
        limit = 1.5 * _angle_tol_at(c2, radius, angle_tol, max_angle_tol, dsig)
        key = 0.0
        slot = np.empty(3, np.int64)
        fits = True
        for q in range(3):
            k = np.rint((ang[q] - off) / spacing)
            res = ang[q] - off - k * spacing
            slot[q] = int(k) % count
            fits = fits and abs(res) <= limit
            key += res * res
        if fits and slot[0] != slot[1] and slot[0] != slot[2] and slot[1] != slot[2]:
            rows[s_count] = t
            keys[s_count] = key
            s_count += 1
    order = np.argsort(keys[:s_count], kind="mergesort")
    return triples, rows[:s_count][order], keys[:s_count][order]


@njit(cache=True, nogil=True)
def _fit_members(pts: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`circle_kernel` (10 iterations) with the normal towards the cameras (as
    :func:`oriented`); status (index 9) 1 when there is no finite circle (``FitError``)."""
    try:
        fit = circle_kernel(pts, 10)
    except Exception:  # a singular circle system
        fit = np.zeros(10)
        fit[9] = 1.0
        return fit
    for q in range(10):
        if not np.isfinite(fit[q]):
            fit[9] = 1.0
    if fit[9] == 0.0 and fit[3:6] @ (-fit[0:3]) < 0.0:
        fit[3:6] = -fit[3:6]
    return fit


@njit(cache=True, nogil=True)
def hypothesis_kernel(
    p: np.ndarray, seed: np.ndarray, rp: np.ndarray
) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Step 3 for one seed, the arithmetic of :func:`_fit_hypothesis`: (found, members (sorted
    point indices), their slots, residuals (deg), distances from the circle (mm), and 16
    floats: the oriented fit (10, as :func:`circle_kernel`), offset (deg), cost, angle
    tolerance (deg), inlier tolerance (mm), points on the circle off the slots, range z)."""
    radius, count, rtol_frac, inlier_tol, angle_tol, max_angle_tol, dsig, max_view_deg = _unpack(rp)
    n = p.shape[0]
    info = np.zeros(16)
    no = np.zeros(0, np.int64)
    nof = np.zeros(0)
    current = np.sort(seed)
    fit = np.zeros(10)
    dist = np.zeros(n)
    near = no
    slots = no
    resid = nof
    offset, itol, atol, z = 0.0, 0.0, 0.0, 0.0
    for _ in range(4):
        fit = _fit_members(p[current])
        if fit[9] != 0.0:
            return False, no, no, nof, nof, info
        center, normal = fit[0:3], fit[3:6]
        z = fit[2]
        sz = dsig * (z * z)
        itol = max(inlier_tol, 4.0 * sz)
        atol = _angle_tol_at(z, radius, angle_tol, max_angle_tol, dsig)
        offset = _slot_offset(_slot_angles(p[current], center, normal), count)
        dist = distance_kernel(p, center, normal, fit[6])
        near = np.flatnonzero(dist <= itol)
        slots, resid = _slot_residuals(_slot_angles(p[near], center, normal), offset, count)
        chosen = np.full(count, -1, np.int64)  # the near point taken by each slot
        for j in range(near.shape[0]):
            s, r = slots[j], resid[j]
            if abs(r) > atol:
                continue
            if chosen[s] < 0 or abs(r) < abs(resid[chosen[s]]):
                chosen[s] = j
        new = np.sort(near[chosen[chosen >= 0]])
        if new.shape[0] < 3:
            return False, no, no, nof, nof, info
        same = new.shape[0] == current.shape[0]
        if same:
            for q in range(new.shape[0]):
                same = same and new[q] == current[q]
        current = new
        if same:
            break
    sel = np.zeros(near.shape[0], np.bool_)
    q = 0
    for j in range(near.shape[0]):  # near and current are both ascending
        while q < current.shape[0] and current[q] < near[j]:
            q += 1
        sel[j] = q < current.shape[0] and current[q] == near[j]
    members = near[sel]
    m_slots, m_resid = slots[sel], resid[sel]
    d_m = dist[members]
    cost_d, cost_a = 0.0, 0.0
    for q in range(members.shape[0]):
        cost_d += (d_m[q] / itol) ** 2
        cost_a += (m_resid[q] / atol) ** 2
    # the fit must still be the ring we look for
    if abs(fit[6] - radius) > rtol_frac * radius + 2.0 * (dsig * (z * z)) or fit[7] > itol:
        return False, no, no, nof, nof, info
    c = fit[0:3]
    view = -c / max(math.sqrt(c @ c), 1e-9)
    if math.acos(min(1.0, max(-1.0, float(fit[3:6] @ view)))) * _DEG > max_view_deg:
        return False, no, no, nof, nof, info
    info[0:10] = fit
    info[10], info[11], info[12], info[13] = offset, cost_d + cost_a, atol, itol
    info[14], info[15] = near.shape[0] - members.shape[0], z
    return True, members, m_slots, m_resid, d_m, info


@njit(cache=True, nogil=True)
def refine_kernel(
    p: np.ndarray, triples: np.ndarray, seeds: np.ndarray, rp: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Step 3 over the seeds in order (the loop of :func:`find_ring`): a seed whose three points
    all belong to a hypothesis already found is skipped, a hypothesis found twice is kept once.
    Per distinct hypothesis (H rows, N = ``count`` columns, padded with −1 / 0): members,
    slots, residuals (deg), distances (mm), and :func:`hypothesis_kernel`'s 16 floats."""
    count = int(rp[1])
    cap = seeds.shape[0]  # each seed adds at most one hypothesis
    members = np.full((cap, count), -1, np.int64)
    slots = np.full((cap, count), -1, np.int64)
    resid = np.zeros((cap, count))
    dist = np.zeros((cap, count))
    info = np.zeros((cap, 16))
    h = 0
    for t in seeds:
        covered = False
        for g in range(h):
            inside = 0
            for q in range(count):
                v = members[g, q]
                inside += v == triples[t, 0] or v == triples[t, 1] or v == triples[t, 2]
            if inside == 3:
                covered = True
                break
        if covered:
            continue  # already explained by a refined hypothesis
        found, mem, sl, rs, dm, inf = hypothesis_kernel(p, triples[t], rp)
        if not found:
            continue
        m = mem.shape[0]
        seen = False
        for g in range(h):
            same = members[g, m - 1] >= 0 and (m == count or members[g, m] < 0)
            for q in range(m):
                same = same and members[g, q] == mem[q]
            if same:
                seen = True
                break
        if seen:
            continue
        members[h, :m], slots[h, :m], resid[h, :m], dist[h, :m] = mem, sl, rs, dm
        info[h] = inf
        h += 1
    return members[:h], slots[:h], resid[:h], dist[:h], info[:h]


def _seeds_reference(
    p: FloatArray, params: RingParams
) -> tuple[np.ndarray, np.ndarray, FloatArray]:
    """:func:`seed_kernel`'s result with the numpy formulation (the reference of the tests)."""
    triples = _seed_triples(_compatible_pairs(p, params))
    if len(triples) == 0:
        return triples, np.zeros(0, np.int64), np.zeros(0)
    c, nrm, r = _circumcircles(p, triples)
    z = c[:, 2]
    t_idx = np.flatnonzero(np.abs(r - params.radius_mm) <= params.radius_tol(z))
    res, distinct = _seed_slots(p, triples[t_idx], c[t_idx], nrm[t_idx], params.led_count)
    ok = distinct & (np.max(np.abs(res), axis=1) <= 1.5 * params.angle_tol_deg_at(z[t_idx]))
    keys = np.sum(res[ok] ** 2, axis=1)
    order = np.argsort(keys, kind="stable")
    return triples, t_idx[ok][order], keys[order]


def _hypotheses_reference(
    p: FloatArray, triples: np.ndarray, seeds: np.ndarray, params: RingParams
) -> list[_Hypothesis]:
    """:func:`refine_kernel`'s loop with :func:`_fit_hypothesis` (the reference of the tests)."""
    hyps: list[_Hypothesis] = []
    covered: list[set[int]] = []
    seen: set[tuple[int, ...]] = set()
    for t in seeds:
        tri = set(triples[t].tolist())
        if any(tri <= cov for cov in covered):
            continue  # already explained by a refined hypothesis
        h = _fit_hypothesis(p, triples[t], params)
        if h is None:
            continue
        key = tuple(h.members.tolist())
        covered.append(set(key))
        if key in seen:
            continue
        seen.add(key)
        hyps.append(h)
    return hyps


def _log10_comb(n: int, k: int) -> float:
    if k < 0 or k > n:
        return -math.inf
    return (math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1)) / math.log(10)


def log10_nfa(
    n: int,
    volume_mm3: float,
    circle: Circle3D,
    points: FloatArray,
    resid_deg: FloatArray,
    params: RingParams,
    distance_mm: FloatArray | None = None,
) -> float:
    """A-contrario number of false alarms (log10) of an m-point ring among n candidates
    (``distance_mm``: the points' distances from the circle, if already known).

    Background model: n unrelated points uniform in ``volume_mm3``. An m-point fit is tested
    C(n, m)·N!/(N−m)! times (point sets × slot labellings). "As well as this fit" uses the
    hypothesis' own precision ρ (its largest distance from the circle, slot residual and
    radius error, in mm; at least 3σ_Z, the measurement noise): by chance, the 2nd point lands
    at a chord length (a shell 4πc²·2δ), the 3rd on the 1-DOF family of slot positions left by
    the first two (a torus 2πR·πρ²), and every further point in its fixed slot cell (a ball
    of radius ρ).
    """
    R, N = params.radius_mm, params.led_count
    m = len(points)
    if m < 3 or n < m:
        return math.inf
    z = float(circle.center[2])
    floor = max(0.3, 3.0 * float(params.sigma_z(z)))
    dist = distance_to_circle(points, circle) if distance_mm is None else distance_mm
    resid = np.asarray(resid_deg).tolist()
    rho = max(
        floor,
        max(np.asarray(dist).tolist(), default=0.0),
        R * math.radians(max(max(resid), -min(resid))),
    )
    delta = 2.0 * rho + max(floor, abs(circle.radius - R))
    chord = 2.0 * R * math.sin(math.pi * (N // 2) / N)
    v = max(volume_mm3, 1.0)
    p2 = min(1.0, 4.0 * math.pi * chord**2 * 2.0 * delta / v)
    p3 = min(1.0, 2.0 * math.pi * R * math.pi * rho**2 / v)
    p4 = min(1.0, 4.0 / 3.0 * math.pi * rho**3 / v)
    labellings = math.lgamma(N + 1) - math.lgamma(N - m + 1)
    return (
        _log10_comb(n, m)
        + labellings / math.log(10)
        + math.log10(p2)
        + math.log10(p3)
        + (m - 3) * math.log10(p4)
    )


def _volume(p: FloatArray, params: RingParams) -> float:
    """Volume (mm³) over which background points could have fallen: the cameras' field of
    view at the candidates' median depth times their depth spread (if the field is known),
    at least their bounding box; every extent at least 4R."""
    floor = 4.0 * params.radius_mm
    side = np.maximum(p.max(axis=0) - p.min(axis=0), floor)
    volume = float(side.prod())
    if params.fov_tan is not None:
        z = statistics.median(p[:, 2].tolist())
        width = max(params.fov_tan[0] * z, floor)
        height = max(params.fov_tan[1] * z, floor)
        volume = max(volume, width * height * float(side[2]))
    return volume


def _radius_only_count(p: FloatArray, params: RingParams, triples: np.ndarray) -> int:
    """Most points on one circle of the ring's radius (ignoring the slots): diagnosis only.
    Few candidates: every triple; many: the chord-compatible ones."""
    if len(p) <= 30:
        triples = np.array(list(combinations(range(len(p)), 3)), dtype=np.int64).reshape(-1, 3)
    if len(triples) == 0:
        return 0
    c, nrm, r = _circumcircles(p, triples)
    z = c[:, 2]
    ok = np.abs(r - params.radius_mm) <= params.radius_tol(z)
    best = 0
    for t in np.flatnonzero(ok)[:2000]:
        circle = Circle3D(c[t], nrm[t], float(r[t]), 0.0, 0.0)
        cnt = int(np.sum(distance_to_circle(p, circle) <= params.inlier_tol(z[t])))
        best = max(best, cnt)
    return best


def _hypotheses(
    p: FloatArray,
    triples: np.ndarray,
    seeds: np.ndarray,
    params: RingParams,
    consts: FloatArray,
) -> list[_Hypothesis]:
    """The distinct refined hypotheses of the seeds (:func:`refine_kernel`), NFA not yet set."""
    members, slots, resid, dist, info = refine_kernel(p, triples, seeds, consts)
    hyps = []
    for h in range(len(members)):
        m = int(np.count_nonzero(members[h] >= 0))
        fit = info[h]
        circle = Circle3D(
            fit[0:3].copy(), fit[3:6].copy(), float(fit[6]), float(fit[7]), float(fit[8])
        )
        hyps.append(
            _Hypothesis(
                members=members[h, :m],
                points=p[members[h, :m]],
                slots=slots[h, :m],
                resid_deg=resid[h, :m],
                circle=circle,
                offset_deg=float(fit[10]),
                cost=float(fit[11]),
                angle_tol=float(fit[12]),
                inlier_tol=float(fit[13]),
                extra_on_ring=int(fit[14]),
                distance_mm=dist[h, :m],
            )
        )
    return hyps


@njit(cache=True, nogil=True)
def radius_only_kernel(
    p: np.ndarray, triples: np.ndarray, rp: np.ndarray
) -> int:  # pragma: no cover - compiled
    """:func:`_radius_only_count` in one loop: with ≤ 30 points every triple i < j < k (in
    lexicographic order), else ``triples``; the first 2000 circumcircles of the ring's radius;
    the most points within the inlier tolerance of one of them. ``rp``: :func:`_ring_consts`."""
    radius, rtol_frac, inlier_tol, dsig = rp[0], rp[2], rp[3], rp[6]
    n = p.shape[0]
    every = n <= 30
    total = n * (n - 1) * (n - 2) // 6 if every else triples.shape[0]
    i, j, k = 0, 1, 2
    tried, best = 0, 0
    for t in range(total):
        if every:
            if t > 0:  # the next combination
                k += 1
                if k == n:
                    j += 1
                    if j == n - 1:
                        i += 1
                        j = i + 1
                    k = j + 1
        else:
            i, j, k = triples[t, 0], triples[t, 1], triples[t, 2]
        circ = _circumcircle(p, i, j, k)
        sz = dsig * (circ[2] * circ[2])
        if not abs(circ[6] - radius) <= rtol_frac * radius + 2.0 * sz:
            continue
        dist = distance_kernel(p, circ[0:3], circ[3:6], circ[6])
        tol = max(inlier_tol, 4.0 * sz)
        cnt = 0
        for q in range(n):
            cnt += dist[q] <= tol
        best = max(best, cnt)
        tried += 1
        if tried == 2000:
            break
    return best


def find_ring(
    points: FloatArray,
    params: RingParams,
    prior: RingPrior | None = None,
    consistent: Callable[[RingFit], bool] | None = None,
) -> RingFit | RingRejection:
    """Locate the LED ring among ``points`` (N×3, mm, left camera frame) with the integrity
    tests of the module docstring. ``prior``: a recent lock (for 3-LED hypotheses).

    ``consistent``: whether a hypothesis' own residuals agree with the measurement noise (the
    caller's χ² test, :mod:`app.vision.error_bound`). When hypotheses compete ("ambiguous"),
    the one that alone passes it is taken: a ring of sun glints on polished bolts fits the
    slots as well as the LEDs but its specular points triangulate off any circle by far more
    than the centroid noise allows (χ² ≈ 270 for 6 dof against ≈ 1 for the LEDs on the
    held-back optics set). With none or several passing, the frame stays ambiguous."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    index_map = np.flatnonzero(np.isfinite(pts).all(axis=1))
    p = pts[index_map]
    n, N = len(p), params.led_count
    if n < params.min_leds:
        return RingRejection(f"only {n} matched LED(s); need at least {params.min_leds}")
    consts = _ring_consts(params)
    triples, seeds, _ = seed_kernel(p, consts)
    hyps = _hypotheses(p, triples, seeds[:MAX_SEEDS], params, consts) if len(seeds) else []
    if not hyps:
        most = radius_only_kernel(p, triples, consts)
        if most >= 4:
            return RingRejection(
                f"{most} points lie on a ring of radius {params.radius_mm:.0f} mm but not on "
                f"{N} evenly spaced slots: check led_count (the ring may carry a different "
                f"number of LEDs)"
            )
        return RingRejection(
            f"no 3 matched points lie on evenly spaced slots of a ring of radius "
            f"{params.radius_mm:.0f} mm ({n} candidate point(s))"
        )
    volume = _volume(p, params)
    near_prior = -1  # candidates in the prior's neighbourhood (counted when first needed)
    for h in hyps:
        h.log10_nfa = log10_nfa(n, volume, h.circle, h.points, h.resid_deg, params, h.distance_mm)
        if prior is not None and agrees_with_prior(h.circle, prior):
            # a hypothesis predicted by a recent lock is tested only against its neighbourhood
            if near_prior < 0:
                d = np.linalg.norm(p - prior.center_mm, axis=1)
                near_prior = int(np.count_nonzero(d <= params.radius_mm + prior.gate_mm))
            local = log10_nfa(
                near_prior,
                prior_volume_mm3(params, prior),
                h.circle,
                h.points,
                h.resid_deg,
                params,
                h.distance_mm,
            )
            h.log10_nfa = min(h.log10_nfa, local)
    hyps.sort(key=lambda h: (-len(h.members), h.cost))
    best = hyps[0]
    m = len(best.members)
    limit = _nfa_limit(best, params, prior)
    if best.log10_nfa > limit:
        return RingRejection(
            f"not distinctive: a {m}-LED ring fit is expected by chance "
            f"(NFA 10^{best.log10_nfa:.1f} > 10^{limit:.1f}) among {n} candidate points"
        )
    best_set = set(best.members.tolist())
    rivals = [
        h
        for h in hyps[1:]
        if not set(h.members.tolist()) <= best_set
        and h.log10_nfa <= params.log10_nfa_max
        and (
            len(h.members) == m
            or (len(h.members) == m - 1 and h.log10_nfa <= best.log10_nfa + params.ambiguity_log10)
        )
    ]
    if rivals:
        passing = (
            []
            if consistent is None
            else [h for h in [best, *rivals] if consistent(_ring_fit(h, index_map, n, len(hyps)))]
        )
        if len(passing) != 1:
            noise = "" if consistent is None else f"; {len(passing)} consistent with the noise"
            return RingRejection(
                f"ambiguous: {len(rivals) + 1} ring hypotheses fit ({m} and "
                f"{len(rivals[0].members)} LEDs, NFA 10^{best.log10_nfa:.1f} vs "
                f"10^{rivals[0].log10_nfa:.1f}{noise})"
            )
        best = passing[0]
        m = len(best.members)
        limit = _nfa_limit(best, params, prior)
        if best.log10_nfa > limit:
            return RingRejection(
                f"ambiguous: the one ring hypothesis consistent with the noise ({m} LEDs) is "
                f"not distinctive (NFA 10^{best.log10_nfa:.1f} > 10^{limit:.1f})"
            )
    if best.extra_on_ring > params.max_extra_on_ring:
        return RingRejection(
            f"{best.extra_on_ring} points lie on the ring between its {N} LED slots: check "
            f"led_count (the ring may carry a different number of LEDs)"
        )
    if m < params.min_leds:
        return RingRejection(
            f"only {m} point(s) fit an evenly spaced ring of radius {params.radius_mm:.0f} mm; "
            f"need at least {params.min_leds}"
        )
    return _ring_fit(best, index_map, n, len(hyps))


def _nfa_limit(h: _Hypothesis, params: RingParams, prior: RingPrior | None) -> float:
    """The largest log10 NFA a hypothesis may have to be locked: stricter with 3 LEDs unless a
    recent lock predicts it."""
    limit = params.log10_nfa_max
    if len(h.members) == 3 and not (prior is not None and agrees_with_prior(h.circle, prior)):
        limit -= params.three_led_log10_margin
    return limit


def _ring_fit(h: _Hypothesis, index_map: np.ndarray, candidates: int, hypotheses: int) -> RingFit:
    """A hypothesis as a :class:`RingFit` (indices into the caller's points)."""
    return RingFit(
        circle=h.circle,
        indices=tuple(index_map[h.members].tolist()),
        slots=tuple(h.slots.tolist()),
        offset_deg=h.offset_deg,
        residual_deg=tuple(h.resid_deg.tolist()),
        log10_nfa=h.log10_nfa,
        candidates=candidates,
        hypotheses=hypotheses,
    )
