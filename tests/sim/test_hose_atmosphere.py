"""ISA and CAS → TAS of the hose's flight condition, against JSBSim's own atmosphere."""

from __future__ import annotations

import pytest

from app.sim.hose.atmosphere import FlowCondition, flow_from_kcas, isa

SLUG_FT3 = 515.378818  # kg/m³ per slug/ft³


def _jsbsim(altitude_ft: float, kcas: float) -> tuple[float, float]:
    jsbsim = pytest.importorskip("jsbsim")
    jsbsim.FGJSBBase().debug_lvl = 0
    fdm = jsbsim.FGFDMExec(None)
    fdm.set_debug_level(0)
    assert fdm.load_model("A4")
    fdm["ic/h-sl-ft"] = altitude_ft
    fdm["ic/vc-kts"] = kcas
    fdm.run_ic()
    return fdm["atmosphere/rho-slugs_ft3"] * SLUG_FT3, fdm["velocities/vt-fps"] * 0.3048


@pytest.mark.parametrize(("alt", "kcas"), [(15000.0, 230.0), (5000.0, 200.0), (25000.0, 280.0)])
def test_density_and_true_airspeed_match_jsbsim(alt: float, kcas: float) -> None:
    rho, tas = _jsbsim(alt, kcas)
    flow = flow_from_kcas(alt, kcas)
    assert flow.air_density_kgm3 == pytest.approx(rho, rel=0.005)
    assert flow.airspeed_mps == pytest.approx(tas, rel=0.005)


def test_sea_level_and_tropopause() -> None:
    assert isa(0.0) == pytest.approx((288.15, 101325.0, 1.225), rel=1e-4)
    t, p, rho = isa(11000.0)
    assert t == pytest.approx(216.65) and p == pytest.approx(22632.0, rel=1e-3)
    assert flow_from_kcas(0.0, 200.0).airspeed_mps == pytest.approx(200 * 0.514444, rel=1e-6)


@pytest.mark.parametrize(("alt", "kcas"), [(-10.0, 230.0), (15000.0, 20.0), (40000.0, 450.0)])
def test_out_of_range_is_a_value_error(alt: float, kcas: float) -> None:
    with pytest.raises(ValueError):
        flow_from_kcas(alt, kcas)
    with pytest.raises(ValueError):
        FlowCondition(air_density_kgm3=0.0, airspeed_mps=100.0)
