"""Where points sit on a ring: one oriented circle fit and the slot angles (paper §5.2).

Slot angles are measured clockwise from the camera's up direction (−y) projected on the ring
plane (:func:`app.geometry.circle_fit.plane_axes`); the slot offset is the circular mean of
the angles × N (one slot period → 2π), ÷ N. :func:`ring_measures` gives all of it for the
tracker's ring check in one compiled call (:func:`~app.geometry.ring.kernels.ring_measures_kernel`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.geometry.circle_fit import Circle3D, circle_points, run_circle_fit
from app.geometry.ring.kernels import (
    ring_measures_kernel,
    slot_angles_kernel,
    slot_offset_kernel,
    slot_residuals_kernel,
)
from app.types import FloatArray


def oriented(circle: Circle3D) -> Circle3D:
    """The circle with its normal pointing towards the cameras at the origin."""
    n = circle.normal
    if float(n @ (-circle.center)) < 0:
        n = -n
    return Circle3D(circle.center, n, circle.radius, circle.rms, circle.plane_rms)


def view_angle_deg(circle: Circle3D) -> float:
    """Angle (deg) between the ring's normal and the line of sight to its centre (0 = head on,
    90 = edge-on)."""
    c = circle.center
    view = -c / max(math.sqrt(float(c @ c)), 1e-9)
    return math.degrees(math.acos(min(1.0, max(-1.0, float(circle.normal @ view)))))


def slot_angles_deg(points: FloatArray, circle: Circle3D) -> FloatArray:
    """Angle of each point around the ring, clockwise from the top as seen by the cameras."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    center = np.asarray(circle.center, dtype=np.float64)
    return np.asarray(slot_angles_kernel(pts, center, np.asarray(circle.normal, dtype=np.float64)))


def slot_offset_deg(angles_deg: FloatArray, count: int) -> float:
    """Offset of the evenly spaced slot pattern that best fits ``angles_deg``, in [0, 360/N):
    the circular mean of the angles × N (one slot period → 2π), ÷ N."""
    return float(slot_offset_kernel(np.ascontiguousarray(angles_deg, dtype=np.float64), int(count)))


def slot_residuals(
    angles_deg: FloatArray, offset_deg: float, count: int
) -> tuple[np.ndarray, FloatArray]:
    """(slot index 0..N−1, signed residual deg) of each angle for the given slot offset."""
    slots, resid = slot_residuals_kernel(
        np.ascontiguousarray(angles_deg, dtype=np.float64), float(offset_deg), int(count)
    )
    return np.asarray(slots), np.asarray(resid)


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
        ring_measures_kernel, circle_points(points), int(count)
    )
    return RingMeasures(circle, dist, angles, float(offset), slots, resid)
