"""The recovery law flown on JSBSim's A-4 (not on the model it was written from): the break-away's
descent in the updraft that lifted the receiver over the drogue.

Two keep-outs of the held-out harsh·moderate campaign (seeds 370022 and 370090) were high
misses in an updraft of ≈ 4–5 m/s: the recovery law's attitude hold stopped ≈ 1.5° short of its
command (a PD hold against the A-4's pitch stiffness) and its sink-rate integral could add only
1.5 m/s, so the receiver held its height for 1.5–2 s after the crossing while it overshot the
plane, and the nose came within 0.21–0.28 m of the hose. The figures below are JSBSim's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from app.control.envelope import EnvelopeBounds
from app.control.recovery import RecoveryGains, RecoveryLaw
from app.sim.docking import DockingConfig
from app.sim.docking.plant_design import design_for
from app.sim.jsbsim_plant import JsbsimPlant


def _descent_in_updraft(
    gains: RecoveryGains, updraft_mps: float, seconds: float
) -> tuple[float, float]:
    """Fly the recovery law on JSBSim from trim into a steady updraft that starts with the
    take-over (the probe at the drogue's plane and height): the height lost after ``seconds``
    (m, down +) and the least α flown (deg)."""
    cfg = DockingConfig(plant="jsbsim", vision=False)
    model = design_for(cfg).design.model
    dt = 1.0 / cfg.tick_hz
    plant = JsbsimPlant(cfg.jsbsim_condition(None), cfg.tick_hz, model)
    x = plant.reset(np.zeros(12))
    law = RecoveryLaw(model, gains)
    law.reset(dt)
    air = np.array([0.0, 0.0, -updraft_mps])  # tanker axes, z down: an updraft is −z
    z0, prev, alpha_min = float(x[11]), x.copy(), np.inf
    for k in range(round(seconds / dt)):
        speed = (x[9] - prev[9]) / dt if k else 0.0
        sink = (x[11] - prev[11]) / dt if k else 0.0
        prev = x.copy()
        x = plant.step(law.command(x, speed, sink, aft_m=0.0, below_m=0.0), air)
        alpha_min = min(alpha_min, plant.flight_data().alpha_deg)
    return float(x[11]) - z0, float(alpha_min)


@pytest.mark.parametrize("updraft_mps", [0.0, 4.0])
def test_the_break_away_descends_within_two_seconds_even_in_an_updraft(updraft_mps: float) -> None:
    """≥ 1 m below the plane 2 s after the take-over (the receiver overshoots the plane by
    2–3 m in that time), with α ≥ 1° above the monitor's floor all the while."""
    lost_m, alpha_min = _descent_in_updraft(RecoveryGains(), updraft_mps, 2.0)
    assert lost_m >= 1.0, f"only {lost_m:.2f} m lower after 2 s in a {updraft_mps} m/s updraft"
    assert alpha_min >= EnvelopeBounds().alpha_min_deg + 1.0


def test_the_old_hold_stayed_level_for_two_seconds_in_a_4_mps_updraft() -> None:
    """The gains before (ω_θ 2 rad/s, sink integral 0.5 /s clipped at 3 m) in the same 4 m/s
    updraft: no height lost after 2 s — what the new defaults fix."""
    old = replace(
        RecoveryGains(), omega_pitch_rad_s=2.0, sink_integral_per_s=0.5, sink_integral_max_m=3.0
    )
    lost_m, _ = _descent_in_updraft(old, 4.0, 2.0)
    assert lost_m < 0.3
