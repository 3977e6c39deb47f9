"""Guidance numbers for a real stream (no simulated receiver, no own-state feed).

Frame: the *approach frame* of the left camera, in metres: x forward (camera +Z, the
closure axis), y right (camera +X), z down (camera +Y). The probe tip sits at
``probe_tip_cam_mm`` in the left-camera frame (its mount offset; default the camera origin).

Per pair: the drogue centre from the pipeline (:class:`PoseResult`, camera frame, mm) is
filtered by :class:`app.control.drogue_filter.DrogueFilter` (constant velocity, χ² gating;
measurement noise from the stereo geometry, σ_Z ≈ Z²·σ_d/(f·B), σ_XY ≈ Z·σ_px/f), and from the
filter estimate: relative position (drogue − probe tip), closure speed (−ẋ), predicted miss
(:func:`app.control.abort.predicted_miss_m`: lateral offset extrapolated to the crossing) and
time to contact (gap / closure speed, when closing). Without a lock the filter coasts.

The controller needs the receiver's own state: it runs only with the simulation. A real
autopilot feed would plug in here (an own-state source giving the tip's tanker-frame pose).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.control.abort import predicted_miss_m
from app.control.drogue_filter import DrogueFilter
from app.model.pose import PoseResult
from app.types import FloatArray

MAX_GAP_S = 1.0  # a longer gap between frames (or time going back) restarts the filter


@dataclass(frozen=True)
class StreamGuidanceConfig:
    probe_tip_cam_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    focal_px: float = 2350.0  # for the measurement noise model
    baseline_mm: float = 115.0
    centroid_sigma_px: float = 0.2
    min_closure_mps: float = 0.05  # slower closure: no time to contact
    max_coast_s: float = 0.5  # after this long without a lock the estimate is withheld


@dataclass
class GuidanceState:
    """One pair's guidance output (approach frame, m; ``None`` when not available)."""

    drogue_measured_m: tuple[float, float, float] | None = None
    drogue_estimate_m: tuple[float, float, float] | None = None
    drogue_velocity_mps: tuple[float, float, float] | None = None
    probe_tip_m: tuple[float, float, float] | None = None
    rel_position_m: tuple[float, float, float] | None = None
    closure_speed_mps: float | None = None
    predicted_miss_m: float | None = None
    time_to_contact_s: float | None = None
    coast_s: float = 0.0


def cam_mm_to_approach_m(p_mm: FloatArray) -> FloatArray:
    """Left-camera frame (mm; x right, y down, z forward) → approach frame (m; x fwd)."""
    p = np.asarray(p_mm, float) / 1e3
    return np.array([p[2], p[0], p[1]])


def _vec(v: FloatArray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


class StreamGuidance:
    def __init__(self, config: StreamGuidanceConfig | None = None) -> None:
        self.config = config or StreamGuidanceConfig()
        self.filter = DrogueFilter()
        self.tip_m = cam_mm_to_approach_m(np.asarray(self.config.probe_tip_cam_mm, float))
        self._last_t: float | None = None

    def reset(self) -> None:
        self.filter.reset()
        self._last_t = None

    def _noise(self, depth_m: float) -> FloatArray:
        c = self.config
        z_mm = max(depth_m * 1e3, 1.0)
        lateral = z_mm * c.centroid_sigma_px / c.focal_px
        axial = z_mm**2 * c.centroid_sigma_px / (c.focal_px * c.baseline_mm)
        s = np.array([max(axial, 1.0), max(lateral, 1.0), max(lateral, 1.0)]) / 1e3
        return np.diag(s**2)

    def update(self, t_s: float, pose: PoseResult | None) -> GuidanceState:
        f = self.filter
        if self._last_t is not None:
            dt = t_s - self._last_t
            if not (0.0 < dt <= MAX_GAP_S):
                f.reset()
            else:
                f.predict(dt)
        self._last_t = t_s
        out = GuidanceState(probe_tip_m=_vec(self.tip_m))
        if pose is not None and pose.lock and pose.drogue is not None:
            z = cam_mm_to_approach_m(np.asarray(pose.drogue.center_mm, float))
            out.drogue_measured_m = _vec(z)
            f.update(z, self._noise(float(z[0])))
        out.coast_s = float(f.coast_time_s)
        if not f.initialised or f.coast_time_s > self.config.max_coast_s:
            return out
        pos, vel = f.position, f.velocity
        rel = pos - self.tip_m
        out.drogue_estimate_m = _vec(pos)
        out.drogue_velocity_mps = _vec(vel)
        out.rel_position_m = _vec(rel)
        closure = -float(vel[0])
        out.closure_speed_mps = closure
        out.predicted_miss_m = predicted_miss_m(rel, vel)
        gap = float(rel[0])
        if closure >= self.config.min_closure_mps and gap > 0:
            ttc = gap / closure
            out.time_to_contact_s = ttc if math.isfinite(ttc) else None
        return out
