"""The numpy formulation of the ring search's compiled steps (the reference of the tests).

:func:`seeds_reference` gives :func:`~app.geometry.ring.kernels.seed_kernel`'s result,
:func:`hypotheses_reference` :func:`~app.geometry.ring.kernels.refine_kernel`'s loop with
:func:`fit_hypothesis` (:func:`~app.geometry.ring.kernels.hypothesis_kernel`'s arithmetic),
:func:`radius_only_count` :func:`~app.geometry.ring.kernels.radius_only_kernel`'s: the same
seeds, in the same order, and the same hypotheses (``tests/geometry/test_ring_kernels.py``).
"""

from __future__ import annotations

import math
from itertools import combinations

import numpy as np

from app.geometry.circle_fit import Circle3D, FitError, distance_to_circle, fit_circle_3d
from app.geometry.ring import (
    RingHypothesis,
    RingParams,
    oriented,
    slot_angles_deg,
    slot_offset_deg,
    slot_residuals,
    view_angle_deg,
)
from app.types import FloatArray


def cross_rows(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise a × b of (T, 3) arrays (``np.cross`` costs ~5× more on small arrays)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.column_stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def circumcircles(p: FloatArray, triples: np.ndarray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Centre (T,3), unit normal (T,3), radius (T,) of the circle through each triple."""
    p1, p2, p3 = p[triples[:, 0]], p[triples[:, 1]], p[triples[:, 2]]
    a, b = p1 - p3, p2 - p3
    axb = cross_rows(a, b)
    n2 = np.sum(axb * axb, axis=1)
    ok = n2 > 1e-9
    n2 = np.where(ok, n2, 1.0)
    num = cross_rows(np.sum(a * a, axis=1)[:, None] * b - np.sum(b * b, axis=1)[:, None] * a, axb)
    center = p3 + num / (2.0 * n2[:, None])
    radius = np.where(ok, np.linalg.norm(center - p3, axis=1), np.inf)
    normal = axb / np.sqrt(n2)[:, None]
    return center, normal, radius


def compatible_pairs(p: FloatArray, params: RingParams) -> np.ndarray:
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


def seed_triples(adj: np.ndarray) -> np.ndarray:
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


def seed_slots(
    p: FloatArray, triples: np.ndarray, center: FloatArray, normal: FloatArray, count: int
) -> tuple[FloatArray, np.ndarray]:
    """Vectorised slot check of seed triples on their circumcircles: (T, 3) residuals (deg)
    from the best evenly spaced slots, and whether the three slots are distinct (T,)."""
    n = normal * np.where(np.sum(normal * -center, axis=1) < 0, -1.0, 1.0)[:, None]
    up = np.array([0.0, -1.0, 0.0])
    e_up = up[None, :] - (n @ up)[:, None] * n
    e_up /= np.maximum(np.linalg.norm(e_up, axis=1), 1e-12)[:, None]
    e_right = cross_rows(e_up, n)
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


def fit_hypothesis(p: FloatArray, members: np.ndarray, params: RingParams) -> RingHypothesis | None:
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
    return RingHypothesis(
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


def seeds_reference(p: FloatArray, params: RingParams) -> tuple[np.ndarray, np.ndarray, FloatArray]:
    """:func:`seed_kernel`'s result with the numpy formulation (the reference of the tests)."""
    triples = seed_triples(compatible_pairs(p, params))
    if len(triples) == 0:
        return triples, np.zeros(0, np.int64), np.zeros(0)
    c, nrm, r = circumcircles(p, triples)
    z = c[:, 2]
    t_idx = np.flatnonzero(np.abs(r - params.radius_mm) <= params.radius_tol(z))
    res, distinct = seed_slots(p, triples[t_idx], c[t_idx], nrm[t_idx], params.led_count)
    ok = distinct & (np.max(np.abs(res), axis=1) <= 1.5 * params.angle_tol_deg_at(z[t_idx]))
    keys = np.sum(res[ok] ** 2, axis=1)
    order = np.argsort(keys, kind="stable")
    return triples, t_idx[ok][order], keys[order]


def hypotheses_reference(
    p: FloatArray, triples: np.ndarray, seeds: np.ndarray, params: RingParams
) -> list[RingHypothesis]:
    """:func:`refine_kernel`'s loop with :func:`fit_hypothesis` (the reference of the tests)."""
    hyps: list[RingHypothesis] = []
    covered: list[set[int]] = []
    seen: set[tuple[int, ...]] = set()
    for t in seeds:
        tri = set(triples[t].tolist())
        if any(tri <= cov for cov in covered):
            continue  # already explained by a refined hypothesis
        h = fit_hypothesis(p, triples[t], params)
        if h is None:
            continue
        key = tuple(h.members.tolist())
        covered.append(set(key))
        if key in seen:
            continue
        seen.add(key)
        hyps.append(h)
    return hyps


def radius_only_count(p: FloatArray, params: RingParams, triples: np.ndarray) -> int:
    """Most points on one circle of the ring's radius (ignoring the slots): diagnosis only.
    Few candidates: every triple; many: the chord-compatible ones."""
    if len(p) <= 30:
        triples = np.array(list(combinations(range(len(p)), 3)), dtype=np.int64).reshape(-1, 3)
    if len(triples) == 0:
        return 0
    c, nrm, r = circumcircles(p, triples)
    z = c[:, 2]
    ok = np.abs(r - params.radius_mm) <= params.radius_tol(z)
    best = 0
    for t in np.flatnonzero(ok)[:2000]:
        circle = Circle3D(c[t], nrm[t], float(r[t]), 0.0, 0.0)
        cnt = int(np.sum(distance_to_circle(p, circle) <= params.inlier_tol(z[t])))
        best = max(best, cnt)
    return best
