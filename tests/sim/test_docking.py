"""Closed-loop docking: acceptance in calm air with vision in the loop, API shape, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.docking import DockingConfig, DockingSimulation


def test_calm_air_vision_in_the_loop_captures_within_15s_and_5cm():
    # on the controller's design model (plant="linear"); the JSBSim A-4's calm-air precision is
    # a campaign figure (docs/control.md: p95 26 cm, the 5 cm target not met)
    sim = DockingSimulation(
        DockingConfig(plant="linear", turbulence="none", seed=0, vision=True, station_keep_s=0.2)
    )
    locks = 0
    meas_err = []
    tick = None
    while not sim.done:
        tick = sim.step()
        if tick.drogue_measured_m is not None:
            locks += 1
            meas_err.append(np.linalg.norm(tick.drogue_measured_m - tick.drogue_truth_m))
    out = sim.outcome()
    assert out.captured
    assert out.time_to_capture_s <= 15.0
    assert out.miss_distance_m <= 0.05
    assert 0.5 <= out.closure_speed_mps <= 2.0
    assert out.aborts == 0
    # the pipeline really measured the drogue (against simulator truth) on most frames
    assert locks > 0.9 * sim.k
    assert np.median(meas_err) < 0.05
    assert tick is not None and tick.pose is not None and tick.left_image is not None
    assert tick.led_truth_cam_mm is not None and tick.led_truth_cam_mm.shape == (5, 3)


def test_tick_fields_and_frames_truth_mode():
    sim = DockingSimulation(DockingConfig(turbulence="light", seed=1, vision=False))
    tick = sim.step()
    # the A-4 stabilises at the pre-contact position before its first approach
    assert tick.phase == ("stabilise" if sim.stabilise_first else "approach")
    assert tick.uav_state.shape == (12,) and len(tick.uav_state_names) == 12
    assert tick.control.shape == (4,) and tick.control_names[0] == "throttle"
    for v in (tick.drogue_truth_m, tick.drogue_normal, tick.probe_tip_m, tick.reference_m):
        assert v.shape == (3,)
    assert np.allclose(tick.rel_position_m, tick.drogue_truth_m - tick.probe_tip_m)
    # drogue ahead of (x larger than) the probe, about start_gap away; normal points aft
    assert 9.0 < tick.rel_position_m[0] < 11.0
    assert tick.drogue_normal[0] < -0.95  # hose tangent at the drogue: ≈ 11° droop
    assert tick.pose is None and tick.left_image is None
    assert sim.dt == pytest.approx(0.02)


def test_truth_mode_moderate_turbulence_is_deterministic_and_reset_works():
    sim = DockingSimulation(
        DockingConfig(turbulence="moderate", seed=4, vision=False, station_keep_s=0.5)
    )
    a = sim.run()
    sim.reset()
    b = sim.run()
    sim.reset(seed=5)
    c = sim.run()
    assert a == b
    # a named outcome, no safety event (the capture rate is the campaigns' business)
    assert a.outcome in ("captured", "rim_strike", "missed", "aborted")
    assert c.miss_distance_m != a.miss_distance_m


def test_invalid_config_raises_value_error():
    with pytest.raises(ValueError):
        DockingSimulation(DockingConfig(turbulence="hurricane"))
    with pytest.raises(ValueError):
        DockingSimulation(DockingConfig(camera_hz=500.0))
    with pytest.raises(ValueError):
        DockingSimulation(DockingConfig(led_dropout=(9,)))


def test_roi_tracking_alias_renders_only_the_tracker_windows():
    """``roi_tracking`` (deprecated) is ``render_mode="windows"``: full-size images with only
    the tracker's windows rendered, the same drogue measured as with full frames."""
    cfg = DockingConfig(
        turbulence="light", seed=2, vision=True, roi_tracking=True, station_keep_s=0.2
    )
    sim = DockingSimulation(cfg)
    assert sim.effective_render_mode == "windows"
    windowed = 0
    errs = []
    for _ in range(60):
        tick = sim.step()
        if tick.image_windows_px is not None:
            windowed += 1
            assert tick.left_image is not None and tick.left_image.shape == (1024, 1280)
            assert len(tick.image_windows_px[0]) == 5 and len(tick.image_windows_px[1]) == 5
        if tick.drogue_measured_m is not None:
            errs.append(np.linalg.norm(tick.drogue_measured_m - tick.drogue_truth_m))
    assert windowed >= 10  # frames the tracker tracked (at 13 m it still often re-acquires)
    assert len(errs) == 60
    assert np.median(errs) < 0.05


def test_no_lock_without_leds_holds_the_gap_and_never_captures():
    cfg = DockingConfig(
        turbulence="none", seed=0, vision=True, led_dropout=(1, 2, 3, 4, 5), max_time_s=1.5
    )
    sim = DockingSimulation(cfg)
    ticks = []
    while not sim.done:
        ticks.append(sim.step())
    assert all(not t.lock and t.lock_reason for t in ticks)
    assert all(t.drogue_measured_m is None for t in ticks)
    out = sim.outcome()
    assert not out.captured and out.aborts == 0
    # the probe did not close on a drogue it cannot see: it flies the a-priori rest position
    # only down to the search gap (5 m) and holds there
    assert min(t.rel_position_m[0] for t in ticks) > 4.5


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_large_start_offset_is_absorbed_without_saturation_blowup(seed):
    """A 1.5 m (1σ) start offset: the bounded position error keeps the loop out of actuator
    saturation, so the approach still captures."""
    cfg = DockingConfig(
        plant="linear",  # the design model's saturation behaviour (the A-4: campaigns)
        turbulence="moderate",
        seed=seed,
        vision=False,
        start_offset_sigma_m=1.5,
        station_keep_s=0.2,
    )
    out = DockingSimulation(cfg).run()
    assert out.captured
    assert out.miss_distance_m < 0.2
    assert out.max_control_saturation < 0.9


def test_the_a4_stabilises_behind_the_drogue_before_its_first_approach():
    """The first approach as the field flies it (and as after a break-away): the A-4 closes
    from its start gap to the pre-contact position, is held there for the dwell, and only
    then approaches; measured on the flown probe tip and the simulated drogue (truth)."""
    sim = DockingSimulation(DockingConfig(turbulence="none", seed=3, vision=False))
    assert sim.stabilise_first
    dwell = sim.guidance.cfg.rejoin_dwell_s
    pre_contact = sim.guidance.cfg.rejoin_gap_m
    gaps = []
    tick = sim.step()
    while tick.phase == "stabilise" and tick.t_s < 30.0:
        gaps.append(float(tick.rel_position_m[0]))
        tick = sim.step()
    assert tick.phase == "approach"
    assert tick.t_s > dwell + 3.0  # 5 m closed on the rejoin's ramps, then the dwell
    last = np.array(gaps[-int(dwell / sim.dt) :])
    # the fore-aft loop stops the 0.3 m/s² ramp ≈ 0.7 m late (seen 4.3–4.9 m in calm air)
    assert np.all(np.abs(last - pre_contact) < 0.8), (last.min(), last.max())
    assert min(gaps) > pre_contact - 0.8  # no overshoot towards the drogue while stabilising
