"""LQR state feedback with integral action (paper §6.1, eq. 20).

The plant ``x_{k+1} = A_d x_k + B_d u_k`` (zero-order hold at the tick) is augmented with the
integral of the tracking error ``ζ_{k+1} = ζ_k + Δt (C x_k − y*_k)``; the gain
``K = [K_p  K_i]`` comes from the discrete algebraic Riccati equation (python-control's
``dlqr`` with its ``integral_action`` on the lag- and rate-augmented plant: no cross weight is
needed), the discrete counterpart of eq. 20's ``K = −R⁻¹ Bᵀ P*``, for which
:func:`continuous_lqr` (python-control's ``lqr``) is also provided. Control law: ``u = −K_p (x̂ − x*) − K_i ζ``.

Rate-weighted form (``r_rate``, the A-4): the plant is further augmented with the previous
command ``u_{k−1}`` and the design's input is the increment ``Δu_k`` (:func:`augment_rate`), so
that R weighs the command's *rate* and Q its size: the law ``u_k = u_{k−1} − K z_k`` is a leaky
integrator of the feedback and rolls off above its bandwidth — sensor noise no longer drives
the surfaces onto their rate limits. ``u_{k−1}`` is the servo position actually reached (rate
and travel limits), so the command's memory cannot wind up; the tracking integrator ζ is
conditioned (not advanced on a tick whose command the actuators could not follow).
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np

from app.types import FloatArray


def continuous_lqr(a: FloatArray, b: FloatArray, q: FloatArray, r: FloatArray) -> FloatArray:
    """Eq. 20: ``K = R⁻¹ Bᵀ P*`` with P* the stabilising CARE solution (u = −K x;
    python-control's ``lqr``)."""
    k, _, _ = control.lqr(a, b, q, r)
    return np.asarray(k, float)


def discrete_lqr(
    ad: FloatArray,
    bd: FloatArray,
    q: FloatArray,
    r: FloatArray,
    integral_action: FloatArray | None = None,
) -> FloatArray:
    """``K = (R + Bᵀ P B)⁻¹ Bᵀ P A`` with P the stabilising DARE solution (u = −K x;
    python-control's ``dlqr``). ``integral_action`` (p×n): the plant is first augmented with
    ``ζ_{k+1} = ζ_k + integral_action x_k`` (python-control's augmentation, the same as
    :func:`augment_integral` with ``integral_action = Δt C``); ``q`` then weighs ``[x, ζ]``."""
    k, _, _ = control.dlqr(ad, bd, q, r, integral_action=integral_action)
    return np.asarray(k, float)


def augment_lag(
    ad: FloatArray, bd: FloatArray, alpha: float | FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Plant driven through first-order lags ``e_k = e_{k−1} + α (u_k − e_{k−1})`` (one α for
    all inputs, or one per input), ``x_{k+1} = A x_k + B e_k``: state ``[x_k, e_{k−1}]``,
    input ``u_k``."""
    n, m = bd.shape
    a_vec = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (m,))
    a_aug = np.zeros((n + m, n + m))
    a_aug[:n, :n] = ad
    a_aug[:n, n:] = bd * (1.0 - a_vec)
    a_aug[n:, n:] = np.diag(1.0 - a_vec)
    b_aug = np.vstack([bd * a_vec, np.diag(a_vec)])
    return a_aug, b_aug


def lag_alpha(dt: float, lag_s: float | tuple[float, ...]) -> float | FloatArray:
    """Per-tick gain α = 1 − exp(−Δt/τ) of a first-order lag (1: no lag); one per input when
    ``lag_s`` is a tuple (e.g. an engine's spool-up lag on the throttle, servo lags on the
    surfaces)."""
    if isinstance(lag_s, tuple):
        tau = np.asarray(lag_s, dtype=np.float64)
        safe = np.where(tau > 0, tau, 1.0)
        return np.where(tau > 0, 1.0 - np.exp(-dt / safe), 1.0)
    return 1.0 - float(np.exp(-dt / lag_s)) if lag_s > 0 else 1.0


def has_lag(lag_s: float | tuple[float, ...]) -> bool:
    """Whether any input has a modelled lag."""
    return bool(np.any(np.asarray(lag_s, dtype=np.float64) > 0))


def augment_rate(ad: FloatArray, bd: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Plant ``s_{k+1} = A s_k + B u_k`` with ``u_k = u_{k−1} + Δu_k``: state ``[s_k, u_{k−1}]``,
    input ``Δu_k`` (weights on Δu are weights on the command's rate)."""
    n, m = bd.shape
    a_aug = np.zeros((n + m, n + m))
    a_aug[:n, :n] = ad
    a_aug[:n, n:] = bd
    a_aug[n:, n:] = np.eye(m)
    b_aug = np.vstack([bd, np.eye(m)])
    return a_aug, b_aug


def augment_integral(
    ad: FloatArray, bd: FloatArray, c: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray]:
    """Discrete plant augmented with ``ζ_{k+1} = ζ_k + Δt C x_k`` (tracked outputs ``C x``)."""
    n, m = bd.shape
    p = c.shape[0]
    a_aug = np.zeros((n + p, n + p))
    a_aug[:n, :n] = ad
    a_aug[n:, :n] = dt * c
    a_aug[n:, n:] = np.eye(p)
    b_aug = np.vstack([bd, np.zeros((p, m))])
    return a_aug, b_aug


@dataclass
class IntegralLqr:
    """``u = −K_p (x̂ − x*) − K_e ê − K_i ζ`` with a bounded integrator.

    ``ke`` (with ``design_lag_s`` > 0): the lag-aware design — the gain also acts on the
    deflection ``ê`` that a servo lag of ``design_lag_s`` would have reached (a model state
    the caller propagates with :meth:`lag_step`)."""

    kp: FloatArray
    ki: FloatArray
    c: FloatArray
    dt: float
    integral_limit: float = 5.0
    # per-state bound on |x̂ − x*| fed to the gain (None: unbounded). Keeps the commands in the
    # linear range of the rate-limited actuators after a large reference jump (re-acquisition,
    # big start offset): the loop then closes the error at a bounded rate instead of saturating.
    error_clip: FloatArray | None = None
    output_error_clip: float = float("inf")
    ke: FloatArray | None = None
    design_lag_s: float | tuple[float, ...] = 0.0  # s; one for all inputs or one per input
    # rate-weighted form: gain on the previous command u_{k−1} (None: the plain law)
    ku: FloatArray | None = None
    # conditioned integration: ζ is not advanced on a tick whose command was limited
    anti_windup: bool = True

    @classmethod
    def design(
        cls,
        ad: FloatArray,
        bd: FloatArray,
        c: FloatArray,
        dt: float,
        q_state: FloatArray,
        q_int: FloatArray,
        r: FloatArray,
        design_lag_s: float | tuple[float, ...] = 0.0,
        q_lag: float = 0.0,
        r_rate: FloatArray | None = None,
    ) -> IntegralLqr:
        """Eq. 20 gains on the plant augmented with the integral of ``C x``; with
        ``design_lag_s`` > 0 the plant is first augmented with a servo lag of that time
        constant (:func:`augment_lag`; its states weighted by ``q_lag``). With ``r_rate``
        (one weight per input, on Δu per tick) the rate-weighted form: ``r`` then weighs the
        command's size ``u_{k−1}`` (a state) and ``r_rate`` its increment (the input)."""
        n, m = bd.shape
        if r_rate is not None:
            return cls._design_rate(ad, bd, c, dt, q_state, q_int, r, r_rate, design_lag_s)
        if has_lag(design_lag_s):
            a_l, b_l = augment_lag(ad, bd, lag_alpha(dt, design_lag_s))
            c_l = np.hstack([c, np.zeros((c.shape[0], m))])
            q = np.diag(np.concatenate([q_state, np.full(m, q_lag), q_int]))
            k = discrete_lqr(a_l, b_l, q, np.diag(r), integral_action=dt * c_l)
            return cls(
                kp=k[:, :n],
                ki=k[:, n + m :],
                c=c,
                dt=dt,
                ke=k[:, n : n + m],
                design_lag_s=design_lag_s,
            )
        q = np.diag(np.concatenate([q_state, q_int]))
        k = discrete_lqr(ad, bd, q, np.diag(r), integral_action=dt * c)
        return cls(kp=k[:, :n], ki=k[:, n:], c=c, dt=dt)

    @classmethod
    def _design_rate(
        cls,
        ad: FloatArray,
        bd: FloatArray,
        c: FloatArray,
        dt: float,
        q_state: FloatArray,
        q_int: FloatArray,
        r: FloatArray,
        r_rate: FloatArray,
        design_lag_s: float | tuple[float, ...],
    ) -> IntegralLqr:
        """The rate-weighted design: state ``[x, e_{k−1}, u_{k−1}, ζ]``, input ``Δu``."""
        n, m = bd.shape
        a_l, b_l = augment_lag(ad, bd, lag_alpha(dt, design_lag_s))
        a_r, b_r = augment_rate(a_l, b_l)
        c_r = np.hstack([c, np.zeros((c.shape[0], 2 * m))])
        q = np.diag(np.concatenate([q_state, np.zeros(m), np.asarray(r, float), q_int]))
        k = discrete_lqr(a_r, b_r, q, np.diag(np.asarray(r_rate, float)), integral_action=dt * c_r)
        return cls(
            kp=k[:, :n],
            ki=k[:, n + 2 * m :],
            c=c,
            dt=dt,
            ke=k[:, n : n + m],
            design_lag_s=design_lag_s,
            ku=k[:, n + m : n + 2 * m],
        )

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.zeta = np.zeros(self.c.shape[0])
        m = self.kp.shape[0]
        self.e_hat = np.zeros(m)  # modelled servo deflection (deviation), lag-aware design
        self.u_prev = np.zeros(m)  # the servo position reached last tick (deviation)
        self._zeta_before = self.zeta.copy()
        self._u_cmd: FloatArray | None = None
        self._u_ff = np.zeros(m)  # the feed-forward in the last command

    def lag_step(self, servo_dev: FloatArray) -> FloatArray:
        """Advance the modelled deflection ``ê`` towards the servo position (deviation from
        trim) by one tick of the design lag; return it (the servo position without a lag)."""
        servo = np.asarray(servo_dev, float)
        if (
            self.anti_windup
            and self._u_cmd is not None
            and np.any(np.abs(servo - self._u_cmd) > 1e-9)
        ):
            self.zeta = self._zeta_before  # the actuators could not follow: no integration
        self._u_cmd = None
        self.u_prev = servo - self._u_ff  # the feedback's share of the servo position
        alpha = lag_alpha(self.dt, self.design_lag_s)
        self.e_hat = np.asarray(self.e_hat + alpha * (servo - self.e_hat))
        return self.e_hat

    def closed_loop_matrix(self, ad: FloatArray, bd: FloatArray) -> FloatArray:
        """Augmented closed-loop transition matrix, state feedback on ``[x, (e), ζ]`` (the
        servo-lag states ``e`` with the lag-aware design), for stability checks."""
        if self.ku is not None and self.ke is not None:
            m = bd.shape[1]
            a_l, b_l = augment_lag(ad, bd, lag_alpha(self.dt, self.design_lag_s))
            a_r, b_r = augment_rate(a_l, b_l)
            c_r = np.hstack([self.c, np.zeros((self.c.shape[0], 2 * m))])
            a_aug, b_aug = augment_integral(a_r, b_r, c_r, self.dt)
            return a_aug - b_aug @ np.hstack([self.kp, self.ke, self.ku, self.ki])
        if self.ke is not None:
            m = bd.shape[1]
            a_l, b_l = augment_lag(ad, bd, lag_alpha(self.dt, self.design_lag_s))
            c_l = np.hstack([self.c, np.zeros((self.c.shape[0], m))])
            a_aug, b_aug = augment_integral(a_l, b_l, c_l, self.dt)
            return a_aug - b_aug @ np.hstack([self.kp, self.ke, self.ki])
        a_aug, b_aug = augment_integral(ad, bd, self.c, self.dt)
        return a_aug - b_aug @ np.hstack([self.kp, self.ki])

    def control(
        self,
        x_hat: FloatArray,
        x_ref: FloatArray,
        y_ref: FloatArray,
        u_ff: FloatArray | None = None,
    ) -> FloatArray:
        """Control deviation from trim (feedback plus the feed-forward ``u_ff``, if any);
        advances the integrator by one tick."""
        dx = x_hat - x_ref
        if self.error_clip is not None:
            dx = np.clip(dx, -self.error_clip, self.error_clip)
        fb = self.kp @ dx + self.ki @ self.zeta
        if self.ke is not None:
            fb = fb + self.ke @ self.e_hat
        if self.ku is not None:  # rate-weighted form: u_k = u_{k−1} − K z_k
            u = self.u_prev - fb - self.ku @ self.u_prev
        else:
            u = -fb
        err = np.clip(self.c @ x_hat - y_ref, -self.output_error_clip, self.output_error_clip)
        self._zeta_before = self.zeta.copy()
        self.zeta = np.clip(self.zeta + self.dt * err, -self.integral_limit, self.integral_limit)
        if u_ff is not None:
            u = u + np.asarray(u_ff, float)
        self._u_ff = np.zeros_like(u) if u_ff is None else np.asarray(u_ff, float).copy()
        self._u_cmd = np.asarray(u, float).copy()
        return np.asarray(u)

    def hand_over(self, servo_dev: FloatArray) -> None:
        """Bumpless take-over from another law (run-time assurance): the integrators start
        empty and the command's memory at the servo position now."""
        self.zeta = np.zeros(self.c.shape[0])
        self._zeta_before = self.zeta.copy()
        self._u_cmd = None
        self._u_ff = np.zeros_like(self.u_prev)
        self.u_prev = np.asarray(servo_dev, float).copy()
        self.e_hat = self.u_prev.copy()
