"""Contact, latch, reel take-up, whip and release of the multi-body hose."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.hose.atmosphere import flow_from_kcas
from app.sim.hose.contact import Coupling, push_in, push_in_path
from app.sim.hose.model import MultibodyHose
from app.sim.hose.params import CouplingParams, ReelParams

FLOW = flow_from_kcas(15000, 230)
WIDE = CouplingParams(max_closure_mps=8.0)  # a coupling that latches whatever the closure


@pytest.mark.parametrize("closure", [1.0, 1.6, 2.6])
@pytest.mark.parametrize("push", [1.5, 3.0])
def test_reel_keeps_the_hose_taut_through_a_push_in(closure: float, push: float) -> None:
    r = push_in(MultibodyHose(FLOW), closure, push)
    assert r.latched and not r.released and not r.whip
    assert r.max_take_up_m == pytest.approx(push, abs=0.15)  # the reel took the hose up
    assert r.peak_tension_n < 1.3 * r.trail_tension_n
    assert r.slack_time_s <= 0.3  # at most a brief slack while the reel spins up


def test_slower_closures_never_go_slack() -> None:
    r = push_in(MultibodyHose(FLOW), 1.6, 3.0)
    assert r.slack_time_s == 0.0 and r.slack_wave == ()
    assert r.min_tension_n > 0.0  # (it dips as the contact wave runs up the hose)


def test_closure_outrunning_the_reel_whips_the_hose() -> None:
    r = push_in(MultibodyHose(FLOW), 4.5, 3.0, coupling=WIDE)
    assert r.whip
    assert r.peak_tension_n > 1.5 * r.trail_tension_n
    assert r.slack_time_s > 0.3 and r.max_slack_segments >= 5
    # the slack wave: the slack region's extent changes over the ticks (it travels)
    ends = {round(s.end_m, 2) for s in r.slack_wave}
    starts = {round(s.start_m, 2) for s in r.slack_wave}
    assert len(ends | starts) > 3
    # a lighter reel (slower, weaker) whips worse at the same closure
    slow = MultibodyHose(FLOW, reel=ReelParams(max_speed_mps=2.0))
    r_slow = push_in(slow, 4.5, 3.0, coupling=WIDE)
    assert r_slow.peak_tension_n > r.peak_tension_n


@pytest.mark.parametrize(("closure", "word"), [(0.5, "outside"), (3.0, "outside")])
def test_no_latch_outside_the_window(closure: float, word: str) -> None:
    r = push_in(MultibodyHose(FLOW), closure, 2.0)
    assert not r.latched and word in r.reason
    assert np.isnan(r.peak_tension_n)


def test_coupling_releases_when_the_receiver_pulls_back() -> None:
    hose = MultibodyHose(FLOW)
    c = Coupling(hose)
    start = hose.drogue_m
    assert c.contact(1.5, start)
    dt = 0.02
    for k in range(1, 400):  # the receiver drops back at 2 m/s: the reel reaches its stop
        c.step(dt, start - np.array([2.0 * k * dt, 0.0, 0.0]))
        if c.released:
            break
    r = c.report()
    assert r.released and "released" in r.reason
    assert r.peak_coupling_pull_n > CouplingParams().release_load_n
    assert not hose.latched
    hose.step(dt)  # free again: no probe needed


def test_push_in_path_stops_at_the_push_in() -> None:
    f = push_in_path(2.0, 3.0)
    assert f(0.0) == 0.0 and f(100.0) == pytest.approx(3.0)
    assert (f(0.011) - f(0.01)) / 0.001 == pytest.approx(2.0, rel=0.01)
    with pytest.raises(ValueError):
        push_in_path(0.0, 1.0)


def test_report_says_where_the_peak_was() -> None:
    r = push_in(MultibodyHose(FLOW), 1.6, 3.0)
    # at a gentle push-in the highest tension stays at the reel exit (the trail tension)
    assert 0.0 < r.peak_tension_at_m < 1.0
    assert r.peak_tension_n == pytest.approx(r.trail_tension_n, rel=0.01)
