"""app.control.envelope and app.control.recovery: the monitor's bounds, the separation
geometry against hand-computed cases, and the recovery law's signs on the A-4's model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.control.envelope import (
    EnvelopeBounds,
    EnvelopeMonitor,
    FlightData,
    SeparationBounds,
    point_to_polyline_m,
    separation,
)
from app.control.recovery import RecoveryLaw
from app.sim.docking import DockingConfig
from app.sim.docking.plant_design import design_for

LEVEL = FlightData(3.5, 1.0, 0.0, 3.5, 230.0, 4572.0)


def _with(**kw: float) -> FlightData:
    return FlightData(**{**LEVEL.__dict__, **kw})


def test_each_bound_trips_the_monitor_and_trim_does_not() -> None:
    mon = EnvelopeMonitor()
    b = EnvelopeBounds()
    assert mon.envelope_violation(LEVEL, 4572.0) is None
    cases = {
        "α": _with(alpha_deg=b.alpha_max_deg + 0.1),
        "load factor": _with(load_factor_g=b.load_factor_min_g - 0.1),
        "bank": _with(bank_deg=-(b.bank_max_deg + 1)),
        "airspeed": _with(kcas=b.kcas_min - 1),
        "height": _with(altitude_m=4572.0 - b.height_loss_max_m - 1),
    }
    for word, f in cases.items():
        why = mon.envelope_violation(f, 4572.0)
        assert why is not None and word in why
    assert "not finite" in (mon.envelope_violation(_with(alpha_deg=math.nan), 4572.0) or "")


def test_monitor_bounds_sit_inside_the_flight_test_limits() -> None:
    """The recovery starts before the limits the acceptance watches are reached."""
    b = EnvelopeBounds()
    assert -2.0 < b.alpha_min_deg and b.alpha_max_deg < 12.0
    assert -0.5 < b.load_factor_min_g and b.load_factor_max_g < 3.0
    assert b.bank_max_deg < 60.0 and b.height_loss_max_m < 150.0
    assert 180.0 < b.kcas_min and b.kcas_max < 290.0


def test_point_to_polyline_distance_by_hand() -> None:
    nodes = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0]])
    assert point_to_polyline_m(np.array([5.0, 3.0, 4.0]), nodes) == 5.0
    assert point_to_polyline_m(np.array([13.0, 14.0, 0.0]), nodes) == 5.0


def test_separation_skips_the_hose_end_and_sees_the_tanker_plane() -> None:
    b = SeparationBounds()
    hose = np.array([[0.0, 0.0, 0.0], [-5.0, 0.0, 1.0], [-10.0, 0.0, 2.0], [-15.0, 0.0, 3.0]])
    drogue = hose[-1]
    nose_at_drogue = drogue + np.array([-0.6, 0.0, 0.0])
    sep = separation(nose_at_drogue, drogue, drogue, hose, b)
    assert sep.hose_m > 2.0  # the last 2 m of hose (where the probe goes) are not counted
    assert sep.tanker_m == -b.tanker_plane_aft_m - nose_at_drogue[0]
    mon = EnvelopeMonitor()
    on_hose = np.array([-10.0, 0.3, 2.0])  # aft of the tanker's plane, 0.3 m from the hose
    near = separation(on_hose, on_hose, drogue, hose, b)
    assert "hose" in (mon.keep_out_violation(near) or "")


def test_recovery_law_levels_the_wings_pulls_power_and_holds_a_descent() -> None:
    model = design_for(DockingConfig(plant="jsbsim", vision=False)).design.model
    law = RecoveryLaw(model)
    x = np.zeros(12)
    x[6] = math.radians(10.0)  # right wing down
    u = law.command(x, speed_mps=1.5, sink_rate_mps=0.0, aft_m=1.0, below_m=0.0)
    assert u[0] < 0  # power back while closing
    assert u[1] * model.b[3, 1] < 0  # the aileron rolls left (towards wings level)
    # level at trim pitch, asked to descend: the elevator pitches the nose down
    u2 = law.command(np.zeros(12), speed_mps=0.0, sink_rate_mps=0.0, aft_m=1.0, below_m=0.0)
    assert u2[2] * model.b[4, 2] < 0
    # beyond the drop-back's aim (standoff + margin), moving with the tanker: no more throttle
    law.reset()
    u3 = law.command(np.zeros(12), speed_mps=0.0, sink_rate_mps=0.0, aft_m=17.0, below_m=6.0)
    assert u3[0] == 0.0


def test_recovery_law_drifts_back_to_its_lateral_station_slowly() -> None:
    """Off to the right of the station it held at the take-over, with no side speed: the law
    banks left, gently (the commanded side speed is capped), and not at all on station."""
    model = design_for(DockingConfig(plant="jsbsim", vision=False)).design.model
    law = RecoveryLaw(model)
    on_station = law.command(np.zeros(12), 0.0, 0.0, 12.0, 4.0, 0.0, 0.0)
    assert on_station[1] == 0.0
    right = law.command(np.zeros(12), 0.0, 0.0, 12.0, 4.0, 0.0, 8.0)
    assert right[1] * model.b[3, 1] < 0  # rolls left, back towards the station
    far_right = law.command(np.zeros(12), 0.0, 0.0, 12.0, 4.0, 0.0, 80.0)
    # the side speed asked for is capped (1 m/s): 80 m off asks no more than 10 m off
    ten = law.command(np.zeros(12), 0.0, 0.0, 12.0, 4.0, 0.0, 10.0)
    assert far_right[1] == pytest.approx(ten[1])
    # moving back at the capped speed already: no more bank
    back = law.command(np.zeros(12), 0.0, 0.0, 12.0, 4.0, -1.0, 80.0)
    assert back[1] == pytest.approx(0.0, abs=1e-12)


def test_the_drop_back_slows_into_the_standoff_on_its_braking_curve() -> None:
    """The commanded drop-back speed is −min(8, √(2 · 1 m/s² · distance to 16 m aft)), by hand;
    the speed brakes are out only while short of the standoff and faster than that; the
    sink-rate integrator is clipped (a wound-up integral kept the receiver sinking 10–18 m
    below the standoff)."""
    model = design_for(DockingConfig(plant="jsbsim", vision=False)).design.model
    law = RecoveryLaw(model)
    g = law.gains
    aim = g.standoff_aft_m + g.standoff_margin_aft_m
    assert aim == 16.0 and g.brake_mps2 == 1.0
    assert law.drop_back_profile(0.0) == pytest.approx(-math.sqrt(32.0))  # under the 8 m/s cap
    assert law.drop_back_profile(-20.0) == -g.drop_back_mps
    assert law.drop_back_profile(8.0) == pytest.approx(-4.0)  # √(2 · 8)
    assert law.drop_back_profile(14.0) == pytest.approx(-2.0)  # √(2 · 2)
    assert law.drop_back_profile(16.0) == 0.0 and law.drop_back_profile(30.0) == 0.0
    assert law.speedbrake(-3.0, 8.0) == 1.0  # faster (forward) than −4 m/s at 8 m
    assert law.speedbrake(-5.0, 8.0) == 0.0  # already dropping back faster than the curve
    assert law.speedbrake(-1.0, 12.0) == 0.0  # past the standoff
    law.reset(0.02)
    for _ in range(2000):  # 40 s asked to sink at 3 m/s while climbing
        law.command(np.zeros(12), 0.0, -1.0, 0.0, 0.0)
    assert abs(law.sink_error_integral) == pytest.approx(g.sink_integral_max_m)
