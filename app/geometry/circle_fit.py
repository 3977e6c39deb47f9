"""Plane and circle fitting in 3-D (paper §5.2, eqs. 17–18).

The paper fits a sphere and a plane by least squares; we fit the plane by SVD (total least
squares) and the circle inside it (algebraic fit, then Gauss–Newton on the geometric distance),
which gives the drogue rim's centre, unit normal and radius directly, from 3 points upward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.geometry.calibration import FloatArray


class FitError(ValueError):
    """Points that do not define a plane/circle (fewer than 3, collinear, non-finite)."""


@dataclass(frozen=True)
class Circle3D:
    center: FloatArray  # (3,) mm
    normal: FloatArray  # (3,) unit; sign chosen by the caller
    radius: float  # mm
    rms: float  # RMS 3-D distance of the points from the circle, mm
    plane_rms: float  # RMS distance of the points from the plane, mm


def fit_plane(points: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Total-least-squares plane: (centroid, unit normal, RMS distance) — eq. 18's role."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 3 or not np.all(np.isfinite(pts)):
        raise FitError("a plane needs at least 3 finite points")
    centroid = pts.mean(axis=0)
    _, s, vt = np.linalg.svd(pts - centroid)
    if s[1] < 1e-9 * max(1.0, s[0]):
        raise FitError("points are collinear")
    normal = vt[2]
    rms = float(np.sqrt(np.mean(((pts - centroid) @ normal) ** 2)))
    return centroid, normal, rms


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """a × b for 3-vectors (np.cross costs ~10× more on single vectors)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def plane_basis(
    normal: FloatArray, up_hint: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Orthonormal in-plane axes (e1, e2). e1 is ``up_hint`` projected on the plane if given."""
    n = normal / math.sqrt(float(normal @ normal))
    hint = np.array([0.0, -1.0, 0.0]) if up_hint is None else np.asarray(up_hint, float)
    e1 = hint - float(hint @ n) * n
    length = math.sqrt(float(e1 @ e1))
    if length < 1e-6:
        e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
        length = math.sqrt(float(e1 @ e1))
    e1 = e1 / length
    return e1, _cross(e1, n)


def fit_circle_2d(xy: FloatArray, iterations: int = 10) -> tuple[FloatArray, float]:
    """Circle through 2-D points: Kåsa algebraic fit, then Gauss–Newton on geometric distance."""
    x, y = xy[:, 0], xy[:, 1]
    A = np.column_stack([2 * x, 2 * y, np.ones(len(x))])
    b = x * x + y * y
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:2].copy()
    r = float(np.sqrt(max(sol[2] + c @ c, 0.0)))
    if len(xy) > 3:
        J = np.empty((len(xy), 3))
        J[:, 2] = -1.0
        for _ in range(iterations):
            dx, dy = x - c[0], y - c[1]
            dist = np.hypot(dx, dy)
            if float(dist.min()) < 1e-12:
                break
            res = dist - r
            J[:, 0] = -dx / dist
            J[:, 1] = -dy / dist
            try:  # normal equations (3×3): the same step as lstsq on a well-posed fit
                step = np.linalg.solve(J.T @ J, -(J.T @ res))
            except np.linalg.LinAlgError:
                step, *_ = np.linalg.lstsq(J, -res, rcond=None)
            c = c + step[:2]
            r = r + float(step[2])
            if float(np.abs(step).max()) < 1e-10:
                break
    return np.asarray(c, dtype=np.float64), abs(r)


def fit_circle_3d(points: FloatArray) -> Circle3D:
    """Plane + in-plane circle through ≥ 3 points (mm). The normal's sign is arbitrary here."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centroid, normal, plane_rms = fit_plane(pts)
    e1, e2 = plane_basis(normal)
    rel = pts - centroid
    xy = np.column_stack([rel @ e1, rel @ e2])
    c2, radius = fit_circle_2d(xy)
    center = centroid + c2[0] * e1 + c2[1] * e2
    # 3-D distance of each point from the circle: in-plane radial and out-of-plane parts.
    off = rel @ normal
    radial = np.hypot(xy[:, 0] - c2[0], xy[:, 1] - c2[1]) - radius
    rms = float(np.sqrt(np.mean(radial**2 + off**2)))
    return Circle3D(center=center, normal=normal, radius=radius, rms=rms, plane_rms=plane_rms)


def distance_to_circle(points: FloatArray, circle: Circle3D) -> FloatArray:
    """3-D distance (mm) from each point to the circle."""
    rel = np.asarray(points, dtype=np.float64).reshape(-1, 3) - circle.center
    off = rel @ circle.normal
    in_plane = rel - off[:, None] * circle.normal
    radial = np.sqrt(np.einsum("ij,ij->i", in_plane, in_plane)) - circle.radius
    return np.asarray(np.sqrt(radial**2 + off**2))
