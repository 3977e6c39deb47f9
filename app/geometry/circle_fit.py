"""Plane and circle fitting in 3-D (paper §5.2, eqs. 17–18).

The paper fits a sphere and a plane by least squares; we fit the plane by total least squares
(the smallest eigenvector of the points' scatter matrix) and the circle inside it (algebraic
fit, then Gauss–Newton on the geometric distance), which gives the drogue rim's centre, unit
normal and radius directly, from 3 points upward. The arithmetic runs in the compiled loops
of :mod:`app.geometry.circle_fit_kernels`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.geometry.circle_fit_kernels import circle_kernel, distance_kernel, plane_axes
from app.types import FloatArray


class FitError(ValueError):
    """Points that do not define a plane/circle (fewer than 3, collinear, non-finite)."""


@dataclass(frozen=True)
class Circle3D:
    center: FloatArray  # (3,) mm
    normal: FloatArray  # (3,) unit; sign chosen by the caller
    radius: float  # mm
    rms: float  # RMS 3-D distance of the points from the circle, mm
    plane_rms: float  # RMS distance of the points from the plane, mm


def plane_basis(normal: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Orthonormal in-plane axes (e1, e2 = e1 × n) of the plane with this normal: e1 is the
    camera's up direction (−y) projected on the plane (the slot-angle convention of
    :mod:`app.geometry.led_ids`)."""
    e1, e2 = plane_axes(np.asarray(normal, dtype=np.float64))
    return np.asarray(e1), np.asarray(e2)


def circle_points(points: FloatArray) -> FloatArray:
    """≥ 3 finite points as a C-contiguous (n, 3) float64 array, else ``FitError``."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    if len(pts) < 3 or not np.all(np.isfinite(pts)):
        raise FitError("a plane needs at least 3 finite points")
    return pts


def run_circle_fit(kernel: Callable[..., Any], *args: Any) -> tuple[Circle3D, Any]:
    """Call a compiled fit whose result starts with
    :func:`~app.geometry.circle_fit_kernels.circle_kernel`'s 10 floats and turn
    them into a :class:`Circle3D` (``FitError`` when there is no circle); returns the circle
    and the kernel's full result."""
    try:
        out = kernel(*args)
    except np.linalg.LinAlgError as exc:  # a singular circle system: no circle
        raise FitError(f"no circle through the points ({exc})") from None
    res = out[0] if isinstance(out, tuple) else out
    if res[9] != 0.0:
        raise FitError("points are collinear")
    if not np.all(np.isfinite(res)):
        raise FitError("no finite circle through the points")
    circle = Circle3D(
        center=res[0:3].copy(),
        normal=res[3:6].copy(),
        radius=float(res[6]),
        rms=float(res[7]),
        plane_rms=float(res[8]),
    )
    return circle, out


def fit_circle_3d(points: FloatArray, iterations: int = 10) -> Circle3D:
    """Plane + in-plane circle through ≥ 3 points (mm), eqs. 17–18's role (see the module
    docstring). The normal's sign is arbitrary here."""
    return run_circle_fit(circle_kernel, circle_points(points), int(iterations))[0]


def distance_to_circle(points: FloatArray, circle: Circle3D) -> FloatArray:
    """3-D distance (mm) from each point to the circle (compiled loop)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    return np.asarray(
        distance_kernel(
            pts,
            np.asarray(circle.center, dtype=np.float64),
            np.asarray(circle.normal, dtype=np.float64),
            float(circle.radius),
        )
    )
