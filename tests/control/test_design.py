"""app.control.design: the controller designed on each plant's linearisation, and the guidance
choices that go with the A-4 (app.sim.docking)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from app.control.design import A4_WEIGHTS, AEROSONDE_WEIGHTS, design_controller
from app.control.margins import closed_loop_matrix, delay_margin_ticks, spectral_radius
from app.sim.docking import DockingConfig, DockingSimulation
from app.sim.jsbsim_plant import JsbsimCondition, JsbsimPlant
from app.sim.receiver import FlightCondition, LinearReceiver

DT = 0.02


@cache
def a4():  # type: ignore[no-untyped-def]
    plant = JsbsimPlant(JsbsimCondition(), 1.0 / DT)
    return plant, design_controller(plant.model, DT, (8.2, 0.5, -0.3), A4_WEIGHTS)


def test_a4_design_is_stable_with_margin_on_its_own_linearisation():
    plant, d = a4()
    assert d.lqr_design_lag_s[0] == pytest.approx(plant.engine_lag_s)  # the engine's spool-up
    assert 0.05 < plant.engine_lag_s < 0.2
    assert spectral_radius(closed_loop_matrix(**d.margin_loop(DT))) < 1.0
    # observer + LQR keep ≥ 3 ticks (60 ms) of input-delay margin on the design model
    assert delay_margin_ticks(**d.margin_loop(DT)) >= 3
    # the JSBSim FDM at the design condition is what the matrices were linearised from
    np.testing.assert_allclose(d.model.x_trim[7], np.radians(plant.trim.theta_deg), atol=1e-6)


def test_a4_gains_keep_the_commands_inside_their_travel_for_small_errors():
    """A 0.1 m lateral and vertical tip error asks for less than a tenth of each command's
    travel from trim (the heavy jet's gains are not the Aerosonde's)."""
    plant, d = a4()
    x = np.zeros(12)
    x[10] = x[11] = 0.1
    u = -d.lqr_kp @ x
    lim = d.model.limits
    room = np.minimum(np.array(lim.upper) - d.model.u_trim, d.model.u_trim - np.array(lim.lower))
    assert np.all(np.abs(u) < 0.1 * room), u / room


def test_aerosonde_design_is_the_linear_plants():
    rec = LinearReceiver(condition=FlightCondition(airspeed_mps=120.0, air_density=0.909))
    d = design_controller(rec.linear_model(), DT, (3.0, 0.0, -0.3), AEROSONDE_WEIGHTS)
    sim = DockingSimulation(DockingConfig(plant="linear", vision=False))
    np.testing.assert_array_equal(d.lqr_kp, sim.models.lqr_kp)
    assert d.lqr_design_lag_s == 0.03


def test_plant_guidance_defaults_and_overrides():
    lin = DockingSimulation(DockingConfig(plant="linear", vision=False))
    jsb = DockingSimulation(DockingConfig(plant="jsbsim", vision=False))
    assert (lin.smoothing_s, lin.swing_abort) == (0.0, False)
    assert (jsb.smoothing_s, jsb.swing_abort) == (8.0, True)
    own = DockingSimulation(
        DockingConfig(
            plant="jsbsim", vision=False, reference_smoothing_s=0.0, swing_model_abort=False
        )
    )
    assert (own.smoothing_s, own.swing_abort) == (0.0, False)
    # issue 21 follow-up: the A-4's bow-wave and closure feed-forward, swing lead, margin
    assert (jsb.bow_ff, jsb.closure_ff, jsb.swing_lead, jsb.abort_margin) == (True, True, 1.0, 3.0)
    assert (lin.bow_ff, lin.closure_ff, lin.swing_lead, lin.abort_margin) == (False, False, 0, 1.5)
    assert not jsb.timed and jsb.guidance.cfg.standoff_gap_m is None
    off = DockingSimulation(
        DockingConfig(
            plant="jsbsim", vision=False, bow_feedforward=False, swing_lead=0.0, abort_margin=1.5
        )
    )
    assert (off.bow_ff, off.swing_lead, off.abort_margin) == (False, 0.0, 1.5)


def test_a4_bow_wave_feedforward_aims_where_the_drogue_is_pushed():
    """Calm air, truth measurements: with the feed-forward the probe meets the drogue where
    the bow wave has pushed it (≈ 0.2 m out and up); without it the probe arrives where the
    drogue was."""
    misses = {}
    for ff in (True, False):
        sim = DockingSimulation(
            DockingConfig(
                plant="jsbsim", turbulence="none", vision=False, seed=1, bow_feedforward=ff
            )
        )
        out = sim.run()
        assert out.captured
        misses[ff] = out.miss_distance_m
        pushed = float(np.linalg.norm(sim.drogue.d[1:]))
    assert misses[True] < 0.05 < misses[False]
    assert pushed > 0.1


def test_one_break_away_counts_one_abort_until_the_gap_is_open_again():
    sim = DockingSimulation(DockingConfig(plant="linear", vision=False, turbulence="none"))
    while float(sim.drogue.position_m[0] - sim.probe_tip()[0]) > 0.8:
        sim.step()
    sim.break_away()
    sim.step()
    sim.break_away()  # the same break-away: the probe is still close
    assert sim.aborts == 1 and sim.rta_reason is not None  # the recovery law flies
    while float(sim.drogue.position_m[0] - sim.probe_tip()[0]) < 2.0 and sim.t < 30:
        sim.step()
    sim.step()
    assert not sim.captured
    sim.break_away()
    assert sim.aborts == 2


def test_a4_timed_closure_holds_at_the_standoff_then_commits_and_captures():
    """The timed closure (an option on the A-4, not its default): calm air, truth
    measurements — the reference stops at the standoff, the swing prediction (no swing)
    commits, and the probe captures."""
    sim = DockingSimulation(
        DockingConfig(plant="jsbsim", turbulence="none", vision=False, seed=1, timed_closure=True)
    )
    held = committed = False
    while not sim.done:
        sim.step()
        held = held or sim.guidance.holding
        committed = committed or sim.guidance.committed
    assert held and committed
    out = sim.outcome()
    assert out.captured and out.aborts == 0 and out.miss_distance_m < 0.1
