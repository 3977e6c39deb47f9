"""Steady shape and swing of the multi-body hose against what we did not write: the continuous
towed-cable equilibrium and its lateral linearisation (``tests/support/towed_cable_reference``,
scipy, sharing no code with the model), convergence in the number of nodes, and the
pendulum/string estimate of the reduced-order model."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from app.sim.hose.atmosphere import FlowCondition, flow_from_kcas
from app.sim.hose.kernels import forces, pack_hose
from app.sim.hose.params import DrogueParams, HoseParams
from app.sim.hose.steady import steady_shape, swing_modes
from app.sim.hose_drogue import HoseDrogueParams
from tests.support.towed_cable_reference import Cable, lateral_modes, solve, vertical_mode

AFT = np.array([-1.0, 1.0, 1.0])  # tanker frame (x forward) → x aft


def _cable(flow: FlowCondition, h: HoseParams, d: DrogueParams) -> Cable:
    return Cable(
        h.length_m, h.mass_per_m_kg, h.diameter_m, h.cd_normal, h.cd_tangential,
        d.mass_kg, d.cd, d.area_m2, flow.air_density_kgm3, flow.airspeed_mps,
    )  # fmt: skip


def test_steady_shape_is_an_equilibrium_of_the_dynamic_forces() -> None:
    flow, h, d = flow_from_kcas(15000, 230), HoseParams(), DrogueParams()
    s = steady_shape(flow, h, d)
    n = h.segments
    force, tension = np.empty((n + 1, 3)), np.empty(n)
    air = np.tile([-flow.airspeed_mps, 0.0, 0.0], (n + 1, 1))
    forces(s.nodes_m, np.zeros((n + 1, 3)), air, np.zeros(3), 15.0 / n, pack_hose(flow, h, d),
           force, tension)  # fmt: skip
    assert np.abs(force[1:]).max() < 1e-6  # N, against tensions of ≈ 2 kN
    assert np.allclose(tension, s.tensions_n, rtol=1e-9)
    assert np.allclose(s.nodes_m[0], 0.0)


@pytest.mark.parametrize("kcas", [200.0, 230.0, 280.0])
def test_shape_and_reel_tension_match_the_continuous_towed_cable(kcas: float) -> None:
    flow, h, d = flow_from_kcas(15000, kcas), HoseParams(), DrogueParams()
    s = steady_shape(flow, h, d)
    ref = solve(_cable(flow, h, d))
    err = np.linalg.norm(s.nodes_m * AFT - ref.at(np.linspace(0.0, 15.0, h.segments + 1)), axis=1)
    # the model's hose stretches by T/EA (≤ 0.6 %); the reference is inextensible
    assert err[-1] < 0.01 * h.length_m
    assert err.max() < 0.01 * h.length_m
    assert s.reel_tension_n == pytest.approx(ref.tension[0], rel=0.01)


def test_shape_converges_as_the_nodes_grow() -> None:
    """Inextensible limit (EA 10⁹ N): the drogue's and the reel tension's errors against the
    continuous cable fall with the number of segments (first order)."""
    flow, d = flow_from_kcas(15000, 230), DrogueParams()
    h0 = HoseParams(axial_stiffness_n=1e9)
    ref = solve(_cable(flow, h0, d))
    drogue_err, tension_err = [], []
    for n in (5, 10, 20, 40):
        s = steady_shape(flow, replace(h0, segments=n), d)
        drogue_err.append(np.linalg.norm(s.drogue_m * AFT - ref.at(np.array([15.0]))[0]))
        tension_err.append(abs(s.reel_tension_n - ref.tension[0]))
    assert all(b < 0.6 * a for a, b in zip(tension_err, tension_err[1:], strict=False))
    assert drogue_err[-1] < 0.6 * drogue_err[0]
    assert drogue_err[-1] < 1e-3 * 15.0


def test_drogue_trails_further_aft_and_higher_as_speed_grows() -> None:
    d = [steady_shape(flow_from_kcas(15000, k), HoseParams(), DrogueParams()).drogue_m
         for k in (200, 230, 280)]  # fmt: skip
    aft = [-p[0] for p in d]
    down = [p[2] for p in d]
    assert aft[0] < aft[1] < aft[2]
    assert down[0] > down[1] > down[2] > 0.0


@pytest.mark.parametrize("kcas", [200.0, 280.0])
def test_lateral_swing_matches_the_linearised_continuous_cable(kcas: float) -> None:
    flow, h, d = flow_from_kcas(15000, kcas), HoseParams(), DrogueParams()
    modes = swing_modes(flow, h, d, steady_shape(flow, h, d))
    cable = _cable(flow, h, d)
    f_ref, zeta_ref = lateral_modes(cable, solve(cable))
    assert modes.lateral.frequency_hz == pytest.approx(f_ref, rel=0.02)
    assert modes.lateral.damping_ratio == pytest.approx(zeta_ref, rel=0.05)


def test_swing_against_the_pendulum_string_estimate() -> None:
    """At the reduced-order model's condition (3000 m, 120 m/s): the string estimate
    ω² = T_d / (L (m_d + μL/3)) (drag carried by the hose, no hose drag) is the lower bound; the
    hose's own cross-flow drag at its steady inclination adds lateral stiffness (+≈ 30 %) and
    the damping stays ≈ the drogue's D/(2 m V ω)."""
    p = HoseDrogueParams()
    flow = FlowCondition(air_density_kgm3=p.air_density, airspeed_mps=p.airspeed_mps)
    h, d = HoseParams(), DrogueParams()
    s = steady_shape(flow, h, d)
    modes = swing_modes(flow, h, d, s)
    w_lat = 2 * math.pi * modes.lateral.frequency_hz
    assert p.omega_rad_s == pytest.approx(1.43, abs=0.01)
    w_string = math.sqrt(s.tensions_n[-1] / (h.length_m * p.effective_mass_kg))
    assert w_string < w_lat < 1.5 * w_string
    assert 0.05 < modes.lateral.damping_ratio < 0.15
    assert 0.05 < modes.vertical.damping_ratio < 0.15
    assert modes.vertical.frequency_hz > modes.lateral.frequency_hz


def test_swing_converges_as_the_nodes_grow() -> None:
    flow, d = flow_from_kcas(15000, 230), DrogueParams()
    f_lat, f_vert = [], []
    for n in (10, 20, 40):
        h = HoseParams(segments=n)
        m = swing_modes(flow, h, d, steady_shape(flow, h, d))
        f_lat.append(m.lateral.frequency_hz)
        f_vert.append(m.vertical.frequency_hz)
    for f in (f_lat, f_vert):
        assert abs(f[2] - f[1]) < 0.6 * abs(f[1] - f[0]) + 1e-4
        assert abs(f[2] - f[1]) < 0.01 * f[2]


def test_vertical_swing_matches_the_continuous_cable_by_shooting() -> None:
    """The in-plane mode of the continuous inextensible cable, found by shooting from a
    pendulum-like guess (0.3 Hz, ζ 0.05) that does not come from the model."""
    flow, h, d = flow_from_kcas(15000, 230), HoseParams(), DrogueParams()
    modes = swing_modes(flow, h, d, steady_shape(flow, h, d))
    f_ref, zeta_ref = vertical_mode(_cable(flow, h, d), 0.3, 0.05)
    assert modes.vertical.frequency_hz == pytest.approx(f_ref, rel=0.02)
    assert modes.vertical.damping_ratio == pytest.approx(zeta_ref, rel=0.05)
