"""Where the drogue will be when the probe arrives: its swing about the mean as a damped
oscillator (the reduced-order hose–drogue model's lateral/vertical mode, ω and ζ from the
flight condition: :class:`app.sim.hose_drogue.HoseDrogueParams`).

A receiver much slower than the drogue's swing (the A-4: lateral position bandwidth ≈ 0.5
rad/s against a 1.6 rad/s, ζ ≈ 0.08 swing at 230 KCAS) cannot follow it; it holds the drogue's
mean (the guidance's smoothed estimate) at a pre-contact gap and closes when the predicted
offset at arrival is small — the go/no-go of :class:`app.sim.docking.DockingSimulation`.
"""

from __future__ import annotations

import math

import numpy as np

from app.types import FloatArray


def predict_swing_offset(
    offset_m: FloatArray,
    velocity_mps: FloatArray,
    omega_rad_s: float,
    zeta: float,
    horizon_s: float,
) -> FloatArray:
    """Offset from the mean (m, per axis) after ``horizon_s`` of free damped oscillation
    ẍ + 2ζω ẋ + ω² x = 0 from ``offset_m`` and ``velocity_mps`` (ζ < 1)."""
    x0 = np.asarray(offset_m, dtype=np.float64)
    v0 = np.asarray(velocity_mps, dtype=np.float64)
    if horizon_s <= 0:
        return x0.copy()
    wd = omega_rad_s * math.sqrt(max(1.0 - zeta * zeta, 1e-9))
    decay = math.exp(-zeta * omega_rad_s * horizon_s)
    c, s = math.cos(wd * horizon_s), math.sin(wd * horizon_s)
    return np.asarray(decay * (x0 * c + (v0 + zeta * omega_rad_s * x0) / wd * s))
