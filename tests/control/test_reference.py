"""The reference trajectory's rejoin after a break-away (app/control/reference.py)."""

from __future__ import annotations

import numpy as np
import pytest

from app.control.reference import GuidanceConfig, ReferenceGenerator

DT = 0.02


def test_the_rejoin_brings_the_reference_back_at_bounded_speeds_with_its_velocity() -> None:
    """From 30 m behind, 4 m below and 6 m to the right of the drogue: the reference starts
    where the probe is, moves back at ≤ 2 m/s fore-aft while far and ≤ 1 m/s near, sideways
    and up; its velocity is the finite difference of its position (the LQR's feed-forward);
    the approach begins only after the dwell at the pre-contact position, on the drogue's line."""
    cfg = GuidanceConfig(closure_speed_mps=1.6)
    g = ReferenceGenerator(cfg, start_gap_m=10.0)
    drogue = np.array([-14.0, 0.5, 4.0])
    g.start_rejoin(30.0, 4.0, 6.0)
    ref, _ = g.update(DT, drogue, np.zeros(3), lock=True)
    assert ref == pytest.approx(drogue + np.array([-30.0, 6.0, 4.0]), abs=0.05)
    t, prev = DT, ref
    while g.phase == "rejoin" and t < 60.0:
        ref, vel = g.update(DT, drogue, np.zeros(3), lock=True)
        step = (ref - prev) / DT
        assert vel == pytest.approx(step, abs=1e-6)
        gap_before = drogue[0] - prev[0]
        fast = cfg.rejoin_far_speed_mps if gap_before > 15.0 else cfg.rejoin_speed_mps
        assert step[0] <= fast + 1e-9
        assert np.all(np.abs(step[1:]) <= cfg.rejoin_speed_mps + 1e-9)
        prev, t = ref, t + DT
    assert g.phase == "approach"
    assert ref == pytest.approx(drogue - np.array([cfg.rejoin_gap_m, 0.0, 0.0]), abs=1e-9)
    # 15 m at 2 m/s, 10 m at 1 m/s, then the dwell: ≈ 21.5 s (1 m/s all the way: 29 s)
    assert t == pytest.approx(15 / 2 + 10 + cfg.rejoin_dwell_s, abs=0.2)
