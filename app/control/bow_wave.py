"""Bow-wave feed-forward: where the receiver's nose will have pushed the drogue when the probe
arrives.

The guidance carries its own bow-wave model (:class:`app.model.drogue.DrogueModel`: a
force ``F₀ exp(−s/ℓ)`` away from the nose axis and up, ``s`` the axial distance nose → drogue)
acting on the drogue's lateral/vertical mode (ω, ζ, effective mass). Its *nominal* parameters
only: a flown bow wave of another strength, or a drogue of another mass, is not known to it.

* :class:`BowWaveModel` runs the model's response alongside the flight, driven by the estimated
  nose and drogue, so the guidance can split the drogue estimate into the bow-wave push (known)
  and the rest (mean + swing);
* :meth:`BowWaveModel.forecast` predicts that push at the arrival, the nose closing at the
  planned speed — the feed-forward: aim where the nose will have pushed the drogue.
"""

from __future__ import annotations

import math

import numpy as np

from app.control.drogue_swing import predict_swing_offset
from app.model.drogue import DrogueModel
from app.types import FloatArray

FORECAST_STEPS = 64  # quadrature points of the forced response over the horizon


def bow_force_n(
    params: DrogueModel, drogue_m: FloatArray, nose_m: FloatArray, nose_axis: FloatArray
) -> FloatArray:
    """The model's bow-wave force (N, tanker frame) on a drogue at ``drogue_m`` (the formula
    the simulated drogue uses, written here once more: the guidance shares no code with it)."""
    if params.bow_force_n == 0.0:
        return np.zeros(3)
    rel = np.asarray(drogue_m, float) - np.asarray(nose_m, float)
    axis = np.asarray(nose_axis, float)
    s = max(float(rel @ axis), 0.0)
    direction = rel - s * axis + np.array([0.0, 0.0, -params.bow_up_bias_m])
    direction /= np.linalg.norm(direction)
    return np.asarray(params.bow_force_n * math.exp(-s / params.bow_length_m) * direction)


class BowWaveModel:
    """The bow wave's push on the drogue (lateral y, vertical z; m, m/s) as the guidance
    models it: the drogue's lateral mode ``ẍ + 2ζω ẋ + ω² x = F/m`` driven by the modelled
    force."""

    def __init__(self, params: DrogueModel) -> None:
        self.params = params
        self.omega = params.omega_rad_s
        self.zeta = params.damping_ratio
        self.mass = params.effective_mass_kg
        self.reset()

    def reset(self) -> None:
        self.d = np.zeros(2)
        self.v = np.zeros(2)

    def step(self, dt: float, force_n: FloatArray, substeps: int = 4) -> None:
        """Advance by ``dt`` (s) under the force ``force_n`` (N, tanker frame; y and z used)."""
        f = np.asarray(force_n, float)[1:3] / self.mass
        w, z = self.omega, self.zeta
        h = dt / substeps
        for _ in range(substeps):
            acc = f - w * w * self.d - 2.0 * z * w * self.v
            self.v = self.v + h * acc
            self.d = self.d + h * self.v

    def forecast(
        self,
        horizon_s: float,
        nose_gap_m: float,
        closure_mps: float,
        direction: FloatArray,
    ) -> FloatArray:
        """The push (y, z; m) after ``horizon_s``: the present state's free response plus the
        forced response to the force the nose will exert, its axial distance to the drogue
        shrinking from ``nose_gap_m`` at ``closure_mps`` (never below 0), along the unit
        ``direction`` (y, z of the force's direction at the arrival)."""
        free = predict_swing_offset(self.d, self.v, self.omega, self.zeta, horizon_s)
        p = self.params
        if horizon_s <= 0 or p.bow_force_n == 0.0:
            return free
        tau = np.linspace(0.0, horizon_s, FORECAST_STEPS + 1)
        s = np.maximum(nose_gap_m - closure_mps * tau, 0.0)
        f = p.bow_force_n * np.exp(-s / p.bow_length_m) / self.mass
        w, z = self.omega, self.zeta
        wd = w * math.sqrt(max(1.0 - z * z, 1e-9))
        lag = horizon_s - tau
        g = np.exp(-z * w * lag) * np.sin(wd * lag) / wd  # impulse response
        y = g * f
        forced = float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(tau)))
        return np.asarray(free + forced * np.asarray(direction, float))
