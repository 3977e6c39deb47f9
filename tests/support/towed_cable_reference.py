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
origin. The lateral swing of the same cable (:func:`lateral_modes`), linearised about this
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
