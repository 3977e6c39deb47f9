"""The reference trajectory's rejoin after a break-away (app/control/reference.py)."""

from __future__ import annotations

import numpy as np
import pytest

from app.control.reference import GuidanceConfig, ReferenceGenerator

DT = 0.02


def test_the_rejoin_brings_the_reference_back_smoothly_at_bounded_speeds() -> None:
    """From 30 m behind, 4 m below and 6 m to the right of the drogue: the reference starts
    where the probe is, with no velocity (the LQR's feed-forward must not step at the
    hand-back); it moves back at ≤ 2 m/s fore-aft while far and ≤ 1.5 m/s otherwise, its
    velocity changing at ≤ 0.3 m/s², and slows into the end on its braking curve (no
    overshoot past the pre-contact gap, no hunting about it); its velocity is the finite difference of its position; the
    approach begins only after the dwell at the pre-contact position, on the drogue's line."""
    cfg = GuidanceConfig(closure_speed_mps=1.6)
    g = ReferenceGenerator(cfg, start_gap_m=10.0)
    drogue = np.array([-14.0, 0.5, 4.0])
    g.start_rejoin(30.0, 4.0, 6.0)
    ref, vel = g.update(DT, drogue, np.zeros(3), lock=True)
    assert ref == pytest.approx(drogue + np.array([-30.0, 6.0, 4.0]), abs=0.01)
    assert np.all(np.abs(vel) <= cfg.rejoin_accel_mps2 * DT + 1e-9)
    t, prev, prev_vel = DT, ref, vel
    while g.phase == "rejoin" and t < 90.0:
        ref, vel = g.update(DT, drogue, np.zeros(3), lock=True)
        assert vel == pytest.approx((ref - prev) / DT, abs=1e-6)
        assert vel[0] <= cfg.rejoin_far_speed_mps + 1e-9
        assert np.all(np.abs(vel[1:]) <= cfg.rejoin_speed_mps + 1e-9)
        if drogue[0] - prev[0] < cfg.rejoin_gap_m + 1.0:  # the last metre: the near speed
            assert vel[0] <= cfg.rejoin_speed_mps + 1e-9
        assert np.all(np.abs(vel - prev_vel) <= cfg.rejoin_accel_mps2 * DT + 0.05 + 1e-9)
        assert g.gap_cmd >= cfg.rejoin_gap_m - 1e-9  # never past the pre-contact gap
        assert not np.any(np.sign(vel) * np.sign(prev_vel) < 0)  # no reversal: no hunting
        prev, prev_vel, t = ref, vel, t + DT
    assert g.phase == "approach"
    assert ref == pytest.approx(drogue - np.array([cfg.rejoin_gap_m, 0.0, 0.0]), abs=1e-9)
    # 25 m fore-aft: the ramps at 0.3 m/s² and ≈ 2 m/s between them, ≈ 20 s (the slowing as
    # distance / 2 s took 24.6 s, the last half metre at a creep)
    assert t < 21.0 + cfg.rejoin_dwell_s


def test_the_first_approach_stabilises_at_the_pre_contact_position_then_closes() -> None:
    """``start_stabilise``: from the start gap the reference closes to the pre-contact gap on
    the drogue's line without overshooting it, holds there ``rejoin_dwell_s`` (the phase is
    "stabilise", not "rejoin": no break-away happened), then the approach closes."""
    cfg = GuidanceConfig(closure_speed_mps=1.6)
    g = ReferenceGenerator(cfg, start_gap_m=10.0)
    drogue = np.array([-14.0, 0.5, 4.0])
    g.start_stabilise(10.0)
    assert g.phase == "stabilise"
    t, at_pre_contact = 0.0, None
    while g.phase == "stabilise" and t < 60.0:
        ref, vel = g.update(DT, drogue, np.zeros(3), lock=True)
        t += DT
        assert ref[1:] == pytest.approx(drogue[1:], abs=1e-9)  # on the drogue's line
        assert g.gap_cmd >= cfg.rejoin_gap_m - 1e-9
        if at_pre_contact is None and g.gap_cmd <= cfg.rejoin_gap_m + 1e-9:
            at_pre_contact = t
    assert g.phase == "approach" and at_pre_contact is not None
    assert t - at_pre_contact == pytest.approx(cfg.rejoin_dwell_s, abs=2 * DT)
    gap0 = g.gap_cmd
    for _ in range(50):
        g.update(DT, drogue, np.zeros(3), lock=True)
    assert g.gap_cmd < gap0 - 0.5  # closing after the dwell
