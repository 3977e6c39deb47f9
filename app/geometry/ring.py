"""Find the drogue's LED ring among triangulated points, label the LEDs, reject clutter.

A consensus search (RANSAC over all triples, exhaustive for the few points we have) keeps the
circle of the expected radius that explains the most points; points off that circle, or off the
ring's evenly spaced LED slots, are clutter. LEDs are labelled 1..N clockwise from the top as
seen by the cameras (paper Table 5): slot angles are measured clockwise from the camera's up
direction (−y) projected on the ring plane; slot 1 is the first slot at or after 12 o'clock.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from app.geometry.calibration import FloatArray
from app.geometry.circle_fit import Circle3D, FitError, fit_circle_3d, plane_basis

MAX_POINTS = 24  # consensus search is O(N^3); more candidates than this are trimmed


@dataclass(frozen=True)
class RingParams:
    """The ring we look for (mm, deg)."""

    radius_mm: float = 75.0
    led_count: int = 5
    radius_tol_mm: float = 7.5  # |fitted − expected radius| allowed
    inlier_tol_mm: float = 2.0  # distance from the circle for a point to count
    angle_tol_deg: float = 12.0  # deviation from an evenly spaced LED slot
    min_leds: int = 3


@dataclass(frozen=True)
class RingFit:
    circle: Circle3D  # normal oriented from the drogue towards the cameras
    indices: tuple[int, ...]  # input point indices on the ring (sorted by id)
    ids: tuple[int, ...]  # 1..led_count, aligned with ``indices``


@dataclass(frozen=True)
class RingRejection:
    reason: str


def _oriented(circle: Circle3D) -> Circle3D:
    n = circle.normal
    if float(n @ (-circle.center)) < 0:  # point towards the cameras at the origin
        n = -n
    return Circle3D(circle.center, n, circle.radius, circle.rms, circle.plane_rms)


def _circumcircles(p: FloatArray, triples: np.ndarray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Centre (T,3), unit normal (T,3), radius (T,) of the circle through each triple."""
    p1, p2, p3 = p[triples[:, 0]], p[triples[:, 1]], p[triples[:, 2]]
    a, b = p1 - p3, p2 - p3
    axb = np.cross(a, b)
    n2 = np.sum(axb * axb, axis=1)
    ok = n2 > 1e-9
    n2 = np.where(ok, n2, 1.0)
    num = np.cross(np.sum(a * a, axis=1)[:, None] * b - np.sum(b * b, axis=1)[:, None] * a, axb)
    center = p3 + num / (2.0 * n2[:, None])
    radius = np.where(ok, np.linalg.norm(center - p3, axis=1), np.inf)
    normal = axb / np.sqrt(n2)[:, None]
    return center, normal, radius


def _distances(
    p: FloatArray, center: FloatArray, normal: FloatArray, radius: FloatArray
) -> FloatArray:
    """(T, N) 3-D distance of each point to each candidate circle."""
    rel = p[None, :, :] - center[:, None, :]
    off = np.einsum("tnk,tk->tn", rel, normal)
    in_plane = rel - off[:, :, None] * normal[:, None, :]
    radial = np.linalg.norm(in_plane, axis=2) - radius[:, None]
    return np.asarray(np.sqrt(radial**2 + off**2))


def slot_angles_deg(points: FloatArray, circle: Circle3D) -> FloatArray:
    """Angle of each point around the ring, clockwise from the top as seen by the cameras."""
    e_up, e_right = plane_basis(circle.normal)
    rel = np.asarray(points).reshape(-1, 3) - circle.center
    return np.asarray(np.degrees(np.arctan2(rel @ e_right, rel @ e_up)) % 360.0)


def _slots(angles: FloatArray, count: int) -> tuple[FloatArray, FloatArray, float]:
    """Nearest evenly spaced slot for each angle: (slot index, residual deg, offset deg)."""
    spacing = 360.0 / count
    phase = np.radians(angles * count)  # one slot period → 2π
    offset = float(np.degrees(np.angle(np.mean(np.exp(1j * phase)))) / count) % spacing
    k = np.rint((angles - offset) / spacing)
    resid = angles - offset - k * spacing
    return np.mod(k, count), resid, offset


def find_ring(
    points: FloatArray, params: RingParams, order_hint: FloatArray | None = None
) -> RingFit | RingRejection:
    """Locate the LED ring among ``points`` (N×3, mm). ``order_hint`` (N,) ranks points for
    trimming when there are more than MAX_POINTS (lower is better)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    finite = np.all(np.isfinite(pts), axis=1)
    index_map = np.flatnonzero(finite)
    if len(index_map) > MAX_POINTS:
        rank = np.zeros(len(pts)) if order_hint is None else np.asarray(order_hint, float)
        index_map = index_map[np.argsort(rank[index_map], kind="stable")[:MAX_POINTS]]
    p = pts[index_map]
    n = len(p)
    if n < params.min_leds:
        return RingRejection(f"only {n} matched LED(s); need at least {params.min_leds}")
    triples = np.array(list(combinations(range(n), 3)), dtype=np.int64)
    center, normal, radius = _circumcircles(p, triples)
    plausible = np.abs(radius - params.radius_mm) <= params.radius_tol_mm
    if not np.any(plausible):
        return RingRejection(
            f"no 3 matched points lie on a ring of radius {params.radius_mm:.0f} ± "
            f"{params.radius_tol_mm:.1f} mm"
        )
    center, normal, radius = center[plausible], normal[plausible], radius[plausible]
    dist = _distances(p, center, normal, radius)
    inl = dist <= params.inlier_tol_mm
    score = inl.sum(axis=1) - np.where(inl, dist, 0).sum(axis=1) / (params.inlier_tol_mm * n + 1)
    best = int(np.argmax(score))
    members = np.flatnonzero(inl[best])
    try:
        circle = _oriented(fit_circle_3d(p[members]))
    except FitError as exc:
        return RingRejection(f"ring fit failed: {exc}")
    # Slot check: LEDs sit on evenly spaced slots; at most one point per slot.
    angles = slot_angles_deg(p[members], circle)
    slot, resid, _ = _slots(angles, params.led_count)
    keep: dict[int, int] = {}
    for m, s, r in zip(members, slot.astype(int), resid, strict=True):
        if abs(r) > params.angle_tol_deg:
            continue
        d = float(dist[best, m])
        if s not in keep or d < float(dist[best, keep[s]]):
            keep[s] = int(m)
    members = np.array(sorted(keep.values()), dtype=np.int64)
    if len(members) < params.min_leds:
        return RingRejection(
            f"only {len(members)} point(s) fit an evenly spaced ring of radius "
            f"{params.radius_mm:.0f} mm; need at least {params.min_leds}"
        )
    try:
        circle = _oriented(fit_circle_3d(p[members]))
    except FitError as exc:
        return RingRejection(f"ring fit failed: {exc}")
    if abs(circle.radius - params.radius_mm) > params.radius_tol_mm:
        return RingRejection(
            f"fitted ring radius {circle.radius:.1f} mm is outside {params.radius_mm:.0f} ± "
            f"{params.radius_tol_mm:.1f} mm"
        )
    if circle.rms > params.inlier_tol_mm:
        return RingRejection(
            f"ring fit RMS {circle.rms:.2f} mm exceeds {params.inlier_tol_mm:.2f} mm"
        )
    angles = slot_angles_deg(p[members], circle)
    slot, _, _ = _slots(angles, params.led_count)
    ids = slot.astype(int) + 1
    order = np.argsort(ids, kind="stable")
    return RingFit(
        circle=circle,
        indices=tuple(int(index_map[members[o]]) for o in order),
        ids=tuple(int(ids[o]) for o in order),
    )
