"""Compiled loops of the plane and circle fit in 3-D (paper §5.2, eqs. 17–18's role; numba,
cached on disk): the plane's in-plane axes, the fit itself (total least squares plane, Kåsa
circle, Gauss–Newton on the geometric distance) and the points' distances to a circle. Called
by :mod:`app.geometry.circle_fit` (which documents the fit) and by the ring search's compiled
loops (:mod:`app.geometry.ring`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """Compiled core of :func:`~app.geometry.circle_fit.plane_basis` (for other compiled
    loops): unit in-plane axes (e1, e2 = e1 × n) of the plane with this normal."""
    n = normal / np.sqrt(normal @ normal)
    # e1: the camera's up (0, −1, 0) projected on the plane; (1, 0, 0) if the plane faces up
    e1 = np.array([0.0, -1.0, 0.0]) + n[1] * n
    if np.sqrt(e1 @ e1) < 1e-6:
        e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
    e1 = e1 / np.sqrt(e1 @ e1)
    e2 = np.array(
        [e1[1] * n[2] - e1[2] * n[1], e1[2] * n[0] - e1[0] * n[2], e1[0] * n[1] - e1[1] * n[0]]
    )
    return e1, e2


@njit(cache=True, nogil=True)
def circle_kernel(pts: np.ndarray, iterations: int) -> np.ndarray:  # pragma: no cover - compiled
    """Plane (total least squares: the scatter matrix's smallest eigenvector, eq. 18's role)
    and the circle in it (Kåsa algebraic fit, then Gauss–Newton on the geometric distance).

    Returns 10 floats: centre (3, mm), unit normal (3), radius, RMS 3-D distance to the
    circle, RMS distance to the plane (mm), status (0 ok, 1 collinear points).
    """
    n = pts.shape[0]
    out = np.zeros(10)
    centroid = np.zeros(3)
    for p in range(n):
        centroid += pts[p]
    centroid /= n
    rel = pts - centroid
    scatter = rel.T @ rel
    evals, evecs = np.linalg.eigh(scatter)  # ascending
    s0, s1 = np.sqrt(max(evals[2], 0.0)), np.sqrt(max(evals[1], 0.0))
    if s1 < 1e-9 * max(1.0, s0):
        out[9] = 1.0
        return out
    normal = evecs[:, 0].copy()
    normal /= np.sqrt(normal @ normal)
    e1, e2 = plane_axes(normal)  # in-plane axes (as circle_fit.plane_basis)
    x = rel @ e1
    y = rel @ e2
    # Kåsa: [2x 2y 1]·(cx, cy, c) = x² + y² by its normal equations
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for p in range(n):
        row = (2.0 * x[p], 2.0 * y[p], 1.0)
        rhs = x[p] * x[p] + y[p] * y[p]
        for i in range(3):
            b[i] += row[i] * rhs
            for j in range(3):
                a[i, j] += row[i] * row[j]
    sol = np.linalg.solve(a, b)
    cx, cy = sol[0], sol[1]
    r = np.sqrt(max(sol[2] + cx * cx + cy * cy, 0.0))
    if n > 3:
        for _ in range(iterations):
            jtj = np.zeros((3, 3))
            jtr = np.zeros(3)
            degenerate = False
            for p in range(n):
                dx, dy = x[p] - cx, y[p] - cy
                dist = np.sqrt(dx * dx + dy * dy)
                if dist < 1e-12:
                    degenerate = True
                    break
                jrow = (-dx / dist, -dy / dist, -1.0)
                res = dist - r
                for i in range(3):
                    jtr[i] -= jrow[i] * res
                    for j in range(3):
                        jtj[i, j] += jrow[i] * jrow[j]
            if degenerate:
                break
            step = np.linalg.solve(jtj, jtr)
            cx += step[0]
            cy += step[1]
            r += step[2]
            if max(abs(step[0]), abs(step[1]), abs(step[2])) < 1e-10:
                break
    sq_plane = 0.0
    sq_all = 0.0
    for p in range(n):
        off = rel[p] @ normal
        radial = np.sqrt((x[p] - cx) ** 2 + (y[p] - cy) ** 2) - abs(r)
        sq_plane += off * off
        sq_all += radial * radial + off * off
    out[0:3] = centroid + cx * e1 + cy * e2
    out[3:6] = normal
    out[6] = abs(r)
    out[7] = np.sqrt(sq_all / n)
    out[8] = np.sqrt(sq_plane / n)
    return out


@njit(cache=True, nogil=True)
def distance_kernel(
    points: np.ndarray, center: np.ndarray, normal: np.ndarray, radius: float
) -> np.ndarray:  # pragma: no cover - compiled
    """3-D distance (mm) from each point (N×3, mm) to the circle (centre, unit normal,
    radius mm)."""
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        r0, r1, r2 = points[p, 0] - center[0], points[p, 1] - center[1], points[p, 2] - center[2]
        off = r0 * normal[0] + r1 * normal[1] + r2 * normal[2]
        i0, i1, i2 = r0 - off * normal[0], r1 - off * normal[1], r2 - off * normal[2]
        radial = np.sqrt(i0 * i0 + i1 * i1 + i2 * i2) - radius
        out[p] = np.sqrt(radial * radial + off * off)
    return out
