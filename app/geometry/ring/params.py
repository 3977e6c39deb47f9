"""The ring the search looks for, its tolerances, a prior lock, and what the search returns.

:class:`RingParams` holds the ring (radius mm, LED count) and the tolerances, which grow with
the stereo depth noise σ_Z(z) (paper §5.2); :class:`RingPrior` a recent lock that a 3-LED
hypothesis is judged against; :class:`RingFit` / :class:`RingRejection` the outcome of
:func:`app.geometry.ring.find_ring`; :class:`RingHypothesis` one refined slot assignment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.geometry.circle_fit import Circle3D
from app.types import FloatArray


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
    # σ_lat / z (dimensionless: σ_d / f), the triangulated points' lateral noise; None → the
    # NFA's precision cells are isotropic at the depth noise (app.geometry.ring.nfa)
    lateral_sigma_per_mm: float | None = None
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

    def in_plane_sigmas(self, z_mm: float, sin_tilt: float) -> tuple[float, float] | None:
        """The points' noise σ (mm) along the two axes of the plane of a ring at range
        ``z_mm`` whose normal is ``asin(sin_tilt)`` off the line of sight: along the line of
        sight's projection on the plane (the lateral noise and the share of the depth noise
        the tilt turns into the plane), and across it (the lateral noise alone); None when the
        lateral noise is not set."""
        if self.lateral_sigma_per_mm is None:
            return None
        lateral = self.lateral_sigma_per_mm * z_mm
        tilted = self.sigma_z(z_mm) * sin_tilt
        return math.sqrt(lateral * lateral + tilted * tilted), lateral

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
class RingHypothesis:
    """One refined ring hypothesis: a circle and one point per slot (step 3 of the search)."""

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


def agrees_with_prior(circle: Circle3D, prior: RingPrior) -> bool:
    """The circle is where the prior lock predicts it (centre and normal within the gates)."""
    d = circle.center - np.asarray(prior.center_mm)
    dc = math.sqrt(float(d @ d))
    cosang = min(1.0, max(-1.0, float(circle.normal @ np.asarray(prior.normal))))
    return dc <= prior.gate_mm and math.degrees(math.acos(cosang)) <= prior.gate_deg
