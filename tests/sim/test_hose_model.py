"""The multi-body hose in time: it rests on its steady shape, its free swing follows the
linearised modes, a steady cross-wind turns it into the relative wind, and the hooks (gusts
along the hose, a force on the drogue) act where they should."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.hose.atmosphere import flow_from_kcas
from app.sim.hose.model import FrozenGust, MultibodyHose, combined, wake_field
from app.sim.hose.params import DrogueParams, HoseParams
from app.sim.hose.steady import steady_shape, swing_modes
from app.sim.turbulence import DrydenTurbulence

FLOW = flow_from_kcas(15000, 230)
DT = 0.02  # the docking loop's tick (DockingConfig.tick_hz = 50)


def test_rests_on_its_steady_shape_at_the_tick_rate() -> None:
    hose = MultibodyHose(FLOW)
    assert hose.substeps(DT) >= 2  # substepped below the axial stability limit
    for _ in range(250):
        tick = hose.step(DT)
    assert np.abs(hose.nodes_m - hose.steady.nodes_m).max() < 1e-6
    assert tick.slack_segments == 0 and tick.payout_m == 15.0
    assert hose.reel_tension_n == pytest.approx(hose.trail_tension_n, rel=1e-6)


def test_free_lateral_swing_follows_the_linearised_mode() -> None:
    hose = MultibodyHose(FLOW)
    modes = swing_modes(FLOW, HoseParams(), DrogueParams(), hose.steady)
    hose.vel[-1, 1] = 0.5  # a lateral kick on the drogue
    y = []
    for _ in range(int(20.0 / DT)):
        hose.step(DT)
        y.append(hose.drogue_m[1])
    y_arr = np.array(y)
    t = DT * np.arange(1, len(y_arr) + 1)
    up = np.flatnonzero((y_arr[:-1] < 0) & (y_arr[1:] >= 0))
    period = np.mean(np.diff(t[up]))
    assert 1.0 / period == pytest.approx(modes.lateral.frequency_hz, rel=0.02)
    # decay of the peaks over the cycles: exp(−ζ ω t)
    peaks = [np.max(y_arr[a:b]) for a, b in zip(up[:-1], up[1:], strict=False)]
    rate = -np.polyfit(t[up[:-1]], np.log(peaks), 1)[0]
    w = 2 * np.pi * modes.lateral.frequency_hz
    assert rate / w == pytest.approx(modes.lateral.damping_ratio, rel=0.15)


def test_steady_cross_wind_turns_the_hose_into_the_relative_wind() -> None:
    wind = np.array([0.0, 3.0, 0.0])
    hose = MultibodyHose(FLOW)
    for _ in range(int(40.0 / DT)):
        hose.step(DT, air=lambda p, t: np.tile(wind, (len(p), 1)))
    marched = steady_shape(FLOW, HoseParams(), DrogueParams(), wind_mps=wind)
    assert np.abs(hose.nodes_m - marched.nodes_m).max() < 0.01
    # the whole line turns by the wind's angle g/V (drogue ≈ L g / V to the right)
    assert hose.drogue_m[1] == pytest.approx(-hose.drogue_m[0] * 3.0 / FLOW.airspeed_mps, rel=0.05)


def test_frozen_gust_reaches_the_aft_nodes_later() -> None:
    gust = FrozenGust(100.0, 0.01)
    for k in range(10):
        gust.push(np.array([0.0, float(k), 0.0]))
    points = np.array([[0.0, 0.0, 0.0], [-5.0, 0.0, 0.0], [-2.5, 0.0, 0.0]])
    out = gust(points, 0.0)
    # 5 m aft at 100 m/s: 0.05 s = 5 ticks ago; 2.5 m: 2.5 ticks (interpolated)
    assert out[:, 1] == pytest.approx([9.0, 4.0, 6.5])


def test_force_on_the_drogue_moves_it() -> None:
    hose = MultibodyHose(FLOW)
    for _ in range(int(30.0 / DT)):
        hose.step(DT, drogue_force_n=np.array([0.0, 0.0, -60.0]))  # 60 N up (a bow wave)
    rise = hose.steady.drogue_m[2] - hose.drogue_m[2]
    assert 0.1 < rise < 1.0


def test_bad_tick_is_refused() -> None:
    hose = MultibodyHose(FLOW)
    with pytest.raises(ValueError):
        hose.step(0.0)
    hose.latch(hose.drogue_m, 2e4, 1500.0)
    with pytest.raises(ValueError, match="probe"):
        hose.step(DT)


def test_wake_pushes_the_hose_down_and_fields_add() -> None:
    wake = wake_field(downwash_mps=2.0, sidewash_per_m=0.0)
    pts = np.array([[0.0, 0.0, 0.0], [-20.0, 0.0, 0.0]])
    assert wake(pts, 0.0)[:, 2] == pytest.approx([2.0, 1.0])  # full at the tanker, half at 20 m
    both = combined(wake, lambda p, t: np.tile([0.0, 1.0, 0.0], (len(p), 1)))
    assert both(pts, 0.0)[1] == pytest.approx([0.0, 1.0, 1.0])
    hose = MultibodyHose(FLOW)
    for _ in range(int(20.0 / DT)):
        hose.step(DT, air=wake)
    # the downwash tilts the relative wind down by ≈ w/V: the drogue sinks by ≈ L w / V
    sink = hose.drogue_m[2] - hose.steady.drogue_m[2]
    assert 0.1 < sink < 15.0 * 2.0 / FLOW.airspeed_mps * 1.2


def test_non_finite_inputs_are_refused() -> None:
    hose = MultibodyHose(FLOW)
    with pytest.raises(ValueError, match="finite"):
        hose.step(DT, drogue_force_n=np.array([np.nan, 0.0, 0.0]))
    hose.latch(hose.drogue_m, 2e4, 1500.0)
    with pytest.raises(ValueError, match="probe"):
        hose.step(DT, probe_m=np.array([0.0, np.inf, 0.0]))


def test_moderate_dryden_turbulence_along_the_hose() -> None:
    """60 s of moderate Dryden turbulence carried along the hose at the tick: finite, taut, and
    a lateral drogue motion of the size the reduced-order model gives (σ ≈ 0.35–0.4 m here)."""
    turb = DrydenTurbulence("moderate", FLOW.airspeed_mps, DT, 15000 * 0.3048, seed=3)
    gust = FrozenGust(FLOW.airspeed_mps, DT)
    hose = MultibodyHose(FLOW)
    y, low = [], np.inf
    for _ in range(int(60.0 / DT)):
        gust.push(turb.step())
        tick = hose.step(DT, gust)
        y.append(hose.drogue_m[1])
        low = min(low, tick.min_tension_n)
    assert np.isfinite(hose.nodes_m).all()
    assert low > 0.5 * hose.trail_tension_n
    assert 0.15 < float(np.std(y)) < 0.8
