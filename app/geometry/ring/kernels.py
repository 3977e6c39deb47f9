"""The ring search's compiled loops (numba, cached on disk): seeds, hypotheses, the radius-only
diagnosis and the slot measures of one ring (paper §5.2; steps 1–3 of
:mod:`app.geometry.ring`).

* :func:`seed_kernel` — steps 1–2: chord-compatible pairs, triples, circumcircles of the
  ring's radius, three distinct evenly spaced slots, ordered by slot fit;
* :func:`hypothesis_kernel` / :func:`refine_kernel` — step 3: plane + circle fit, slot offset,
  one point per slot, iterated until stable, for one seed / for all seeds in order;
* :func:`radius_only_kernel` — the refusal's diagnosis: most points on one circle of the
  ring's radius, ignoring the slots;
* :func:`ring_measures_kernel` and the slot-angle loops — one oriented circle fit through
  given points and where each sits on its slots (the tracker's ring check).

Their numpy formulation is the reference of the tests (``tests/support/ring_reference.py``):
the same seeds in the same order and the same hypotheses. Slot angles are measured clockwise
from the camera's up direction (−y) projected on the ring plane
(:func:`app.geometry.circle_fit.plane_axes`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.geometry.circle_fit_kernels import circle_kernel, distance_kernel, plane_axes
from app.geometry.ring.params import RingParams
from app.types import FloatArray

_DEG = 180.0 / math.pi  # np.degrees' factor
_RAD = math.pi / 180.0  # np.radians' factor


def ring_consts(params: RingParams) -> FloatArray:
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
def slot_angles_kernel(
    points: np.ndarray, center: np.ndarray, normal: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    e_up, e_right = plane_axes(normal)
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        rel = points[p] - center
        out[p] = np.degrees(np.arctan2(rel @ e_right, rel @ e_up)) % 360.0
    return out


@njit(cache=True, nogil=True)
def slot_offset_kernel(angles_deg: np.ndarray, count: int) -> float:  # pragma: no cover - compiled
    ss, cs = 0.0, 0.0
    for a in angles_deg:
        phase = np.radians(a * count)  # one slot period → 2π
        ss += np.sin(phase)
        cs += np.cos(phase)
    return (np.degrees(np.arctan2(ss, cs)) / count) % (360.0 / count)


@njit(cache=True, nogil=True)
def slot_residuals_kernel(
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


@njit(cache=True, nogil=True)
def ring_measures_kernel(
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
    angles = slot_angles_kernel(points, center, normal)
    offset = slot_offset_kernel(angles, count)
    slots, resid = slot_residuals_kernel(angles, offset, count)
    return fit, dist, angles, offset, slots, resid


@njit(cache=True, nogil=True)
def _unpack(
    rp: np.ndarray,
) -> tuple[float, int, float, float, float, float, float, float]:  # pragma: no cover - compiled
    """:func:`ring_consts`' array as (radius, count, radius_tol_frac, inlier_tol, angle_tol,
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
    """The reference's ``circumcircles`` of one triple (same arithmetic): centre (3), unit
    normal (3), radius (∞ for collinear points), mm."""
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
    """Steps 1–2 of :mod:`app.geometry.ring` in one loop: the chord-compatible triples
    i < j < k (T, 3) in lexicographic order (as the reference's ``seed_triples`` of
    ``compatible_pairs``), and the rows of those that are seeds (circumcircle of the ring's
    radius, three distinct evenly spaced slots: the reference's ``circumcircles`` and
    ``seed_slots``), best slot fit first (stable), with their sums of squared slot residuals
    (deg²). ``rp``: :func:`ring_consts`."""
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
    :func:`~app.geometry.ring.measures.oriented`); status (index 9) 1 when there is no
    finite circle (``FitError``)."""
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
    """Step 3 for one seed, the arithmetic of the reference's ``fit_hypothesis``: (found,
    members (sorted point indices), their slots, residuals (deg), distances from the circle
    (mm), and 16 floats: the oriented fit (10, as :func:`circle_kernel`), offset (deg), cost,
    angle tolerance (deg), inlier tolerance (mm), points on the circle off the slots, range
    z)."""
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
        offset = slot_offset_kernel(slot_angles_kernel(p[current], center, normal), count)
        dist = distance_kernel(p, center, normal, fit[6])
        near = np.flatnonzero(dist <= itol)
        slots, resid = slot_residuals_kernel(
            slot_angles_kernel(p[near], center, normal), offset, count
        )
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
    """Step 3 over the seeds in order (the loop of
    :func:`~app.geometry.ring.search.find_ring`): a seed whose three points all belong to a
    hypothesis already found is skipped, a hypothesis found twice is kept once.
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


@njit(cache=True, nogil=True)
def radius_only_kernel(
    p: np.ndarray, triples: np.ndarray, rp: np.ndarray
) -> int:  # pragma: no cover - compiled
    """The reference's ``radius_only_count`` in one loop: with ≤ 30 points every triple
    i < j < k (in lexicographic order), else ``triples``; the first 2000 circumcircles of the
    ring's radius; the most points within the inlier tolerance of one of them. ``rp``:
    :func:`ring_consts`."""
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
