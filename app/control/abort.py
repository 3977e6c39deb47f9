"""Breakaway logic (paper §6.1 guidance): abort inside the last metre if the predicted miss
exceeds the capture radius, or if the drogue lock is lost near contact; and inside
``overspeed_gap_m`` if the closure is already faster than the coupling latches (the receiver
cannot shed it before the plane — its engine spools down over seconds — so it would cross
fast, miss the latch window and overshoot the drogue towards the hose); and inside
``high_gap_m`` if the probe is predicted to pass ``high_pass_m`` above the drogue's centre
(well above the rim): the hose rises forward from
the drogue, so a receiver that overshoots high (it always overshoots the plane by 2–4 m while
its power comes off) flies its nose at the hose; breaking away a second earlier starts the
recovery law's descent before the plane.

The predicted miss extrapolates the lateral (y, z, tanker frame) offset of the drogue from the
probe tip with their relative velocity over the time to go ``t_go = gap / closure``.
"""

from __future__ import annotations

import numpy as np

from app.types import FloatArray


def offset_at_plane_m(
    rel_pos_m: FloatArray, rel_vel_mps: FloatArray, min_closure_mps: float = 0.2
) -> FloatArray:
    """The drogue's centre less the probe tip (y, z; m, tanker frame, z down) predicted at the
    plane crossing, both carried on straight lines for ``t_go = gap / closure``. ``rel_*`` =
    drogue minus probe tip. Its norm is the predicted miss; its z how far the tip passes
    above the centre (negative: below)."""
    closure = max(-float(rel_vel_mps[0]), min_closure_mps)
    t_go = max(float(rel_pos_m[0]), 0.0) / closure
    return np.asarray(rel_pos_m[1:3], float) + t_go * np.asarray(rel_vel_mps[1:3], float)


def predicted_miss_m(
    rel_pos_m: FloatArray, rel_vel_mps: FloatArray, min_closure_mps: float = 0.2
) -> float:
    """Lateral miss (m) predicted at the plane crossing (:func:`offset_at_plane_m`)."""
    return float(np.linalg.norm(offset_at_plane_m(rel_pos_m, rel_vel_mps, min_closure_mps)))


def should_abort(
    gap_m: float,
    predicted_miss: float,
    capture_radius_m: float,
    lock_lost: bool,
    final_gap_m: float = 1.0,
    margin: float = 1.0,
    closure_mps: float = 0.0,
    max_closure_mps: float = float("inf"),
    overspeed_gap_m: float = 0.0,
    above_at_plane_m: float = float("-inf"),
    high_gap_m: float = 0.0,
    high_pass_m: float = 0.5,
) -> str | None:
    """Reason to break away (``"overspeed"``, ``"passing_high"``, ``"predicted_miss"``,
    ``"lock_lost"``) or None to continue; ``closure_mps``: the probe's closing speed on the
    drogue (m/s); ``above_at_plane_m``: the z of :func:`offset_at_plane_m`."""
    if 0.0 <= gap_m <= overspeed_gap_m and closure_mps > max_closure_mps:
        return "overspeed"
    if 0.0 <= gap_m <= high_gap_m and above_at_plane_m > high_pass_m:
        return "passing_high"
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


def describe(reason: str, predicted_miss_m: float, closure_mps: float) -> str:
    """A :func:`should_abort` reason in words, for the operator and the run's outcome."""
    words = {
        "predicted_miss": f"predicted miss {predicted_miss_m:.2f} m",
        "overspeed": f"closing at {closure_mps:.2f} m/s, faster than the coupling latches",
        "passing_high": "predicted to pass high over the drogue, on the hose's side",
    }
    return words.get(reason, reason.replace("_", " "))
