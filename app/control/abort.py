"""Breakaway logic (paper §6.1 guidance): abort inside the last metre if the predicted miss
exceeds the capture radius, or if the drogue lock is lost near contact.

The predicted miss extrapolates the lateral (y, z, tanker frame) offset of the drogue from the
probe tip with their relative velocity over the time to go ``t_go = gap / closure``.
"""

from __future__ import annotations

import numpy as np

from app.types import FloatArray


def predicted_miss_m(
    rel_pos_m: FloatArray, rel_vel_mps: FloatArray, min_closure_mps: float = 0.2
) -> float:
    """Lateral miss (m) predicted at the plane crossing. ``rel_*`` = drogue minus probe tip."""
    gap = float(rel_pos_m[0])
    closure = max(-float(rel_vel_mps[0]), min_closure_mps)
    t_go = max(gap, 0.0) / closure
    lat = np.asarray(rel_pos_m[1:3], float) + t_go * np.asarray(rel_vel_mps[1:3], float)
    return float(np.linalg.norm(lat))


def should_abort(
    gap_m: float,
    predicted_miss: float,
    capture_radius_m: float,
    lock_lost: bool,
    final_gap_m: float = 1.0,
    margin: float = 1.0,
) -> str | None:
    """Reason to break away (``"predicted_miss"``, ``"lock_lost"``) or None to continue."""
    if gap_m > final_gap_m or gap_m < 0.0:
        return None
    if lock_lost:
        return "lock_lost"
    if predicted_miss > margin * capture_radius_m:
        return "predicted_miss"
    return None


class AlphaBetaTracker:
    """α–β tracker giving a smoothed velocity (m/s) from position samples (m) at a fixed tick.

    Used for the probe tip's velocity in the predicted-miss check: differentiating the observer's
    position estimate is more robust than ``R·v̂`` when unmodelled gusts bias the body velocity.
    """

    def __init__(self, dt: float, alpha: float = 0.2, beta: float = 0.02) -> None:
        self.dt, self.alpha, self.beta = dt, alpha, beta
        self.pos: FloatArray | None = None
        self.vel = np.zeros(3)

    def update(self, z: FloatArray) -> FloatArray:
        z = np.asarray(z, float)
        if self.pos is None:
            self.pos = z.copy()
            return self.vel
        pred = self.pos + self.dt * self.vel
        r = z - pred
        self.pos = pred + self.alpha * r
        self.vel = self.vel + (self.beta / self.dt) * r
        return self.vel
