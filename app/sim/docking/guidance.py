"""The docking guidance's model of the drogue's swing (a receiver slower than the swing, the
A-4): the drogue's smoothed mean the reference follows, the radial miss predicted at the arrival
from the swing (break-away), the lead to the swing predicted for the arrival, the bow wave's push
split off the estimate and forecast (feed-forward), and the timed closure's commit.

Tanker frame, metres and seconds; lateral/vertical offsets are the (y, z) components. The swing
itself is :func:`app.control.drogue_swing.predict_swing_offset` (a damped oscillator), the bow
wave :class:`app.control.bow_wave.BowWaveModel`.
"""

from __future__ import annotations

import math

import numpy as np

from app.control.bow_wave import BowWaveModel, bow_force_n
from app.control.drogue_swing import predict_swing_offset
from app.control.swing_identifier import SwingEstimate, SwingIdentifier
from app.model.drogue import DrogueModel
from app.sim.docking.config import DockingConfig
from app.types import FloatArray

# timed closure (the A-4): from the hold at the standoff the probe arrives after gap / closure
# speed plus this lag of the fore-aft loop (s; measured, calm air); the probe's lateral error
# to its reference decays with TIP_RETURN_S (s; the lateral loop's ≈ 0.5 rad/s)
COMMIT_LAG_S = 1.0
TIP_RETURN_S = 2.0
SWING_VAR_S = 4.0  # s, averaging of the drogue swing's mean square (≈ one swing period)
SWING_FULL_SMOOTHING_M = 0.1  # m RMS of the swing from which the full smoothing applies


class SwingGuidance:
    """The swing's state over one run: its mean (``mean``, None until the first smoothed
    reference), the smoothed reference and the swing's mean square about the mean (m²), the
    swing's frequency and damping identified online from the drogue estimates
    (:class:`~app.control.swing_identifier.SwingIdentifier`, the nominal model's until
    identified), and the guidance's bow-wave model (the nominal force, not the run's draw)."""

    def __init__(
        self,
        config: DockingConfig,
        drogue: DrogueModel,
        bow_model: BowWaveModel,
        smoothing_s: float,
        dt: float,
    ) -> None:
        self.config = config
        self.drogue = drogue
        self.bow_model = bow_model
        self.smoothing_s = smoothing_s
        self.dt = dt
        self.mean: FloatArray | None = None  # the drogue's mean (smoothing_s)
        self.ref_smooth: tuple[FloatArray, FloatArray] | None = None
        self.var = 0.0  # its swing's mean square about that mean (m²)
        self.identifier = SwingIdentifier(drogue, dt)
        self.swing_estimate: SwingEstimate = self.identifier.estimate()

    def smoothed_reference(
        self, drogue: FloatArray, drogue_vel: FloatArray, measured: bool = True
    ) -> tuple[FloatArray, FloatArray]:
        """The drogue position and velocity the guidance follows: laterally and vertically
        low-passed with a time constant that grows with the drogue's swing — ``smoothing_s``
        once its RMS about the mean reaches ``SWING_FULL_SMOOTHING_M``, none for a drogue at
        rest (whose slow moves, e.g. the bow wave's push, are then followed). The swing about
        the mean feeds the online identification while ``measured`` (the drogue in sight)."""
        dt = self.dt
        if self.mean is None or self.ref_smooth is None:
            self.mean = drogue.copy()
            self.ref_smooth = (drogue.copy(), drogue_vel.copy())
        mean = self.mean
        mean[1:] += (1.0 - math.exp(-dt / self.smoothing_s)) * (drogue[1:] - mean[1:])
        mean[0] = drogue[0]
        dev2 = float(np.sum((drogue[1:] - mean[1:]) ** 2))
        self.identifier.update(drogue[1:] - mean[1:], measured)
        self.swing_estimate = self.identifier.estimate()
        self.var += (1.0 - math.exp(-dt / SWING_VAR_S)) * (dev2 - self.var)
        tau = self.smoothing_s * min(1.0, math.sqrt(self.var) / SWING_FULL_SMOOTHING_M)
        a = 1.0 - math.exp(-dt / tau) if tau > 1e-6 else 1.0
        sp, sv = self.ref_smooth
        sp[1:] += a * (drogue[1:] - sp[1:])
        sv[1:] += a * (drogue_vel[1:] - sv[1:])
        sp[0], sv[0] = drogue[0], drogue_vel[0]
        return sp.copy(), sv.copy()

    def swing_offset_at_arrival(
        self,
        drogue: FloatArray,
        drogue_vel: FloatArray,
        mean: FloatArray,
        tip: FloatArray,
        tip_vel: FloatArray,
        gap_m: float,
        bow_at: FloatArray | None = None,
    ) -> FloatArray:
        """The drogue's centre less the probe tip (y, z; m) predicted at the arrival (``gap_m``
        over the closure speed): the drogue's swing about its mean
        (:func:`~app.control.drogue_swing.predict_swing_offset`), plus the bow wave's push
        forecast for then (``bow_at``, y z), against the probe tip carried by its own velocity.
        Its norm is the predicted miss; its z (down) how far the tip passes above the centre."""
        cfg = self.config
        sw = self.swing_estimate
        horizon = max(gap_m, 0.0) / cfg.closure_speed_mps
        swing = predict_swing_offset(
            (drogue - mean)[1:], drogue_vel[1:], sw.omega_rad_s, sw.damping_ratio, horizon
        )
        if bow_at is not None:
            swing = swing + bow_at
        tip_at = tip[1:] + tip_vel[1:] * horizon
        return np.asarray(mean[1:] + swing - tip_at, float)

    def swing_lead(
        self, drogue: FloatArray, drogue_vel: FloatArray, mean: FloatArray, tip: FloatArray
    ) -> FloatArray:
        """The drogue's swing about its mean (y, z; m) predicted for the probe's arrival (the
        gap to the tip over the closure speed): where the lead puts the probe."""
        sw = self.swing_estimate
        horizon = max(float((drogue - tip)[0]), 0.0) / self.config.closure_speed_mps
        return predict_swing_offset(
            (drogue - mean)[1:],
            drogue_vel[1:],
            sw.omega_rad_s,
            sw.damping_ratio,
            horizon,
        )

    def bow_split(
        self,
        nose: FloatArray,
        axis: FloatArray,
        drogue: FloatArray,
        drogue_vel: FloatArray,
        tip: FloatArray,
        phase: str,
        acquired: bool,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The drogue estimate without the bow wave's modelled push (position, velocity) and
        that push forecast at the arrival (y, z; m): :class:`~app.control.bow_wave.BowWaveModel`
        driven by the estimated nose (``nose``, the body's x ``axis`` in the tanker frame), the
        nose closing at the closure speed while approaching; no force before the drogue was
        ever ``acquired``."""
        bow = self.bow_model
        force = bow_force_n(bow.params, drogue, nose, axis) if acquired else np.zeros(3)
        bow.step(self.dt, force)
        q, qv = drogue.copy(), drogue_vel.copy()
        q[1:] -= bow.d
        qv[1:] -= bow.v
        closing = phase in ("approach", "final")
        closure = self.config.closure_speed_mps if closing else 0.0
        gap = max(float((drogue - tip) @ axis), 0.0)
        horizon = gap / self.config.closure_speed_mps if closing else 0.0
        # the force's direction at the arrival: the drogue on the probe tip
        at = tip - nose
        perp = at - float(at @ axis) * axis + np.array([0.0, 0.0, -bow.params.bow_up_bias_m])
        direction = perp / np.linalg.norm(perp)
        nose_gap = float((drogue - nose) @ axis)
        return q, qv, bow.forecast(horizon, nose_gap, closure, direction[1:])

    def commit_now(
        self,
        drogue: FloatArray,
        drogue_vel: FloatArray,
        tip: FloatArray,
        mean_ref: FloatArray,
        ref: FloatArray,
    ) -> bool:
        """At the standoff: commit to the final closure now? Yes when the drogue's swing about
        its mean predicted for the arrival (:func:`~app.control.drogue_swing.predict_swing_offset`)
        lies within ``commit_radius_m`` of where the probe will be — on its reference (the
        swing's smoothed mean ``mean_ref``; both sides carry the same bow-wave push) plus its
        present error to the reference ``ref``, decaying with the lateral loop's time constant.
        The arrival: the gap at the closure speed plus the fore-aft loop's lag from the hold
        (``COMMIT_LAG_S``). ``drogue``, ``drogue_vel``: the estimate without the modelled bow
        wave's push where the feed-forward is on."""
        cfg = self.config
        sw = self.swing_estimate
        mean = self.mean
        assert mean is not None
        gap = max(float((drogue - tip)[0]), 0.0)
        horizon = gap / cfg.closure_speed_mps + COMMIT_LAG_S
        at = mean[1:] + predict_swing_offset(
            (drogue - mean)[1:], drogue_vel[1:], sw.omega_rad_s, sw.damping_ratio, horizon
        )
        tip_at = mean_ref[1:] + (tip - ref)[1:] * math.exp(-horizon / TIP_RETURN_S)
        return bool(np.linalg.norm(at - tip_at) < cfg.commit_radius_m)
