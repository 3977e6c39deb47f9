"""An independent steady towed-cable solution for checking the hose model (shares no code with
``app.sim.hose``): the continuous, inextensible cable in a uniform stream under the cross-flow
(independence) principle, integrated with ``scipy.integrate.solve_ivp``.

Vertical plane, x aft, z down, arc length s from the drogue (0) to the reel exit (L); φ(s) the
angle of the cable below the horizontal, the unit tangent towards the reel (−cos φ, −sin φ)
in (x aft, z down). Per metre: weight w = μ g down; with q = ½ρV², normal drag
q d C_n sin²φ and tangential drag q π d C_t cos²φ (the stream flows aft). Balance of an element
``d(T t̂)/ds = −f``:

    dT/ds = w sin φ + q π d C_t cos² φ
    T dφ/ds = w cos φ − q d C_n sin² φ

At the drogue the hose carries the drogue's drag D = q C_d A and weight W: T cos φ = D,
T sin φ = W. Positions: d(x, z)/ds = (−cos φ, −sin φ), shifted so that the reel exit is at the
origin. The in-plane swing (:func:`vertical_mode`) by shooting on the linearised equations.
The lateral swing of the same cable (:func:`lateral_modes`), linearised about this
shape and discretised by finite differences on 200 cells:

    μ ÿ = (T y')' − q_n V sin φ ẏ − (q_n V² sin φ cos φ − q_t V² cos² φ) y'   (s from the reel)
    m_d ÿ = −T(L) y'(L) − ½ρ C_d A V ẏ,   y(0) = 0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import eig
from scipy.optimize import root

G = 9.80665


@dataclass(frozen=True)
class Cable:
    length_m: float
    mass_per_m_kg: float
    diameter_m: float
    cd_normal: float
    cd_tangential: float
    drogue_mass_kg: float
    drogue_cd: float
    drogue_area_m2: float
    air_density_kgm3: float
    airspeed_mps: float


@dataclass(frozen=True)
class CableSolution:
    """``s_from_reel`` (m), positions (x aft, z down; m), tension (N), angle (rad), all from the
    reel exit (first) to the drogue (last), on a fine grid."""

    s_from_reel: np.ndarray
    x_aft: np.ndarray
    z_down: np.ndarray
    tension: np.ndarray
    angle: np.ndarray

    def at(self, s_from_reel: np.ndarray) -> np.ndarray:
        """(x aft, 0, z down) at arc lengths from the reel exit."""
        x = np.interp(s_from_reel, self.s_from_reel, self.x_aft)
        z = np.interp(s_from_reel, self.s_from_reel, self.z_down)
        return np.column_stack([x, np.zeros_like(x), z])


def solve(c: Cable, points: int = 2001) -> CableSolution:
    q = 0.5 * c.air_density_kgm3 * c.airspeed_mps**2
    w = c.mass_per_m_kg * G
    drag = q * c.drogue_cd * c.drogue_area_m2
    weight = c.drogue_mass_kg * G

    def rhs(s: float, y: np.ndarray) -> list[float]:
        tension, phi, _x, _z = y
        dt = w * math.sin(phi) + q * math.pi * c.diameter_m * c.cd_tangential * math.cos(phi) ** 2
        dphi = (w * math.cos(phi) - q * c.diameter_m * c.cd_normal * math.sin(phi) ** 2) / tension
        return [dt, dphi, -math.cos(phi), -math.sin(phi)]

    s = np.linspace(0.0, c.length_m, points)
    y0 = [math.hypot(drag, weight), math.atan2(weight, drag), 0.0, 0.0]
    sol = solve_ivp(rhs, (0.0, c.length_m), y0, t_eval=s, rtol=1e-10, atol=1e-10, method="DOP853")
    tension, phi, x, z = sol.y
    # reverse: the reel exit first, at the origin
    return CableSolution(
        s_from_reel=(c.length_m - s)[::-1],
        x_aft=(x - x[-1])[::-1],
        z_down=(z - z[-1])[::-1],
        tension=tension[::-1],
        angle=phi[::-1],
    )


def lateral_modes(c: Cable, sol: CableSolution, points: int = 200) -> tuple[float, float]:
    """(frequency Hz, damping ratio) of the slowest lateral mode of the continuous cable."""
    V = c.airspeed_mps
    qn = 0.5 * c.air_density_kgm3 * c.diameter_m * c.cd_normal
    qt = 0.5 * c.air_density_kgm3 * math.pi * c.diameter_m * c.cd_tangential
    s = np.linspace(0.0, c.length_m, points + 1)
    h = s[1] - s[0]
    tension = np.interp(s, sol.s_from_reel, sol.tension)
    phi = np.interp(s, sol.s_from_reel, sol.angle)
    n = points  # unknowns y_1..y_n (y_0 = 0 at the reel), y_n the drogue
    k = np.zeros((n, n))  # force (per metre; at the drogue, N) = k y + damp ẏ
    damp = np.zeros((n, n))
    mass = np.full(n, c.mass_per_m_kg)
    for i in range(1, n):
        row = i - 1
        t_plus = 0.5 * (tension[i] + tension[i + 1])
        t_minus = 0.5 * (tension[i] + tension[i - 1])
        slope = -(
            qn * V**2 * math.sin(phi[i]) * math.cos(phi[i]) - qt * (V * math.cos(phi[i])) ** 2
        )
        k[row, row] = -(t_plus + t_minus) / h**2
        k[row, row + 1] = t_plus / h**2 + slope / (2 * h)
        if row >= 1:  # (y_0 = 0 at the reel)
            k[row, row - 1] = t_minus / h**2 - slope / (2 * h)
        damp[row, row] = -qn * V * math.sin(phi[i])
    # the drogue: (m_d + half a cell of hose) ÿ = −T y' (backward difference) − ½ρ C_d A V ẏ
    last = n - 1
    t_end = 0.5 * (tension[n] + tension[n - 1])
    k[last, last] = -t_end / h
    k[last, last - 1] = t_end / h
    damp[last, last] = -0.5 * c.air_density_kgm3 * c.drogue_cd * c.drogue_area_m2 * V
    mass[last] = c.drogue_mass_kg + 0.5 * c.mass_per_m_kg * h
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = k / mass[:, None]
    a[n:, n:] = damp / mass[:, None]
    vals = eig(a, right=False)
    osc = [v for v in vals if v.imag > 1e-6]
    lam = min(osc, key=abs)
    return lam.imag / (2 * math.pi), -lam.real / abs(lam)


def _aero_xz(c: Cable, phi: float, u: np.ndarray) -> np.ndarray:
    """Cross-flow drag per metre (x aft, z down) on a cable at angle φ (tangent towards the
    reel (−cos φ, −sin φ)) in the relative air ``u``."""
    t = np.array([-math.cos(phi), -math.sin(phi)])
    ut = float(u @ t)
    un = u - ut * t
    qn = 0.5 * c.air_density_kgm3 * c.diameter_m * c.cd_normal
    qt = 0.5 * c.air_density_kgm3 * math.pi * c.diameter_m * c.cd_tangential
    return np.asarray(qn * np.linalg.norm(un) * un + qt * abs(ut) * ut * t)


def vertical_mode(c: Cable, guess_hz: float, guess_zeta: float) -> tuple[float, float]:
    """(frequency Hz, damping ratio) of the in-plane swing of the continuous inextensible cable
    nearest the guess, by shooting: perturbations ρ (displacement), τ (tension), ψ (angle)
    ∝ e^{λt} obey, with s from the drogue, n̂ = (sin φ, −cos φ),

        ρ' = ψ n̂,   τ' = T φ' ψ + t̂·(μλ²ρ − δf),   (Tψ)' = n̂·(μλ²ρ − δf) − τ φ'

    (δf the drag's change with φ and with the velocity λρ); the drogue's
    m_d λ² ρ = τ t̂ + T ψ n̂ + δF_d starts them, and λ is the root of det[ρ(L)] = 0 for the two
    starting displacements (x and z)."""
    V = c.airspeed_mps
    mu = c.mass_per_m_kg
    air = np.array([V, 0.0])  # the stream flows aft
    q = 0.5 * c.air_density_kgm3 * V**2
    drag, weight = q * c.drogue_cd * c.drogue_area_m2, c.drogue_mass_kg * G
    cda = 0.5 * c.air_density_kgm3 * c.drogue_cd * c.drogue_area_m2
    eps = 1e-6

    def jac(phi: float) -> tuple[np.ndarray, np.ndarray]:
        d_phi = (_aero_xz(c, phi + eps, air) - _aero_xz(c, phi - eps, air)) / (2 * eps)
        d_v = np.column_stack(
            [
                -(_aero_xz(c, phi, air + e * eps) - _aero_xz(c, phi, air - e * eps)) / (2 * eps)
                for e in np.eye(2)
            ]
        )
        return d_phi, d_v

    def end_displacement(lam: complex) -> complex:
        cols = []
        for rho0 in np.eye(2):
            t0 = math.hypot(drag, weight)
            phi0 = math.atan2(weight, drag)
            tt = np.array([-math.cos(phi0), -math.sin(phi0)])
            nn = np.array([math.sin(phi0), -math.cos(phi0)])
            # drogue drag −cda |u| u with u = air − v: its change with v
            d_fd = cda * V * (np.eye(2) + np.outer(air, air) / V**2)
            rhs = c.drogue_mass_kg * lam**2 * rho0 + d_fd @ (lam * rho0)
            tau0, psi0 = complex(rhs @ tt), complex(rhs @ nn) / t0

            def ode(s: float, y: np.ndarray) -> np.ndarray:
                tension, phi = y[0], y[1]
                rho = y[2:4] + 1j * y[4:6]
                tau, psi = y[6] + 1j * y[7], y[8] + 1j * y[9]
                t_hat = np.array([-math.cos(phi), -math.sin(phi)])
                n_hat = np.array([math.sin(phi), -math.cos(phi)])
                dt0 = (
                    mu * G * math.sin(phi)
                    + q * math.pi * c.diameter_m * c.cd_tangential * math.cos(phi) ** 2
                )
                dphi = (
                    mu * G * math.cos(phi) - q * c.diameter_m * c.cd_normal * math.sin(phi) ** 2
                ) / tension
                d_phi, d_v = jac(phi)
                df = d_phi * psi + d_v @ (lam * rho)
                acc = mu * lam**2 * rho - df
                drho = psi * n_hat
                dtau = tension * dphi * psi + t_hat @ acc
                d_tpsi = n_hat @ acc - tau * dphi
                dpsi = (d_tpsi - dt0 * psi) / tension
                return np.array(
                    [dt0, dphi, *drho.real, *drho.imag, dtau.real, dtau.imag, dpsi.real, dpsi.imag]
                )

            y0 = np.array(
                [t0, phi0, rho0[0], rho0[1], 0.0, 0.0, tau0.real, tau0.imag, psi0.real, psi0.imag]
            )
            sol = solve_ivp(ode, (0.0, c.length_m), y0, rtol=1e-9, atol=1e-11, method="DOP853")
            y = sol.y[:, -1]
            cols.append(y[2:4] + 1j * y[4:6])
        return complex(cols[0][0] * cols[1][1] - cols[0][1] * cols[1][0])

    w = 2 * math.pi * guess_hz / math.sqrt(1 - guess_zeta**2)
    lam0 = complex(-guess_zeta * w, w * math.sqrt(1 - guess_zeta**2))

    def f(v: np.ndarray) -> list[float]:
        d = end_displacement(complex(v[0], v[1]))
        return [d.real, d.imag]

    out = root(f, [lam0.real, lam0.imag], method="hybr")
    assert out.success, out.message
    lam = complex(out.x[0], out.x[1])
    return lam.imag / (2 * math.pi), -lam.real / abs(lam)
