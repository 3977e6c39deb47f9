"""Reduced-order hose–drogue model: 2nd-order drogue swing driven by turbulence, plus bow wave.

Parameters are the flight-scale set of a public lumped-hose AAR simulator (RflySimAAR, quoted in
``/work/shared/notes/reference.md``): 15 m hose, 4.1 kg/m, drogue 29.5 kg, drag coefficient 0.8,
drogue radius 0.305 m, flight at 3000 m (ρ = 0.909 kg/m³), 120 m/s.

Model (derivation, small deflections about the trailing equilibrium): the drogue's steady drag
``D₀ = ½ ρ V² C_d π r²`` (≈ 1.53 kN here, close to the quoted 1610 N reel tension) is carried by
the hose, so a lateral/vertical deflection ``d`` of the drogue end tilts the hose and gives a
restoring force ``−D₀ d / L``; a relative cross-wind ``(g − ḋ)`` tilts the drag vector by
``(g − ḋ)/V``. With the drogue plus a third of the hose mass as effective mass ``m``::

    m d̈ = −(D₀/L) d + (D₀/V)(g⊥ − ḋ) + F_bow          (lateral y and vertical z)
    m ẍ = −k_x x − c_x ẋ + (2 D₀/V) g_x + F_bow,x      (axial, stiff reel: ω_x = 2 ω, ζ_x = 0.3)

so ``ω = √(D₀/(m L))`` (≈ 1.43 rad/s, period ≈ 4.4 s), damping ratio ``ζ = D₀/(2 m V ω)`` (≈ 0.09),
and a steady cross-gust ``g`` moves the drogue by ``L g / V`` (the hose aligns with the relative
wind) — the properties the tests check. This is a validated reduced-order alternative, used
in place of a 10-link lumped hose.

Bow wave (documented simple model, not from a CFD source): as the receiver's nose approaches, the
drogue is pushed away from the nose axis and upwards with a force
``F_bow = F₀ exp(−s/ℓ) · unit(r⊥ + ε·up)`` where ``s`` is the axial distance nose→drogue (m),
``r⊥`` the drogue's offset from the nose axis and ε = 0.3 m. Defaults ``F₀ = 60 N, ℓ = 1.5 m``
give a ≈ 0.1 m static displacement with the probe at the drogue.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.model.drogue import DrogueModel
from app.types import FloatArray

GRAVITY = 9.80665


@dataclass(frozen=True)
class HoseDrogueParams:
    hose_length_m: float = 15.0
    hose_mass_per_m: float = 4.1
    drogue_mass_kg: float = 29.5
    drogue_cd: float = 0.8
    drogue_radius_m: float = 0.305
    air_density: float = 0.909  # ISA at 3000 m
    airspeed_mps: float = 120.0
    bow_force_n: float = 60.0
    bow_length_m: float = 1.5
    bow_up_bias_m: float = 0.3

    @property
    def drag_n(self) -> float:
        area = np.pi * self.drogue_radius_m**2
        return 0.5 * self.air_density * self.airspeed_mps**2 * self.drogue_cd * area

    @property
    def effective_mass_kg(self) -> float:
        return self.drogue_mass_kg + self.hose_mass_per_m * self.hose_length_m / 3.0

    @property
    def omega_rad_s(self) -> float:
        return float(np.sqrt(self.drag_n / (self.effective_mass_kg * self.hose_length_m)))

    @property
    def damping_ratio(self) -> float:
        return self.drag_n / (2.0 * self.effective_mass_kg * self.airspeed_mps * self.omega_rad_s)

    @property
    def hang_angle_rad(self) -> float:
        """Droop of the hose tangent at the drogue below the horizontal: drogue weight over drag."""
        return float(np.arctan2(self.drogue_mass_kg * GRAVITY, self.drag_n))

    def guidance_model(self) -> DrogueModel:
        """These parameters as the guidance's model (:class:`~app.model.drogue.
        DrogueModel`): build it from a *nominal* drogue, never from a run's dispersed one."""
        rest = self.equilibrium_m()
        return DrogueModel(
            omega_rad_s=self.omega_rad_s,
            damping_ratio=self.damping_ratio,
            effective_mass_kg=self.effective_mass_kg,
            bow_force_n=self.bow_force_n,
            bow_length_m=self.bow_length_m,
            bow_up_bias_m=self.bow_up_bias_m,
            rest_m=(float(rest[0]), float(rest[1]), float(rest[2])),
        )

    def equilibrium_m(self) -> FloatArray:
        """Drogue centre at rest in the tanker frame (m; hose exit at the origin).

        Static hose shape with the drag concentrated on the drogue: at arc length ``s`` from the
        drogue the tangent droops by ``atan((m_d + λ s) g / D₀)``; integrate along the hose."""
        return self.static_nodes_m(400)[-1].copy()

    def static_nodes_m(self, segments: int = 16) -> FloatArray:
        """The static hose line of :meth:`equilibrium_m` as ``segments + 1`` nodes from the hose
        exit (the origin, first) to the drogue (last), tanker frame (m)."""
        s = np.linspace(0.0, self.hose_length_m, segments + 1)  # arc length from the drogue
        ang = np.arctan2((self.drogue_mass_kg + self.hose_mass_per_m * s) * GRAVITY, self.drag_n)
        ds = np.diff(s)
        mid = 0.5 * (ang[1:] + ang[:-1])
        # from the drogue towards the exit: each segment rises forward at its droop angle
        steps = np.column_stack([np.cos(mid) * ds, np.zeros_like(ds), -np.sin(mid) * ds])
        drogue = -np.sum(steps, axis=0)
        from_drogue = drogue + np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
        return np.asarray(from_drogue[::-1])


def bow_wave_force(
    drogue_m: FloatArray,
    nose_m: FloatArray,
    nose_axis: FloatArray,
    force_n: float,
    length_m: float,
    up_bias_m: float,
) -> FloatArray:
    """Force (N) the receiver's bow wave exerts on a drogue at ``drogue_m`` (module docstring):
    ``F₀ exp(−s/ℓ) · unit(r⊥ + ε·up)``, the nose at ``nose_m`` pointing along ``nose_axis``."""
    if force_n == 0.0:
        return np.zeros(3)
    rel = drogue_m - nose_m
    s = float(rel @ nose_axis)
    if s < 0.0:
        s = 0.0
    r_perp = rel - s * nose_axis
    direction = r_perp + np.array([0.0, 0.0, -up_bias_m])
    direction /= np.linalg.norm(direction)
    return np.asarray(force_n * np.exp(-s / length_m) * direction)


class HoseDrogue:
    """Drogue position/velocity about its equilibrium; explicit state, semi-implicit Euler substeps."""

    def __init__(self, params: HoseDrogueParams | None = None, substeps: int = 4) -> None:
        self.params = params or HoseDrogueParams()
        self.substeps = substeps
        self.eq_m = self.params.equilibrium_m()
        self._static_nodes = self.params.static_nodes_m()
        self._static_nodes[-1] = self.eq_m
        # each node's share of the drogue's deflection: its fraction of the way from the exit
        self._deflection_share = np.linspace(0.0, 1.0, len(self._static_nodes))[:, None]
        self.reset()

    def reset(self, offset_m: FloatArray | None = None) -> None:
        self.d = np.zeros(3) if offset_m is None else np.asarray(offset_m, float).copy()
        self.v = np.zeros(3)

    @property
    def position_m(self) -> FloatArray:
        return self.eq_m + self.d

    @property
    def velocity_mps(self) -> FloatArray:
        return self.v.copy()

    def hose_nodes_m(self) -> FloatArray:
        """The hose's line now (exit first, drogue last; m): the static shape with the drogue's
        deflection carried along the hose in proportion to the distance from the exit."""
        return np.asarray(self._static_nodes + self._deflection_share * self.d[None, :])

    def normal(self) -> FloatArray:
        """Unit normal of the drogue's opening, pointing aft towards the receiver: the hose tangent
        at the drogue, tilted by the deflection over the hose length."""
        g = self.params.hang_angle_rad
        t = np.array([-np.cos(g), 0.0, np.sin(g)]) * self.params.hose_length_m
        n = t + np.array([0.0, self.d[1], self.d[2]])
        return n / np.linalg.norm(n)

    def bow_wave_force(self, nose_m: FloatArray, nose_axis: FloatArray) -> FloatArray:
        """Force (N) the receiver's bow wave exerts on the drogue (see module docstring)."""
        p = self.params
        return bow_wave_force(
            self.position_m, nose_m, nose_axis, p.bow_force_n, p.bow_length_m, p.bow_up_bias_m
        )

    def latch(self, probe_m: FloatArray, closure_mps: float) -> None:
        """Contact: from the next tick on the drogue is welded to the probe (:meth:`ride`);
        nothing to latch in this model."""

    def ride(self, dt: float, probe_m: FloatArray, gust_mps: FloatArray | None = None) -> None:
        """Latched: the drogue sits on the probe tip ``probe_m`` (m), at rest in its frame (the
        gust moves nothing: the drogue is welded)."""
        self.d = probe_m - self.eq_m
        self.v = np.zeros(3)

    def step(self, dt: float, gust_mps: FloatArray, force_n: FloatArray | None = None) -> None:
        p = self.params
        m = p.effective_mass_kg
        d0 = p.drag_n
        k_lat = d0 / p.hose_length_m
        c_lat = d0 / p.airspeed_mps
        k_ax = m * (2.0 * p.omega_rad_s) ** 2
        c_ax = 2.0 * 0.3 * m * 2.0 * p.omega_rad_s
        k = np.array([k_ax, k_lat, k_lat])
        c = np.array([c_ax, c_lat, c_lat])
        g = np.asarray(gust_mps, float)
        f_gust = np.array([2.0 * d0 / p.airspeed_mps * g[0], c_lat * g[1], c_lat * g[2]])
        f_ext = f_gust + (np.zeros(3) if force_n is None else np.asarray(force_n, float))
        h = dt / self.substeps
        for _ in range(self.substeps):
            acc = (-k * self.d - c * self.v + f_ext) / m
            self.v = self.v + h * acc
            self.d = self.d + h * self.v
