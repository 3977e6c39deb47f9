"""Geometry of the drogue's LED ring (paper §3.1, Figure 12, Table 5).

Frame: the LEFT camera frame (x right, y down, z forward, mm), which is the world frame.
The ring's ``normal`` is a unit vector pointing from the drogue towards the cameras
(≈ (0, 0, −1) head on). LED k (k = 0..N−1, id k+1) sits at the angle
θ_k = phase + roll + k·360°/N measured clockwise from the top as seen by the camera::

    p_k = c + r (cos θ_k e_up + sin θ_k e_right)

where ``e_up`` is the camera "up" direction (−y) projected onto the ring plane and
``e_right = e_up × normal`` (≈ +x head on). The id convention is :mod:`app.geometry.led_ids`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.geometry.calibration import StereoCalibration
from app.geometry.circle_fit import plane_basis
from app.geometry.led_ids import DEFAULT_PHASE_DEG
from app.geometry.projection import project_stereo
from app.types import FloatArray

HEAD_ON = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class LedRing:
    """The drogue's LED ring: N LEDs (ids 1..N, clockwise from the top) on a circle (mm)."""

    radius_mm: float = 75.0
    count: int = 5
    led_diameter_mm: float = 5.0
    phase_deg: float = DEFAULT_PHASE_DEG

    def __post_init__(self) -> None:
        if not (math.isfinite(self.radius_mm) and self.radius_mm > 0):
            raise ValueError(f"LedRing.radius_mm must be a positive number, got {self.radius_mm}")
        if not isinstance(self.count, int | np.integer) or self.count < 1:
            raise ValueError(f"LedRing.count must be a positive integer, got {self.count}")
        if not (math.isfinite(self.led_diameter_mm) and self.led_diameter_mm > 0):
            raise ValueError(
                f"LedRing.led_diameter_mm must be a positive number, got {self.led_diameter_mm}"
            )
        if not math.isfinite(self.phase_deg):
            raise ValueError(f"LedRing.phase_deg must be finite, got {self.phase_deg}")

    @property
    def ids(self) -> np.ndarray:
        """LED ids, 1-based, clockwise from the top (paper Table 5 labels)."""
        return np.arange(1, self.count + 1)


def _check_vec3(value: object, name: str) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 3 numbers, got {value!r}") from None
    if arr.shape != (3,):
        raise ValueError(f"{name} must be 3 numbers, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values: {arr.tolist()}")
    return arr


def check_pose(center_mm: object, normal: object) -> tuple[FloatArray, FloatArray]:
    """Validate a ring pose; returns (centre mm, unit normal). Raises ValueError."""
    c = _check_vec3(center_mm, "center_mm")
    n = _check_vec3(normal, "normal")
    norm = float(np.linalg.norm(n))
    if norm < 1e-9:
        raise ValueError("normal is a zero vector; it must point from the drogue to the cameras")
    return c, n / norm


def ring_basis(normal: object) -> tuple[FloatArray, FloatArray]:
    """In-plane unit vectors (e_up, e_right) of the ring plane with the given normal: the
    pipeline's own basis (:func:`app.geometry.circle_fit.plane_basis`), so both measure LED
    angles the same way (:mod:`app.geometry.led_ids`)."""
    _, n = check_pose(np.zeros(3), normal)
    return plane_basis(n)


def led_angles_rad(ring: LedRing, roll_rad: float = 0.0) -> FloatArray:
    """θ_k = phase + roll + k·2π/N (rad), clockwise from the top as seen by the camera."""
    k = np.arange(ring.count, dtype=np.float64)
    return math.radians(ring.phase_deg) + float(roll_rad) + k * (2.0 * math.pi / ring.count)


def ring_points(
    center_mm: object, normal: object, ring: LedRing | None = None, roll_rad: float = 0.0
) -> FloatArray:
    """LED centres (N×3, mm, left camera frame); row k is LED id k+1."""
    ring = ring or LedRing()
    c, n = check_pose(center_mm, normal)
    if not math.isfinite(float(roll_rad)):
        raise ValueError(f"roll_rad must be finite, got {roll_rad}")
    e_up, e_right = ring_basis(n)
    th = led_angles_rad(ring, roll_rad)
    pts = c + ring.radius_mm * (np.outer(np.cos(th), e_up) + np.outer(np.sin(th), e_right))
    return np.asarray(pts, dtype=np.float64)


def normal_tilt_deg(normal: object) -> float:
    """Angle (deg) between a ring normal and the head-on normal (0, 0, −1)."""
    _, n = check_pose(np.zeros(3), normal)
    return float(np.degrees(np.arccos(np.clip(float(n @ HEAD_ON), -1.0, 1.0))))


def tilted_normal(tilt_deg: float, azimuth_deg: float = 0.0) -> FloatArray:
    """Unit normal tilted by ``tilt_deg`` from (0, 0, −1) towards the image direction
    ``azimuth_deg`` (0° = +x/right, 90° = +y/down)."""
    if not (math.isfinite(tilt_deg) and math.isfinite(azimuth_deg)):
        raise ValueError("tilt_deg and azimuth_deg must be finite")
    t, a = math.radians(tilt_deg), math.radians(azimuth_deg)
    return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), -math.cos(t)])


def _ring_fits(
    calib: StereoCalibration,
    center: FloatArray,
    normal: FloatArray,
    ring: LedRing,
    margin_px: float,
) -> bool:
    # the whole circle (not just the LEDs), so any roll of the ring stays in view
    circle = LedRing(radius_mm=ring.radius_mm + 0.5 * ring.led_diameter_mm, count=72)
    pts = ring_points(center, normal, circle)
    pr = (calib.R @ pts.T).T + calib.T
    if np.any(pts[:, 2] < 1.0) or np.any(pr[:, 2] < 1.0):
        return False
    w, h = calib.image_size
    for px in project_stereo(calib, pts):
        if not np.all(np.isfinite(px)):
            return False
        if np.any(px[:, 0] < margin_px) or np.any(px[:, 0] > w - 1 - margin_px):
            return False
        if np.any(px[:, 1] < margin_px) or np.any(px[:, 1] > h - 1 - margin_px):
            return False
    return True


def stereo_center_x_mm(calib: StereoCalibration, depth_mm: float) -> float:
    """x (mm) at depth ``depth_mm`` on y = 0 that sits equally far inside both images."""
    w = calib.image_size[0]

    def balance(x: float) -> float:
        ul, ur = project_stereo(calib, np.array([[x, 0.0, depth_mm]]))
        return float((ul[0, 0] - (w - 1) / 2) + (ur[0, 0] - (w - 1) / 2))

    x0, x1 = -depth_mm, depth_mm
    f0 = balance(x0)
    for _ in range(50):  # bisection; balance() increases with x
        xm = 0.5 * (x0 + x1)
        fm = balance(xm)
        if (fm > 0) == (f0 > 0):
            x0, f0 = xm, fm
        else:
            x1 = xm
    return 0.5 * (x0 + x1)


def random_pose(
    rng: np.random.Generator,
    range_mm: float,
    max_tilt_deg: float = 20.0,
    lateral_frac: float = 0.15,
    calib: StereoCalibration | None = None,
    ring: LedRing | None = None,
    margin_px: float = 20.0,
    max_tries: int = 200,
) -> tuple[FloatArray, FloatArray]:
    """A random ring pose (centre mm, unit normal) at depth ≈ ``range_mm`` (±3 %).

    The lateral offset is drawn uniformly within ±``lateral_frac``·range around the point
    midway in both images, and redrawn until the whole ring circle (so the LEDs at any roll)
    lies ``margin_px`` inside both images of ``calib`` (default: the paper's rig). The normal is tilted from (0, 0, −1) by up to
    ``max_tilt_deg`` in a random direction. If no draw fits after ``max_tries`` (the ring is
    too large for the overlap at this range) the centred pose is returned.
    """
    if not (math.isfinite(range_mm) and range_mm > 0):
        raise ValueError(f"range_mm must be a positive number, got {range_mm}")
    if not (math.isfinite(max_tilt_deg) and 0 <= max_tilt_deg < 90):
        raise ValueError(f"max_tilt_deg must be in [0, 90), got {max_tilt_deg}")
    if not (math.isfinite(lateral_frac) and lateral_frac >= 0):
        raise ValueError(f"lateral_frac must be >= 0, got {lateral_frac}")
    if calib is None:
        from app.geometry.calibration import paper_calibration

        calib = paper_calibration()
    ring = ring or LedRing()
    x_mid = stereo_center_x_mm(calib, range_mm)
    center = np.array([x_mid, 0.0, range_mm])
    normal = HEAD_ON.copy()
    for _ in range(max_tries):
        z = range_mm * (1.0 + rng.uniform(-0.03, 0.03))
        dx, dy = rng.uniform(-lateral_frac, lateral_frac, size=2) * range_mm
        tilt = rng.uniform(0.0, max_tilt_deg)
        az = rng.uniform(0.0, 360.0)
        c = np.array([x_mid * z / range_mm + dx, dy, z])
        n = tilted_normal(tilt, az)
        if _ring_fits(calib, c, n, ring, margin_px):
            return c, n
    return center, normal
