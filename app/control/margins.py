"""Stability margins of the docking loop's inner loop: observer (eq. 19) + LQR with integral
action (eq. 20) on a plant with actuator lag and input delay.

:func:`closed_loop_matrix` builds the linear closed-loop transition of exactly the loop the
simulation runs each tick (clips and rate limits left out: the small-signal loop):

* ``x̂_k = (I − L C)(A x̂_{k−1} + B u_{k−1}) + L C x_k`` (observer on the own-state sensors);
* ``u_k = −K_p x̂_k − K_i ζ_k``; ``ζ_{k+1} = ζ_k + Δt C_tip x̂_k`` (reference 0);
* the command reaches the surfaces ``delay`` ticks later through a first-order lag
  (``e_k = e_{k−1} + α (u_{k−delay} − e_{k−1})``, α = 1 − exp(−Δt/τ));
* ``x_{k+1} = A_p x_k + B_p e_k`` (the plant may differ from the design model ``A, B``).

The loop is stable iff the spectral radius is below 1. :func:`delay_margin_ticks` is the
largest extra input delay that keeps it stable; :func:`gain_margins` the range of a common
scale on the feedback gain that does.
"""

from __future__ import annotations

import numpy as np

from app.control.lqr import has_lag, lag_alpha
from app.types import FloatArray


def closed_loop_matrix(
    a: FloatArray,
    b: FloatArray,
    c_meas: FloatArray,
    obs_gain: FloatArray,
    kp: FloatArray,
    ki: FloatArray,
    c_tip: FloatArray,
    dt: float,
    lag_s: float = 0.0,
    delay_ticks: int = 0,
    plant: tuple[FloatArray, FloatArray] | None = None,
    gain_scale: float = 1.0,
    ke: FloatArray | None = None,
    design_lag_s: float | tuple[float, ...] = 0.0,
    ku: FloatArray | None = None,
) -> FloatArray:
    """Transition matrix of [x, x̂_{k−1}, u_{k−1..k−1−delay}, ζ, e, ê] (module docstring).

    ``design_lag_s`` > 0: the controller models a servo lag of that time constant (the lag-aware
    design, :meth:`app.control.lqr.IntegralLqr.design`): its modelled deflection
    ``ê_k = ê_{k−1} + α_d (u_k − ê_{k−1})`` drives the observer's prediction and enters the
    feedback through ``ke`` (``u_k = −K_p x̂_k − K_e ê_{k−1} − K_i ζ_k``). ``ku``: the
    rate-weighted form, ``u_k = u_{k−1} − (K_p x̂_k + K_e ê_{k−1} + K_u u_{k−1} + K_i ζ_k)``."""
    ap, bp = plant if plant is not None else (a, b)
    n, m = b.shape
    p = c_tip.shape[0]
    d = int(delay_ticks)
    alpha = 1.0 - float(np.exp(-dt / lag_s)) if lag_s > 0 else 1.0
    # state layout
    ix = slice(0, n)
    ih = slice(n, 2 * n)
    iu = [slice(2 * n + j * m, 2 * n + (j + 1) * m) for j in range(d + 1)]  # u_{k-1-j}
    iz = slice(2 * n + (d + 1) * m, 2 * n + (d + 1) * m + p)
    ie = slice(iz.stop, iz.stop + m)
    lag_model = has_lag(design_lag_s)
    ieh = slice(ie.stop, ie.stop + (m if lag_model else 0))
    alpha_d = lag_alpha(dt, design_lag_s)
    size = ieh.stop
    eye_lc = np.eye(n) - obs_gain @ c_meas
    out = np.zeros((size, size))
    for col in range(size):
        s = np.zeros(size)
        s[col] = 1.0
        x, xh_prev, zeta, e_prev = s[ix], s[ih], s[iz], s[ie]
        u_hist = [s[sl] for sl in iu]
        e_hat = s[ieh] if lag_model else u_hist[0]  # what the observer believes acted
        xh = eye_lc @ (a @ xh_prev + b @ e_hat) + obs_gain @ (c_meas @ x)
        fb = kp @ xh + ki @ zeta
        if lag_model and ke is not None:
            fb = fb + ke @ e_hat
        if ku is not None:  # rate-weighted form: u_k = u_{k−1} − K z_k (its memory: u_{k−1})
            u = u_hist[0] - gain_scale * (fb + ku @ u_hist[0])
        else:
            u = -gain_scale * fb
        applied = u if d == 0 else u_hist[d - 1]
        e = e_prev + alpha * (applied - e_prev)
        new = np.zeros(size)
        new[ix] = ap @ x + bp @ e
        new[ih] = xh
        new[iu[0]] = u
        for j in range(1, d + 1):
            new[iu[j]] = u_hist[j - 1]
        new[iz] = zeta + dt * (c_tip @ xh)
        new[ie] = e
        if lag_model:
            new[ieh] = e_hat + alpha_d * (u - e_hat)
        out[:, col] = new
    return out


def spectral_radius(matrix: FloatArray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(matrix))))


def delay_margin_ticks(max_ticks: int = 20, **loop: object) -> int:
    """Largest input delay (ticks, ≤ ``max_ticks``) with a stable loop; −1 if none is."""
    best = -1
    for d in range(max_ticks + 1):
        if spectral_radius(closed_loop_matrix(delay_ticks=d, **loop)) < 1.0:  # type: ignore[arg-type]
            best = d
        else:
            break
    return best


def gain_margins(scales: FloatArray | None = None, **loop: object) -> tuple[float, float]:
    """(lowest, highest) common feedback-gain scale of a contiguous stable range around 1."""
    grid = np.asarray(scales if scales is not None else np.geomspace(0.05, 20.0, 121))
    stable = [
        spectral_radius(closed_loop_matrix(gain_scale=float(g), **loop)) < 1.0  # type: ignore[arg-type]
        for g in grid
    ]
    i1 = int(np.argmin(np.abs(grid - 1.0)))
    if not stable[i1]:
        return (float("nan"), float("nan"))
    lo = hi = i1
    while lo > 0 and stable[lo - 1]:
        lo -= 1
    while hi < len(grid) - 1 and stable[hi + 1]:
        hi += 1
    return float(grid[lo]), float(grid[hi])
