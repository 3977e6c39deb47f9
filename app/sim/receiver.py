"""Receiver UAV: 12-state rigid-body model linearised about straight-and-level trim.

State (perturbations about trim) ``x = [u, v, w, p, q, r, φ, θ, ψ, x, y, z]``: body-axis velocity
(m/s), body rates (rad/s), Euler angles (rad), and the centre-of-gravity position in the tanker
frame (m, x forward, y right, z down; the tanker flies at the trim airspeed, so the position
equation is ``ṗ_T = R_TB v_B − (V, 0, 0)``). Inputs (deviations from trim)
``δ = [throttle (0–1), aileron, elevator, rudder (rad)]``; gust input ``g`` (m/s, tanker axes).

Parameter set: the Aerosonde small UAV of Beard & McLain, *Small Unmanned Aircraft: Theory and
Practice* (Princeton UP, 2012), Appendix E / the authors' ``mavsim`` ``aerosonde_parameters.py``
(mass 11 kg, J_x 0.824, J_y 1.135, J_z 1.759, J_xz 0.120 kg·m², S 0.55 m², b 2.8956 m,
c 0.18994 m, and the stability and control derivatives below). The force/moment model is the
book's linear-coefficient model (ch. 4). Our departures, stated plainly: the flight condition is
the AAR one (3000 m, ρ 0.909 kg/m³, 120 m/s — well beyond the real Aerosonde's envelope, chosen so
the receiver, tanker and hose–drogue share one airspeed), and the propeller model is replaced by
a thrust ``T = T_max δ_t`` with ``T_max`` = twice the trim drag. The nonlinear model is trimmed
(α, δ_e, δ_t) and linearised by central differences; the simulation integrates the linear model
exactly (zero-order hold at the tick).

Actuator limits (ours, typical of small-UAV servos): surfaces ±25° at 60 °/s; throttle 0–1 at
1 /s. They are applied by :class:`Actuators` to the commanded deflections every tick.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import expm
from scipy.optimize import fsolve

from app.control.linear_model import ActuatorLimits, LinearModel
from app.geometry.rotations import euler_to_matrix
from app.sim.plant import TrimPoint
from app.types import FloatArray

GRAVITY = 9.80665

STATE_NAMES: tuple[str, ...] = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi", "x", "y", "z")
INPUT_NAMES: tuple[str, ...] = ("throttle", "aileron", "elevator", "rudder")
SERVO_LAG_S = 0.03  # the lag-aware design's servo lag (s), app.control.design


@dataclass(frozen=True)
class AerosondeParams:
    """Beard & McLain (2012) Aerosonde parameters (SI units, coefficients per rad)."""

    mass: float = 11.0
    jx: float = 0.824
    jy: float = 1.135
    jz: float = 1.759
    jxz: float = 0.120
    s_wing: float = 0.55
    b: float = 2.8956
    c: float = 0.18994
    c_l_0: float = 0.23
    c_l_alpha: float = 5.61
    c_l_q: float = 7.95
    c_l_de: float = 0.13
    c_d_0: float = 0.043
    c_d_alpha: float = 0.03
    c_d_q: float = 0.0
    c_d_de: float = 0.0135
    c_m_0: float = 0.0135
    c_m_alpha: float = -2.74
    c_m_q: float = -38.21
    c_m_de: float = -0.99
    c_y_beta: float = -0.98
    c_y_p: float = 0.0
    c_y_r: float = 0.0
    c_y_da: float = 0.075
    c_y_dr: float = 0.19
    c_ell_beta: float = -0.13
    c_ell_p: float = -0.51
    c_ell_r: float = 0.25
    c_ell_da: float = 0.17
    c_ell_dr: float = 0.0024
    c_n_beta: float = 0.073
    c_n_p: float = 0.069
    c_n_r: float = -0.095
    c_n_da: float = -0.011
    c_n_dr: float = -0.069


@dataclass(frozen=True)
class FlightCondition:
    airspeed_mps: float = 120.0
    air_density: float = 0.909  # ISA 3000 m
    thrust_max_factor: float = 2.0  # T_max = factor × trim drag


def _forces_moments(
    ap: AerosondeParams,
    fc: FlightCondition,
    t_max: float,
    s: FloatArray,
    d: FloatArray,
    wind: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    u, v, w, p, q, r, phi, theta, psi = s[:9]
    dt_, da, de, dr = d
    rtb = euler_to_matrix(phi, theta, psi)
    va_b = np.array([u, v, w]) - rtb.T @ wind
    va = float(np.linalg.norm(va_b))
    alpha = np.arctan2(va_b[2], va_b[0])
    beta = np.arcsin(va_b[1] / va)
    qbar = 0.5 * fc.air_density * va**2
    cl = ap.c_l_0 + ap.c_l_alpha * alpha + ap.c_l_q * ap.c * q / (2 * va) + ap.c_l_de * de
    cd = ap.c_d_0 + ap.c_d_alpha * alpha + ap.c_d_q * ap.c * q / (2 * va) + ap.c_d_de * de
    ca, sa = np.cos(alpha), np.sin(alpha)
    fx = qbar * ap.s_wing * (-cd * ca + cl * sa) + t_max * dt_
    fz = qbar * ap.s_wing * (-cd * sa - cl * ca)
    cy = (
        ap.c_y_beta * beta
        + ap.b / (2 * va) * (ap.c_y_p * p + ap.c_y_r * r)
        + ap.c_y_da * da
        + ap.c_y_dr * dr
    )
    fy = qbar * ap.s_wing * cy
    grav = rtb.T @ np.array([0.0, 0.0, ap.mass * GRAVITY])
    f = np.array([fx, fy, fz]) + grav
    ell = (
        qbar
        * ap.s_wing
        * ap.b
        * (
            ap.c_ell_beta * beta
            + ap.b / (2 * va) * (ap.c_ell_p * p + ap.c_ell_r * r)
            + ap.c_ell_da * da
            + ap.c_ell_dr * dr
        )
    )
    m = (
        qbar
        * ap.s_wing
        * ap.c
        * (ap.c_m_0 + ap.c_m_alpha * alpha + ap.c_m_q * ap.c * q / (2 * va) + ap.c_m_de * de)
    )
    n = (
        qbar
        * ap.s_wing
        * ap.b
        * (
            ap.c_n_beta * beta
            + ap.b / (2 * va) * (ap.c_n_p * p + ap.c_n_r * r)
            + ap.c_n_da * da
            + ap.c_n_dr * dr
        )
    )
    return f, np.array([ell, m, n])


def nonlinear_dynamics(
    ap: AerosondeParams,
    fc: FlightCondition,
    t_max: float,
    s: FloatArray,
    d: FloatArray,
    wind: FloatArray,
) -> FloatArray:
    """Full 12-state derivative (absolute state; position in the tanker frame)."""
    u, v, w, p, q, r, phi, theta, psi = s[:9]
    f, mom = _forces_moments(ap, fc, t_max, s, d, wind)
    udot = r * v - q * w + f[0] / ap.mass
    vdot = p * w - r * u + f[1] / ap.mass
    wdot = q * u - p * v + f[2] / ap.mass
    jx, jy, jz, jxz = ap.jx, ap.jy, ap.jz, ap.jxz
    gam = jx * jz - jxz**2
    g1 = jxz * (jx - jy + jz) / gam
    g2 = (jz * (jz - jy) + jxz**2) / gam
    g3, g4 = jz / gam, jxz / gam
    g5, g6 = (jz - jx) / jy, jxz / jy
    g7 = ((jx - jy) * jx + jxz**2) / gam
    g8 = jx / gam
    ell, m, n = mom
    pdot = g1 * p * q - g2 * q * r + g3 * ell + g4 * n
    qdot = g5 * p * r - g6 * (p**2 - r**2) + m / jy
    rdot = g7 * p * q - g1 * q * r + g4 * ell + g8 * n
    sf, cf = np.sin(phi), np.cos(phi)
    tt, ct = np.tan(theta), np.cos(theta)
    phidot = p + q * sf * tt + r * cf * tt
    thetadot = q * cf - r * sf
    psidot = (q * sf + r * cf) / ct
    pos_dot = euler_to_matrix(phi, theta, psi) @ np.array([u, v, w]) - np.array(
        [fc.airspeed_mps, 0, 0]
    )
    return np.array([udot, vdot, wdot, pdot, qdot, rdot, phidot, thetadot, psidot, *pos_dot])


@dataclass
class LinearReceiver:
    """Trim and continuous-time linear model ``ẋ = A x + B δ + E g`` (see module docstring)."""

    params: AerosondeParams = field(default_factory=AerosondeParams)
    condition: FlightCondition = field(default_factory=FlightCondition)
    limits: ActuatorLimits = field(default_factory=ActuatorLimits)

    def __post_init__(self) -> None:
        ap, fc = self.params, self.condition
        v0 = fc.airspeed_mps
        qbar = 0.5 * fc.air_density * v0**2
        drag_guess = qbar * ap.s_wing * ap.c_d_0
        self.t_max = fc.thrust_max_factor * drag_guess

        def residual(z: FloatArray) -> FloatArray:
            alpha, de, dt_ = z
            s = np.array([v0 * np.cos(alpha), 0, v0 * np.sin(alpha), 0, 0, 0, 0, alpha, 0, 0, 0, 0])
            xd = nonlinear_dynamics(ap, fc, self.t_max, s, np.array([dt_, 0, de, 0]), np.zeros(3))
            return np.array([xd[0], xd[2], xd[4]])

        sol, _info, ier, msg = fsolve(residual, np.array([0.0, 0.0, 0.5]), full_output=True)
        if ier != 1:
            raise RuntimeError(f"receiver trim failed: {msg}")
        alpha, de, dt_ = (float(v) for v in sol)
        self.alpha0 = alpha
        self.theta0 = alpha
        self.x_trim = np.array(
            [v0 * np.cos(alpha), 0, v0 * np.sin(alpha), 0, 0, 0, 0, alpha, 0, 0, 0, 0]
        )
        self.u_trim = np.array([dt_, 0.0, de, 0.0])
        self.A, self.B, self.E = self._jacobians()

    def _jacobians(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        ap, fc, tm = self.params, self.condition, self.t_max
        x0, u0, g0 = self.x_trim, self.u_trim, np.zeros(3)

        def f(x: FloatArray, u: FloatArray, g: FloatArray) -> FloatArray:
            return nonlinear_dynamics(ap, fc, tm, x, u, g)

        def jac(fun, z0: FloatArray, h: float) -> FloatArray:  # type: ignore[no-untyped-def]
            cols = []
            for i in range(len(z0)):
                e = np.zeros_like(z0)
                e[i] = h
                cols.append((fun(z0 + e) - fun(z0 - e)) / (2 * h))
            return np.column_stack(cols)

        a = jac(lambda x: f(x, u0, g0), x0, 1e-6)
        b = jac(lambda u: f(x0, u, g0), u0, 1e-6)
        e = jac(lambda g: f(x0, u0, g), g0, 1e-6)
        return a, b, e

    def linear_model(self, servo_lag_s: float = SERVO_LAG_S) -> LinearModel:
        """The design model (:class:`~app.control.linear_model.LinearModel`): these matrices,
        the trim, the limits, and ``servo_lag_s`` on every input (the lag-aware design's
        assumption; this airframe's thrust has no lag of its own)."""
        return LinearModel(
            a=self.A,
            b=self.B,
            e=self.E,
            x_trim=self.x_trim.copy(),
            u_trim=self.u_trim.copy(),
            input_names=("throttle", "aileron", "elevator", "rudder"),
            limits=self.limits,
            input_lag_s=(servo_lag_s,) * 4,
            airspeed_mps=self.condition.airspeed_mps,
        )

    def trim_point(self, altitude_m: float) -> TrimPoint:
        """The trim as reported (KCAS ≈ the equivalent airspeed; ISA speed of sound)."""
        fc = self.condition
        t_isa = 288.15 - 0.0065 * altitude_m
        sound = float(np.sqrt(1.4 * 287.053 * t_isa))
        eas = fc.airspeed_mps * float(np.sqrt(fc.air_density / 1.225))
        return TrimPoint(
            altitude_ft=altitude_m / 0.3048,
            kcas=eas / 0.514444,
            tas_mps=fc.airspeed_mps,
            alpha_deg=float(np.degrees(self.alpha0)),
            theta_deg=float(np.degrees(self.theta0)),
            throttle=float(self.u_trim[0]),
            weight_lbs=self.params.mass * 2.20462,
            air_density_kgm3=fc.air_density,
            mach=fc.airspeed_mps / sound,
        )

    def discretise(self, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Zero-order-hold ``(A_d, B_d, E_d)`` at step ``dt`` (s)."""
        n, m, k = 12, 4, 3
        big = np.zeros((n + m + k, n + m + k))
        big[:n, :n] = self.A
        big[:n, n : n + m] = self.B
        big[:n, n + m :] = self.E
        ed = expm(big * dt)
        return ed[:n, :n], ed[:n, n : n + m], ed[:n, n + m :]


class Actuators:
    """Rate- and position-limited actuators; ``apply`` returns the achieved deviation from trim.

    ``lag_s`` > 0 adds a first-order lag between the servo position (``position``, what a
    servo-position sensor reports) and the deflection the air sees (``effective``): an
    unmodelled actuator lag for the plant ≠ design imperfection (:mod:`app.sim.imperfections`).
    """

    def __init__(
        self,
        trim: FloatArray,
        limits: ActuatorLimits,
        dt: float,
        lag_s: float = 0.0,
        rate_scale: float = 1.0,
    ) -> None:
        self.trim = np.asarray(trim, float)
        self.lo = np.asarray(limits.lower, float)
        self.hi = np.asarray(limits.upper, float)
        self.rate = np.asarray(limits.rate, float) * rate_scale
        self.dt = dt
        self.lag_alpha = 1.0 - float(np.exp(-dt / lag_s)) if lag_s > 0 else 1.0
        self.reset()

    def reset(self) -> None:
        self.position = self.trim.copy()
        self.effective = self.trim.copy()

    def apply(self, command_dev: FloatArray) -> FloatArray:
        """Servo position after this tick (deviation from trim)."""
        target = np.clip(self.trim + np.asarray(command_dev, float), self.lo, self.hi)
        step = np.clip(target - self.position, -self.rate * self.dt, self.rate * self.dt)
        self.position = self.position + step
        if self.lag_alpha == 1.0:
            self.effective = self.position
        else:
            self.effective = self.effective + self.lag_alpha * (self.position - self.effective)
        return self.position - self.trim

    def effective_dev(self) -> FloatArray:
        """Deflection the air sees (deviation from trim): the servo position, lagged."""
        return np.asarray(self.effective - self.trim)

    def saturation(self) -> float:
        """Largest fraction of the available travel from trim in use (0..1)."""
        dev = self.position - self.trim
        room = np.where(dev >= 0, self.hi - self.trim, self.trim - self.lo)
        return float(np.max(np.abs(dev) / np.maximum(room, 1e-9)))


def perturbed_params(
    base: AerosondeParams,
    aero_scale: dict[str, float],
    mass_scale: float,
    inertia_scale: tuple[float, float, float, float],
) -> AerosondeParams:
    """The parameter set with derivatives, mass and inertias scaled (plant ≠ design)."""
    changes = {k: getattr(base, k) * s for k, s in aero_scale.items()}
    changes["mass"] = base.mass * mass_scale
    for k, s in zip(("jx", "jy", "jz", "jxz"), inertia_scale, strict=True):
        changes[k] = getattr(base, k) * s
    return replace(base, **changes)
