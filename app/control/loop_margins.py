"""Classical and disk stability margins of the docking loop at the plant input, with
python-control (``stability_margins``, ``feedback``, frequency responses).

The loop is exactly the one :mod:`app.sim.docking` runs each tick (clips, rate limits and the
reference left out: the small-signal loop, as in :mod:`app.control.margins`):

* the controller ``K`` (:func:`controller_ss`): the observer (eq. 19), the modelled lag ``ê``,
  the previous command of the rate-weighted form and the integrator ζ (eq. 20), from the INS
  measurements ``y_k`` to the command ``u_k``;
* the plant ``P`` (:func:`plant_ss`): the servos' first-order lag ``τ`` (an imperfection
  preset's), an input delay of whole ticks, the linearised aircraft, to ``y_k = C x_k``.

The loop broken at the plant input is ``L = −K P`` (negative-feedback convention). Per loop
(:attr:`LoopMargins.per_loop`): channel i broken, the other three closed — gain margin (dB),
phase margin (°) and the delay margin (s) it implies (phase margin / crossover). All loops at
once (:attr:`LoopMargins.disk`): the balanced disk margin α = 1 / max_ω σ̄((S − T)/2) with
``S = (I + L)⁻¹``, ``T = L S`` — an unstructured (full-block) bound, so it covers every
simultaneous gain and phase change of all four inputs, coupled or not; it gives a symmetric
gain margin ``±20 log₁₀((1 + α/2)/(1 − α/2))`` dB and a phase margin ``2 atan(α/2)``
(Seiler, Packard & Gahinet, "An introduction to disk margins", IEEE CSM 2020).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control
import numpy as np

from app.control.design import ControllerDesign
from app.control.lqr import has_lag, lag_alpha
from app.types import FloatArray

INPUTS = ("throttle", "aileron", "elevator", "rudder")


@dataclass(frozen=True)
class SingleLoopMargin:
    """One input's loop broken, the others closed."""

    name: str
    gain_margin_db: float  # the gain increase to instability (dB; inf: none)
    gain_reduction_margin_db: float  # the gain decrease to instability (dB, ≤ 0; −inf: none)
    phase_margin_deg: float  # the smallest over the gain crossovers (inf when none)
    delay_margin_s: float  # phase margin / crossover frequency (inf: none)
    crossover_rad_s: float


@dataclass(frozen=True)
class DiskMargin:
    """All inputs perturbed at once (balanced, unstructured disk margin)."""

    alpha: float
    gain_margin_db: float  # symmetric ±
    phase_margin_deg: float
    worst_frequency_rad_s: float


@dataclass(frozen=True)
class LoopMargins:
    per_loop: tuple[SingleLoopMargin, ...]
    disk: DiskMargin
    servo_lag_s: float
    delay_ticks: int


def _matrices(
    step: object, n_state: int, n_in: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(A, B, C, D) of a linear map ``(state, input) → (next state, output)`` by columns."""
    fn = step  # type: ignore[assignment]
    cols_x = [fn(np.eye(n_state)[j], np.zeros(n_in)) for j in range(n_state)]  # type: ignore[operator]
    cols_u = [fn(np.zeros(n_state), np.eye(n_in)[j]) for j in range(n_in)]  # type: ignore[operator]
    a = np.column_stack([c[0] for c in cols_x]) if n_state else np.zeros((0, 0))
    c = np.column_stack([c[1] for c in cols_x]) if n_state else np.zeros((0, 0))
    b = np.column_stack([c[0] for c in cols_u])
    d = np.column_stack([c[1] for c in cols_u])
    return a, b, c, d


def controller_ss(
    a: FloatArray,
    b: FloatArray,
    c_meas: FloatArray,
    obs_gain: FloatArray,
    kp: FloatArray,
    ki: FloatArray,
    c_tip: FloatArray,
    dt: float,
    ke: FloatArray | None = None,
    ku: FloatArray | None = None,
    design_lag_s: float | tuple[float, ...] = 0.0,
) -> control.StateSpace:
    """The controller as a discrete state space from the INS measurements ``y_k`` to the
    command ``u_k`` (state ``[x̂_{k−1}, ê_{k−1}, u_{k−1}, ζ_k]``; see the simulation's tick)."""
    n, m = b.shape
    p = c_tip.shape[0]
    ny = c_meas.shape[0]
    lag = has_lag(design_lag_s)
    alpha_d = lag_alpha(dt, design_lag_s)
    eye_lc = np.eye(n) - obs_gain @ c_meas

    def step(z: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
        xh_prev, e_prev, u_prev, zeta = z[:n], z[n : n + m], z[n + m : n + 2 * m], z[n + 2 * m :]
        acted = e_prev if lag else u_prev
        xh = eye_lc @ (a @ xh_prev + b @ acted) + obs_gain @ y
        fb = kp @ xh + ki @ zeta
        if ke is not None and lag:
            fb = fb + ke @ e_prev
        u = u_prev - fb - ku @ u_prev if ku is not None else -fb
        e = e_prev + alpha_d * (u - e_prev) if lag else u
        return np.concatenate([xh, e, u, zeta + dt * (c_tip @ xh)]), u

    a_c, b_c, c_c, d_c = _matrices(step, n + 2 * m + p, ny)
    return control.ss(a_c, b_c, c_c, d_c, dt)


def plant_ss(
    a: FloatArray,
    b: FloatArray,
    c_meas: FloatArray,
    dt: float,
    lag_s: float = 0.0,
    delay_ticks: int = 0,
) -> control.StateSpace:
    """The aircraft behind a first-order servo lag ``lag_s`` and ``delay_ticks`` of input delay,
    from the command ``u_k`` to the INS measurements ``y_k = C x_k`` (state ``[x_k, e_{k−1},
    u_{k−1..k−d}]``)."""
    n, m = b.shape
    d = int(delay_ticks)
    alpha = 1.0 - math.exp(-dt / lag_s) if lag_s > 0 else 1.0

    def step(s: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        x, e_prev = s[:n], s[n : n + m]
        hist = [s[n + m + j * m : n + m + (j + 1) * m] for j in range(d)]
        applied = hist[d - 1] if d else u
        e = e_prev + alpha * (applied - e_prev)
        new_hist = [u, *hist[:-1]] if d else []
        return np.concatenate([a @ x + b @ e, e, *new_hist]), c_meas @ x

    a_p, b_p, c_p, d_p = _matrices(step, n + m + d * m, m)
    return control.ss(a_p, b_p, c_p, d_p, dt)


def loop_transfer(controller: control.StateSpace, plant: control.StateSpace) -> control.StateSpace:
    """``L = −K P`` broken at the plant input (negative-feedback convention)."""
    return -1.0 * control.series(plant, controller)


def _single_loop(loop: control.StateSpace, i: int, name: str, dt: float) -> SingleLoopMargin:
    m = loop.ninputs
    closed = np.diag([0.0 if j == i else 1.0 for j in range(m)])
    li = control.feedback(loop, closed)[i, i]
    w = np.geomspace(1e-3, math.pi / dt * 0.999, 4000)
    frd = control.frd(li, w)  # on a dense grid: the polynomial method is ill-conditioned here
    gms, pms, _sm, _wpc, wgcs, _wms = control.stability_margins(frd, returnall=True)
    gms_db = [20.0 * math.log10(g) for g in np.atleast_1d(gms) if np.isfinite(g) and g > 0]
    up = min((g for g in gms_db if g > 0), default=math.inf)
    down = max((g for g in gms_db if g <= 0), default=-math.inf)
    pm, wgc, delay = math.inf, math.nan, math.inf
    for p_deg, w_c in zip(np.atleast_1d(pms), np.atleast_1d(wgcs), strict=True):
        p_wrapped = (float(p_deg) + 180.0) % 360.0 - 180.0
        if w_c > 0 and p_wrapped < pm:
            pm, wgc = p_wrapped, float(w_c)
        if w_c > 0:
            delay = min(delay, math.radians(p_wrapped % 360.0) / float(w_c))
    return SingleLoopMargin(name, up, down, pm, delay, wgc)


def disk_margin(loop: control.StateSpace, dt: float, points: int = 600) -> DiskMargin:
    """Balanced unstructured disk margin of the MIMO loop (module docstring)."""
    w = np.geomspace(1e-3, math.pi / dt * 0.999, points)
    m = loop.ninputs
    resp = np.asarray(loop(np.exp(1j * w * dt))).reshape(m, m, len(w))  # SISO: 1-D
    worst, w_worst = 0.0, float(w[0])
    for k in range(len(w)):
        lk = np.asarray(resp[:, :, k]).reshape(m, m)
        s = np.linalg.inv(np.eye(m) + lk)
        t = lk @ s
        sv = float(np.linalg.svd(0.5 * (s - t), compute_uv=False)[0])
        if sv > worst:
            worst, w_worst = sv, float(w[k])
    alpha = 1.0 / worst
    half = alpha / 2.0
    gm = 20.0 * math.log10((1 + half) / (1 - half)) if half < 1 else math.inf
    return DiskMargin(alpha, gm, math.degrees(2.0 * math.atan(half)), w_worst)


def loop_margins(
    controller: control.StateSpace,
    a: FloatArray,
    b: FloatArray,
    c_meas: FloatArray,
    dt: float,
    lag_s: float = 0.0,
    delay_ticks: int = 0,
) -> LoopMargins:
    """Per-loop and all-at-once margins of ``controller`` on the plant ``(a, b)`` behind a servo
    lag ``lag_s`` and ``delay_ticks`` of input delay."""
    loop = loop_transfer(controller, plant_ss(a, b, c_meas, dt, lag_s, delay_ticks))
    per = tuple(_single_loop(loop, i, INPUTS[i], dt) for i in range(loop.ninputs))
    return LoopMargins(per, disk_margin(loop, dt), lag_s, delay_ticks)


def design_margins(design: ControllerDesign, dt: float, lag_s: float = 0.0) -> LoopMargins:
    """:func:`loop_margins` of a designed controller (:mod:`app.control.design`) on its own
    design model behind a servo lag ``lag_s`` (s)."""
    k = controller_ss(
        design.ad,
        design.bd,
        design.c_meas,
        design.obs_gain,
        design.lqr_kp,
        design.lqr_ki,
        design.c_tip,
        dt,
        ke=design.lqr_ke,
        ku=design.lqr_ku,
        design_lag_s=design.lqr_design_lag_s,
    )
    return loop_margins(k, design.ad, design.bd, design.c_meas, dt, lag_s=lag_s)
