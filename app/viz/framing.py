"""Camera framing of the 3-D view: the drogue and the receiver in view (pure numpy, no viser).

Tanker frame (x forward, y right, z down; m). :func:`docking_targets` lists the points that
must be seen (drogue rim, probe tip, receiver nose, tail and wing tips); :func:`frame_view`
places a pinhole camera (vertical field of view ``fov_rad``, ``aspect`` = width / height) on
a fixed viewing direction — from the side and above — far enough back that the points'
bounding sphere fills at most ``fill`` of the narrower field of view; :func:`project` maps
points to pixels with the same camera model viser/three.js use (tests check the framing with
it against the camera the browser reports).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from app.geometry.rotations import euler_to_matrix
from app.model.tick import TickRecord

#: Viewing direction (from the target towards the camera): right of and above the approach,
#: slightly behind the receiver (tanker frame, z down → negative z is up).
VIEW_DIRECTION = np.array([-0.35, 1.0, -0.45])
UP = np.array([0.0, 0.0, -1.0])  # the scene's up (z down)
DROGUE_RADIUS_M = 0.305
FUSELAGE_M = ((0.4, 0.0, 0.0), (-1.6, 0.0, 0.0))  # nose and tail of the drawn fuselage (body)
WING_TIPS_M = ((-0.5, 1.45, 0.05), (-0.5, -1.45, 0.05))


def docking_targets(record: TickRecord) -> np.ndarray:
    """Points (N×3, m) that must be in view for a tick record; empty if it has none.

    Drogue centre and rim extremes (``drogue_truth_m``), probe tip, and the receiver's nose,
    tail and wing tips from ``uav_state`` (φ, θ, ψ at 6..8, position at 9..11).
    """
    pts: list[np.ndarray] = []
    drogue = getattr(record, "drogue_truth_m", None)
    if drogue is not None:
        d = np.asarray(drogue, float)
        pts.append(d)
        for axis in np.eye(3)[1:]:  # rim extremes across the approach (y, z)
            pts.extend((d + DROGUE_RADIUS_M * axis, d - DROGUE_RADIUS_M * axis))
    tip = getattr(record, "probe_tip_m", None)
    if tip is not None:
        pts.append(np.asarray(tip, float))
    uav = getattr(record, "uav_state", None)
    if uav is not None and len(uav) >= 12:
        pos = np.asarray(uav[9:12], float)
        R = euler_to_matrix(float(uav[6]), float(uav[7]), float(uav[8]))
        pts.append(pos)
        pts.extend(pos + R @ np.asarray(p, float) for p in (*FUSELAGE_M, *WING_TIPS_M))
    return np.array(pts, float).reshape(-1, 3)


def frame_view(
    points: np.ndarray,
    *,
    fov_rad: float,
    aspect: float,
    direction: Sequence[float] = tuple(VIEW_DIRECTION),
    fill: float = 0.8,
    min_distance_m: float = 2.0,
) -> tuple[np.ndarray, np.ndarray]:
    """``(position, look_at)`` of a camera that sees every point, from ``direction``.

    The bounding sphere of the points (centre = box centre) must fit in ``fill`` of the
    half-angle of the narrower field of view: distance = r / sin(fill · fov_min / 2).
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    if len(pts) == 0:
        raise ValueError("no points to frame")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = max(float(np.max(np.linalg.norm(pts - center, axis=1))), 0.5)
    fov_h = 2.0 * math.atan(math.tan(fov_rad / 2.0) * aspect)
    half = 0.5 * fill * min(fov_rad, fov_h)
    distance = max(radius / math.sin(half), min_distance_m)
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    return center + distance * d, center


def project(
    points: np.ndarray,
    *,
    position: Sequence[float],
    look_at: Sequence[float],
    up: Sequence[float],
    fov_rad: float,
    width_px: float,
    height_px: float,
) -> np.ndarray:
    """Pixel coordinates (N×2; u right, v down) and NaN behind the camera (pinhole, vertical
    field of view ``fov_rad``, as three.js's PerspectiveCamera with ``lookAt``)."""
    p = np.asarray(position, float)
    f = np.asarray(look_at, float) - p
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(up, float))
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    rel = np.asarray(points, float).reshape(-1, 3) - p
    x, y, z = rel @ r, rel @ u, rel @ f
    focal = 0.5 * height_px / math.tan(fov_rad / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([0.5 * width_px + focal * x / z, 0.5 * height_px - focal * y / z], axis=1)
    uv[z <= 0] = np.nan
    return uv
