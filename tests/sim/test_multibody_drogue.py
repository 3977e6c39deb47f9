"""The multi-body hose flown by the closed loop (``DockingConfig.hose_model = "multibody"``):
a run ends with a named outcome and reports the contact's peak tension, the drogue in the loop
swings at the multi-body hose's frequency (checked against the independent continuous cable of
``tests/support``), the coupling latches and the drogue follows the probe, a closure above the
window is a whip risk (and, latched, a whip), the run's draw disperses the hose, and the default
reduced model is unchanged."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from app.sim.docking import DockingConfig, DockingSimulation, DockingTick
from app.sim.docking.multibody_drogue import MultibodyDrogue, MultibodyDrogueParams
from app.sim.docking.outcomes import OUTCOMES
from app.sim.hose import CouplingParams, DrogueParams, HoseParams, ReelParams, push_in_path
from app.sim.hose.atmosphere import flow_from_kcas
from app.sim.hose_drogue import HoseDrogue
from tests.support.towed_cable_reference import Cable, lateral_modes, solve

TRUTH = DockingConfig(vision=False, station_keep_s=2.0)
FLOW = flow_from_kcas(15000, 230)


def _crossing_period_s(t: np.ndarray, y: np.ndarray) -> float:
    """Twice the mean time between zero crossings (linear interpolation)."""
    i = np.flatnonzero(np.sign(y[:-1]) != np.sign(y[1:]))
    tc = t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])
    assert len(tc) >= 4
    return 2.0 * float(np.mean(np.diff(tc)))


def _free_swing_rad_s(hose_model: str) -> float:
    """The damped lateral swing of the drogue the loop flies, kicked sideways at the start with
    the receiver far behind (30 m: no bow wave), in still air; rad/s from the loop's ticks."""
    sim = DockingSimulation(
        replace(TRUTH, turbulence="none", start_gap_m=30.0, hose_model=hose_model)
    )
    if isinstance(sim.drogue, MultibodyDrogue):
        n = len(sim.drogue.hose.vel)
        sim.drogue.hose.vel[:, 1] = np.linspace(0.0, 0.5, n)  # a lateral kick, reel to drogue
    else:
        sim.drogue.v[1] = 0.5
    t, y = [], []
    for _ in range(int(10.0 / sim.dt)):
        tick = sim.step()
        t.append(tick.t_s)
        y.append(tick.drogue_truth_m[1])
    return 2.0 * math.pi / _crossing_period_s(np.array(t), np.array(y))


def test_drogue_in_the_loop_swings_at_the_multibody_frequency() -> None:
    sim = DockingSimulation(replace(TRUTH, hose_model="multibody"))
    flow, h, d = sim.drogue.params.flow, HoseParams(), DrogueParams()
    cable = Cable(
        h.length_m,
        h.mass_per_m_kg,
        h.diameter_m,
        h.cd_normal,
        h.cd_tangential,
        d.mass_kg,
        d.cd,
        d.area_m2,
        flow.air_density_kgm3,
        flow.airspeed_mps,
    )
    ref_hz, _ = lateral_modes(cable, solve(cable))
    multibody = _free_swing_rad_s("multibody")
    reduced = _free_swing_rad_s("reduced")
    assert multibody == pytest.approx(2.0 * math.pi * ref_hz, rel=0.05)
    assert multibody > 1.15 * reduced  # the hose's own cross-flow drag stiffens the swing


def _first_captured_truth_run(seeds: range) -> tuple[DockingSimulation, list[float], DockingTick]:
    """The first of ``seeds`` whose multibody truth run captures (the test is about the latch
    and the tension, not the capture rate: the campaigns measure that); every run on the way
    ends in a named outcome that is no safety event."""
    for seed in seeds:
        sim = DockingSimulation(
            replace(
                TRUTH,
                turbulence="moderate",
                imperfections="standard",
                seed=seed,
                hose_model="multibody",
            )
        )
        latched_peaks = []
        while not sim.done:
            tick = sim.step()
            if sim.captured and not tick.phase == "contact":  # the ticks ridden on the coupling
                assert sim.drogue.last_tick is not None
                latched_peaks.append(sim.drogue.last_tick.peak_tension_n)
        out = sim.outcome()
        assert out.outcome in OUTCOMES and out.outcome not in ("departure", "keep_out", "error")
        if out.outcome == "captured":
            return sim, latched_peaks, tick
    raise AssertionError(f"no capture in seeds {seeds.start}–{seeds.stop - 1}")


def test_truth_run_completes_latches_and_reports_peak_tension() -> None:
    sim, latched_peaks, tick = _first_captured_truth_run(range(1, 7))
    out = sim.outcome()
    assert sim.drogue.hose.latched and not out.hose_released
    assert out.peak_hose_tension_n == pytest.approx(max(latched_peaks))
    assert out.peak_hose_tension_n > 0.8 * sim.drogue.hose.trail_tension_n
    assert not out.hose_whip
    # after the funnel's centring the drogue rides on the probe head (the coupling's spring)
    assert np.linalg.norm(tick.drogue_truth_m - tick.probe_tip_m) < 0.05
    assert out.to_dict()["peak_hose_tension_n"] == pytest.approx(out.peak_hose_tension_n)


def _adapter() -> MultibodyDrogue:
    return MultibodyDrogue(
        MultibodyDrogueParams(
            flow=FLOW,
            hose=HoseParams(),
            drogue=DrogueParams(),
            reel=ReelParams(),
            coupling=CouplingParams(max_closure_mps=5.0),  # allowed to latch above the window
            bow_force_n=0.0,
        ),
        0.02,
    )


@pytest.mark.parametrize(("closure", "whip"), [(1.6, False), (4.5, True)])
def test_latched_push_in_above_the_reel_whips(closure: float, whip: bool) -> None:
    drogue, dt = _adapter(), 0.02
    contact = drogue.position_m.copy()
    drogue.latch(contact, closure)
    forward = push_in_path(closure, 1.5)
    for k in range(1, int(4.0 / dt)):
        drogue.ride(dt, contact + np.array([forward(k * dt), 0.0, 0.0]), np.zeros(3))
    report = drogue.contact_report()
    assert report is not None and report.latched
    assert report.whip is whip
    assert drogue.peak_contact_tension_n == pytest.approx(report.peak_tension_n)
    assert drogue.payout_m < 15.0 - 1.0  # the reel took up the push-in


def test_closure_above_the_window_is_a_whip_risk_in_the_loop() -> None:
    cfg = replace(
        TRUTH,
        plant="linear",
        turbulence="none",
        closure_speed_mps=3.5,
        max_closure_mps=5.0,
        hose_model="multibody",
    )
    out = DockingSimulation(cfg).run()
    assert out.captured and out.closure_speed_mps > 2.6
    assert out.hose_whip_risk
    assert math.isfinite(out.peak_hose_tension_n)


def test_the_run_draw_disperses_the_hose_and_the_guidance_stays_nominal() -> None:
    cfg = replace(TRUTH, imperfections="standard", seed=4, hose_model="multibody")
    sim = DockingSimulation(cfg)
    hs, p = sim.imp_draw.hose_scale, sim.drogue.params
    assert isinstance(p, MultibodyDrogueParams)
    assert p.hose.length_m == pytest.approx(15.0 * hs["hose_length"])
    assert p.hose.mass_per_m_kg == pytest.approx(4.1 * hs["hose_mass"])
    assert p.hose.cd_normal == pytest.approx(1.2 * hs["hose_drag"])
    assert p.drogue.mass_kg == pytest.approx(29.5 * hs["drogue_mass"])
    assert p.drogue.cd == pytest.approx(0.8 * hs["drogue_drag"])
    assert max(abs(v - 1.0) for v in hs.values()) > 0.05
    nominal = DockingSimulation(replace(cfg, imperfections="none")).drogue_model
    assert sim.drogue_model == nominal


def test_default_is_the_reduced_model_welded_at_contact() -> None:
    cfg = replace(TRUTH, turbulence="light", seed=0)
    assert cfg.hose_model == "reduced"
    sim = DockingSimulation(cfg)
    assert isinstance(sim.drogue, HoseDrogue)
    while not sim.done:
        tick = sim.step()
    out = sim.outcome()
    assert out.captured and math.isnan(out.peak_hose_tension_n) and not out.hose_whip
    np.testing.assert_array_equal(tick.drogue_truth_m, tick.probe_tip_m)  # welded


def test_unknown_hose_model_is_refused() -> None:
    with pytest.raises(ValueError, match="hose_model"):
        DockingConfig(hose_model="rope").validate()
