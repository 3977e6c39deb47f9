"""The a-contrario integrity test of a ring hypothesis: its number of false alarms (log10)
and the volumes the background model spreads unrelated points over (paper §5.2).

An m-point ring among n candidates is "as good as chance" when the expected number of
m-point configurations that would fit as well among n unrelated points, uniform in the
volume, is not small (:func:`log10_nfa`). Volumes in mm³.
"""

from __future__ import annotations

import math
import statistics

import numpy as np

from app.geometry.circle_fit import Circle3D, distance_to_circle
from app.geometry.ring.params import RingParams, RingPrior
from app.types import FloatArray


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

    With the points' lateral noise known (``params.lateral_sigma_per_mm``) the cells follow
    the noise, which stereo makes far larger along the line of sight (σ_Z/σ_lat = z/B): within
    the ring's plane the precision is the same observed residuals (the radius error too) with
    the floor 3σ along each of the plane's axes (:meth:`RingParams.in_plane_sigmas`: ρ_a along
    the line of sight's projection, ρ_b across it), across the plane ρ stays as above. A chord
    lies in the plane (the shell's thickness from ρ_a, the larger); the 3rd point's family runs
    across the plane (a rotation about the chord), so its section is the ellipse ρ_a × ρ_b in
    the plane; a further slot cell is the ellipsoid ρ_a × ρ_b × ρ.
    """
    R, N = params.radius_mm, params.led_count
    m = len(points)
    if m < 3 or n < m:
        return math.inf
    z = float(circle.center[2])
    floor = max(0.3, 3.0 * float(params.sigma_z(z)))
    dist = distance_to_circle(points, circle) if distance_mm is None else distance_mm
    resid = np.asarray(resid_deg).tolist()
    observed = max(
        max(np.asarray(dist).tolist(), default=0.0),
        R * math.radians(max(max(resid), -min(resid))),
    )
    rho = max(floor, observed)
    radius_error = abs(circle.radius - R)
    rho_a = rho_b = rho
    sigmas = None
    if params.lateral_sigma_per_mm is not None:
        sigmas = params.in_plane_sigmas(z, _sin_tilt(circle))
    if sigmas is not None:
        observed = max(0.3, observed, radius_error)
        rho_a = min(rho, max(observed, 3.0 * sigmas[0]))
        rho_b = min(rho_a, max(observed, 3.0 * sigmas[1]))
    delta = 2.0 * rho_a + max(min(floor, rho_a), radius_error)
    chord = 2.0 * R * math.sin(math.pi * (N // 2) / N)
    v = max(volume_mm3, 1.0)
    p2 = min(1.0, 4.0 * math.pi * chord**2 * 2.0 * delta / v)
    p3 = min(1.0, 2.0 * math.pi * R * math.pi * rho_a * rho_b / v)
    p4 = min(1.0, 4.0 / 3.0 * math.pi * rho_a * rho_b * rho / v)
    labellings = math.lgamma(N + 1) - math.lgamma(N - m + 1)
    return (
        _log10_comb(n, m)
        + labellings / math.log(10)
        + math.log10(p2)
        + math.log10(p3)
        + (m - 3) * math.log10(p4)
    )


def _sin_tilt(circle: Circle3D) -> float:
    """The sine of the angle between the ring's normal and the line of sight to its centre
    (scalar arithmetic: this runs for every hypothesis and every tracked frame)."""
    cx, cy, cz = circle.center.tolist()
    nx, ny, nz = circle.normal.tolist()
    wx, wy, wz = ny * cz - nz * cy, nz * cx - nx * cz, nx * cy - ny * cx
    return math.sqrt((wx * wx + wy * wy + wz * wz) / (cx * cx + cy * cy + cz * cz))


def background_volume_mm3(p: FloatArray, params: RingParams) -> float:
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


def prior_volume_mm3(params: RingParams, prior: RingPrior) -> float:
    """The neighbourhood a prior lock confines a ring to (mm³): a cube of side 2(R + gate)."""
    return float((2.0 * (params.radius_mm + prior.gate_mm)) ** 3)
