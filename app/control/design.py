"""The docking controller's design (paper §6): observer (eq. 19) + LQR with integral action
(eq. 20) on a plant's linearisation about its trim (:class:`~app.control.linear_model.LinearModel`).

:func:`design_controller` turns a linear model, the tick, the probe-tip lever arm and a set of
weights (:class:`DesignWeights`) into a :class:`ControllerDesign`: the discretised model, the
tracked output (the probe tip in the tanker frame), the LQR gains of the lag-aware design (the
plant behind each input's own first-order lag: the engine's spool-up on the throttle, servos
on the surfaces) and the observer gain. The simulation (:mod:`app.sim.docking`) and the tests
import it; the plants live in :mod:`app.sim`.

Two weight sets:

* :data:`AEROSONDE_WEIGHTS` — the 11 kg Aerosonde design model of :mod:`app.sim.receiver`
  (the linear plant; weights from a robustness search over the plant spread);
* :data:`A4_WEIGHTS` — the A-4 on JSBSim (:mod:`app.sim.jsbsim_plant`), normalised commands.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from app.control.linear_model import LinearModel
from app.control.lqr import IntegralLqr
from app.control.observer import StateObserver
from app.geometry.rotations import euler_to_matrix
from app.types import FloatArray

MEASURED_STATES = (3, 4, 5, 6, 7, 8, 9, 10, 11)  # p q r φ θ ψ x y z (INS-like)


@dataclass(frozen=True)
class DesignWeights:
    """LQR and observer weights (state order u v w p q r φ θ ψ x y z; inputs as the model)."""

    q_state: tuple[float, ...]  # 12
    q_int: tuple[float, float, float]  # integral of the probe-tip error x, y, z
    r: tuple[float, float, float, float]
    # |x̂ − x*| bounds fed to the gain (only the positions: a reference jump then closes at a
    # bounded rate; velocities, rates and angles keep their full feedback, the damping)
    error_clip: tuple[float, ...]
    # per tick: (m/s)², (rad/s)² on u v w p q r — model uncertainty, so that the observer leans
    # on the INS rather than on the design model's prediction
    observer_model_q: tuple[float, ...]
    meas_sigma: tuple[float, ...] = (0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.01, 0.01, 0.01)
    # the rate-weighted form (app.control.lqr): weights on each command's increment per tick;
    # ``r`` then weighs the command's size (None: the plain law)
    r_rate: tuple[float, float, float, float] | None = None
    # loop-transfer recovery: fictitious process noise on the inputs (B Bᵀ × this, per tick),
    # so that the observer gives back the state feedback's margins at the plant input
    observer_input_q: float = 0.0


# On the Aerosonde design model: chosen for robustness over the plant spread, not per run —
# every plant in 100 draws of the `standard` distribution (design seeds
# 100000–100099, never the campaign's) keeps ≥ 2 ticks (40 ms) of extra input-delay margin with
# the 30 ms actuator lag, the nominal loop ≥ 3 ticks with up to 100 ms of lag
# (app.control.margins, tests); among those, the tightest tracking in truth-measurement runs (a
# random search over the weights). Side velocity v and yaw rate r weighted (sideslip, Dutch
# roll damping), lateral position and its integral ×4, vertical ×2.6 (the bow wave lifts the
# drogue in the last metre), rudder R ×4. The observer's model uncertainty ×1000 over the first
# tuning (1e-2): the side velocity v is not measured, and an observer that trusted the design
# model's v̂ fed a wrong sideslip to the LQR when the flown aircraft was ±20 % off. The search
# and its figures: docs/control.md.
AEROSONDE_WEIGHTS = DesignWeights(
    q_state=(2.0, 20.0, 2.0, 0.1, 0.1, 8.0, 2.0, 9.0, 9.0, 5.0, 2600.0, 1550.0),
    q_int=(3.0, 1300.0, 775.0),
    r=(300.0, 1.2e5, 4.6e5, 1.5e6),  # throttle, aileron, elevator, rudder (rad)
    error_clip=(np.inf,) * 9 + (0.6, 0.6, 0.6),
    observer_model_q=(10.0,) * 6 + (0.0,) * 6,
)

# The A-4 at 15 000 ft / 230 KCAS on normalised commands (aileron 1 = 0.35 rad; rudder command
# clipped at ±0.35 by the shipped FCS). Bryson-style tolerances (Q = 1/x_max², R = 1/u_max²)
# chosen by a Nelder–Mead search on the design model itself: the probe tip holding a fixed
# point in light Dryden turbulence with the INS noise and the engine's spool-up lag, minimising
# its lateral and vertical variance plus its fore-aft variance, with every command's standard
# deviation held to a quarter of its travel from trim (tip σ 0.17 / 0.13 / 0.11 m x / y / z,
# commands 0.25–0.27 of their travel); docs/models.md. Tolerances (m/s, rad/s, rad, m; commands
# normalised): u v w 2.22, p q r 0.243, φ 0.567, θ 0.407, ψ 0.227, x 0.325, y z 0.119;
# integrals x 0.596, y z 0.209 m·s; throttle 0.0079, aileron 0.0348, elevator 0.0468, rudder
# 0.0188. Then, from truth-measurement campaigns, the fore-aft loop stiffened (x 0.158 m,
# throttle 0.05: a heavily penalised throttle lags the closure and overshoots a stop) and y z
# ×2.5 in Q (0.075 m, integrals 0.132 m·s: the tip closer to its reference in the last metre;
# ×3 asks for more than a tenth of the elevator's travel for a 0.1 m error, which a test
# refuses). The campaigns behind each step: docs/control.md.
A4_WEIGHTS = DesignWeights(
    q_state=(0.2029, 0.2029, 0.2029, 16.89, 16.89, 16.89, 3.106, 6.034, 19.42, 40.0, 178.0, 178.0),
    q_int=(2.816, 57.4, 57.4),
    # the rate-weighted form: r on the commands' size (throttle ×10, aileron ×3.6, elevator
    # ×17.5 over the plain design's 400 / 825.7 / 456.6 / 2829), r_rate on their increments per
    # tick — chosen on the margins of app.control.loop_margins (every loop ≥ 45° and ≥ 6 dB
    # with the `standard` servo lag, all at once ≥ ±4 dB / 30° and ≥ 160 ms of delay with the
    # `harsh` lag) and the surfaces' time on their rate limits in calm air with the INS noise
    # (docs/control.md, "Safety")
    r=(4000.0, 3000.0, 8000.0, 2829.0),
    error_clip=(np.inf,) * 9 + (0.6, 0.6, 0.6),
    # u v w are not measured: with the Aerosonde's 10 (m/s)² per tick the observer took them
    # from the differentiated position fixes (σ 1 cm at 50 Hz) and that noise flew the tip;
    # 10⁻² on u v w trusts the design model, which is the FDM's own nonlinear aircraft
    # linearised (at most lighter). Calm-air misses before and after: docs/control.md
    observer_model_q=(0.01,) * 3 + (10.0,) * 3 + (0.0,) * 6,
    r_rate=(2.0e5, 2.0e4, 1.0e4, 2.0e4),
)


@dataclass
class ControllerDesign:
    """A designed controller and the model it was designed on."""

    model: LinearModel
    ad: FloatArray
    bd: FloatArray
    ed: FloatArray
    c_tip: FloatArray  # ∂(probe tip, tanker frame)/∂x at trim
    tip0_b: FloatArray  # R(trim) r_probe: tip offset from CG at trim attitude
    lqr_kp: FloatArray
    lqr_ki: FloatArray
    lqr_ke: FloatArray | None  # gain on the modelled input lags' deflections (lag-aware design)
    lqr_ku: FloatArray | None  # gain on the previous command (rate-weighted design)
    lqr_design_lag_s: float | tuple[float, ...]
    obs_gain: FloatArray
    c_meas: FloatArray
    meas_sigma: FloatArray
    weights: DesignWeights

    @property
    def error_clip(self) -> FloatArray:
        return np.asarray(self.weights.error_clip, dtype=np.float64)

    def margin_loop(self, dt: float, **extra: Any) -> dict[str, Any]:
        """Keyword arguments of :func:`app.control.margins.closed_loop_matrix` for this design
        (observer, LQR, modelled lags); ``extra`` adds or overrides (``lag_s``, ``plant``…)."""
        loop: dict[str, Any] = dict(
            a=self.ad,
            b=self.bd,
            c_meas=self.c_meas,
            obs_gain=self.obs_gain,
            kp=self.lqr_kp,
            ki=self.lqr_ki,
            ke=self.lqr_ke,
            design_lag_s=self.lqr_design_lag_s,
            ku=self.lqr_ku,
            c_tip=self.c_tip,
            dt=dt,
        )
        return {**loop, **extra}


def closure_feedforward(model: LinearModel) -> tuple[FloatArray, FloatArray]:
    """The steady state and commands of a constant closure: per m/s of fore-aft ground speed
    relative to the tanker, the state deviation (12; positions 0) and the command deviation
    (4) with every velocity, rate and angle steady and no lateral or vertical drift — the
    minimum-norm solution of ``A x + B δ = (0…0, 1, 0, 0)`` (rows u…ψ, then ẋ ẏ ż).

    Fed forward with the closure's reference speed, the commands no longer wait for the
    integrators: at the A-4's heavily penalised throttle the integrator built up the closure's
    thrust with a 1.3 m lag and, when the reference stopped, overshot the gap by 1.5 m."""
    a, b = model.a, model.b
    m = np.hstack([a[:, :9], b])  # unknowns: u … ψ, commands (positions do not enter)
    rhs = np.zeros(12)
    rhs[9] = 1.0
    sol = np.linalg.lstsq(m, rhs, rcond=None)[0]
    x = np.zeros(12)
    x[:9] = sol[:9]
    return x, np.asarray(sol[9:])


def tip_jacobian(theta0: float, r_probe: FloatArray) -> FloatArray:
    """∂(R_TB(φ, θ₀ + θ, ψ) r_probe)/∂(φ, θ, ψ) at zero perturbation (3×3)."""

    def tip(angles: FloatArray) -> FloatArray:
        return euler_to_matrix(angles[0], theta0 + angles[1], angles[2]) @ r_probe

    cols = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1e-6
        cols.append((tip(e) - tip(-e)) / 2e-6)
    return np.column_stack(cols)


def design_controller(
    model: LinearModel,
    dt: float,
    probe_tip_body_m: tuple[float, float, float],
    weights: DesignWeights,
) -> ControllerDesign:
    """Observer + integral LQR (eqs. 19–20) on ``model`` at the tick ``dt`` (s), tracking the
    probe tip at ``probe_tip_body_m`` (body frame, m, from the CG)."""
    ad, bd, ed = model.discretise(dt)
    r_probe = np.asarray(probe_tip_body_m, dtype=np.float64)
    theta0 = model.theta0
    c_tip = np.zeros((3, 12))
    c_tip[:, 6:9] = tip_jacobian(theta0, r_probe)
    c_tip[:, 9:12] = np.eye(3)
    tip0 = euler_to_matrix(0.0, theta0, 0.0) @ r_probe
    lags = model.input_lag_s
    design_lag: float | tuple[float, ...] = lags[0] if len(set(lags)) == 1 else tuple(lags)
    ctrl = IntegralLqr.design(
        ad,
        bd,
        c_tip,
        dt,
        np.asarray(weights.q_state, dtype=np.float64),
        np.asarray(weights.q_int, dtype=np.float64),
        np.asarray(weights.r, dtype=np.float64),
        design_lag_s=design_lag,
        r_rate=None if weights.r_rate is None else np.asarray(weights.r_rate, dtype=np.float64),
    )
    c_meas = np.zeros((len(MEASURED_STATES), 12))
    for row, idx in enumerate(MEASURED_STATES):
        c_meas[row, idx] = 1.0
    meas_sigma = np.asarray(weights.meas_sigma, dtype=np.float64)
    # process noise: the gusts (E_d E_dᵀ·4) plus model uncertainty on the velocities and rates
    # (the flown aircraft is not the design model), so the observer leans on the INS
    q0 = (
        ed @ ed.T * 4.0
        + np.diag(weights.observer_model_q)
        + bd @ bd.T * weights.observer_input_q
        + np.eye(12) * 1e-6
    )
    obs = StateObserver(ad, bd, c_meas, q0, np.diag(meas_sigma**2))
    return ControllerDesign(
        model=model,
        ad=ad,
        bd=bd,
        ed=ed,
        c_tip=c_tip,
        tip0_b=tip0,
        lqr_kp=ctrl.kp,
        lqr_ki=ctrl.ki,
        lqr_ke=ctrl.ke,
        lqr_ku=ctrl.ku,
        lqr_design_lag_s=ctrl.design_lag_s,
        obs_gain=obs.gain,
        c_meas=c_meas,
        meas_sigma=meas_sigma,
        weights=weights,
    )
