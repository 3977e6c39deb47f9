"""Online identification of the drogue's swing from the guidance's own drogue estimates.

The guidance predicts the drogue's swing about its mean as a damped oscillator
``d̈ + 2ζω ḋ + ω² d = F/m`` (:func:`app.control.drogue_swing.predict_swing_offset`). Its
nominal ω and ζ (:class:`app.model.drogue.DrogueModel`) are the catalogue values of the
hose type; the flown hose and drogue differ (length, mass, drag: ±30 % in the ``standard`` and
``harsh`` presets, and a multi-body hose swings faster than the reduced model). So the guidance
identifies them while it flies, from nothing but its estimates of the drogue:

* the deviation of the estimate from its running mean (lateral y and vertical z, metres) is
  sampled every ``sample_s`` seconds;
* an AR(2) model ``x_k = a₁ x_{k−1} + a₂ x_{k−2} + e_k`` — the exact discretisation of the
  oscillator's free response, whose poles are ``z = exp(s T)`` with ``s = −ζω ± iω√(1−ζ²)`` —
  is fitted to both axes together by recursive least squares with exponential forgetting
  (time constant ``forgetting_s``);
* the poles give ``ω = |ln z| / T`` and ``ζ = −Re(ln z) / |ln z|``.

Until enough swing has been seen (``min_samples`` samples while the swing's RMS is above
``min_rms_m``) or when the fit is not an underdamped oscillator inside the plausible range
(``omega_range`` × the nominal ω, ``zeta_range``), the estimate is the nominal model's and says
so (``identified`` False).
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from app.model.drogue import DrogueModel
from app.types import FloatArray


@dataclass(frozen=True)
class SwingEstimate:
    """The swing the guidance predicts with: natural frequency (rad/s) and damping ratio,
    whether they were identified (False: the nominal model's), and how many samples the fit
    has seen."""

    omega_rad_s: float
    damping_ratio: float
    identified: bool
    samples: int


@dataclass(frozen=True)
class SwingIdentifierConfig:
    """Sampling period and forgetting time constant (s), the samples and the swing RMS (m)
    needed before the fit is used, and the plausible range (ω as multiples of the nominal)."""

    sample_s: float = 0.2
    forgetting_s: float = 60.0
    min_samples: int = 60
    min_rms_m: float = 0.03
    order: int = 4
    omega_range: tuple[float, float] = (0.5, 2.0)
    zeta_range: tuple[float, float] = (0.02, 0.6)


class SwingIdentifier:
    """Recursive least squares on the AR(2) swing model (module docstring)."""

    def __init__(
        self, prior: DrogueModel, dt_s: float, config: SwingIdentifierConfig | None = None
    ) -> None:
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s!r}")
        self.prior = prior
        self.dt_s = dt_s
        self.config = config or SwingIdentifierConfig()
        self._lambda = math.exp(-self.config.sample_s / self.config.forgetting_s)
        if not 2 <= self.config.order <= 6:
            raise ValueError(f"order must be in 2–6, got {self.config.order!r}")
        self.theta = np.zeros(self.config.order)
        self.cov = np.eye(self.config.order) * 1e3
        self._since_sample_s = 0.0
        self._history: list[FloatArray] = []  # the last `order` samples, newest last (y, z)
        self.samples = 0
        self._ms = 0.0  # the deviation's mean square (m²), same forgetting

    def update(self, deviation_m: FloatArray, measured: bool = True) -> None:
        """One tick: the drogue estimate's deviation from its mean (y, z; m). ``measured``
        False (no fresh measurement: the estimate coasts) breaks the sample history, so that no
        regression spans the gap."""
        x = np.asarray(deviation_m, float).reshape(2)
        if not (measured and np.isfinite(x).all()):
            self._history = []
            self._since_sample_s = 0.0
            return
        self._since_sample_s += self.dt_s
        if self._since_sample_s + 1e-9 < self.config.sample_s:
            return
        self._since_sample_s = 0.0
        lam = self._lambda
        self._ms = lam * self._ms + (1.0 - lam) * float(x @ x) / 2.0
        order = self.config.order
        if len(self._history) == order and math.sqrt(self._ms) >= self.config.min_rms_m:
            past = np.array(self._history[::-1])  # newest first: x_{k-1}, x_{k-2}, …
            for axis in range(2):
                self._rls(past[:, axis], float(x[axis]), lam if axis == 0 else 1.0)
            self.samples += 1
        self._history = [*self._history[1 - order :], x]

    def _rls(self, phi: FloatArray, y: float, lam: float) -> None:
        p_phi = self.cov @ phi
        gain = p_phi / (lam + float(phi @ p_phi))
        self.theta = self.theta + gain * (y - float(phi @ self.theta))
        self.cov = (self.cov - np.outer(gain, p_phi)) / lam

    def fitted(self) -> tuple[float, float] | None:
        """(ω rad/s, ζ) of the fit as it stands — its least damped stable complex pole pair,
        the swing's resonance — or None when it has no such pair."""
        poles = np.roots(np.concatenate([[1.0], -self.theta]))
        best: tuple[float, float] | None = None
        for z in poles:
            if z.imag <= 1e-9 or abs(z) >= 1.0:
                continue  # real (the forcing's colour) or unstable
            s = cmath.log(complex(z)) / self.config.sample_s
            omega = abs(s)
            zeta = -s.real / omega
            if best is None or zeta < best[1]:
                best = (omega, zeta)
        return best

    def estimate(self) -> SwingEstimate:
        """The swing to predict with: the fit once it is trusted, else the nominal model."""
        cfg = self.config
        nominal = SwingEstimate(
            self.prior.omega_rad_s, self.prior.damping_ratio, False, self.samples
        )
        if self.samples < cfg.min_samples:
            return nominal
        fit = self.fitted()
        if fit is None:
            return nominal
        omega, zeta = fit
        lo, hi = (k * self.prior.omega_rad_s for k in cfg.omega_range)
        if not (lo <= omega <= hi and cfg.zeta_range[0] <= zeta <= cfg.zeta_range[1]):
            return nominal
        return SwingEstimate(omega, zeta, True, self.samples)
