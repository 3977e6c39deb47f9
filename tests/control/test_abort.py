"""The break-away checks of app.control.abort: the overspeed and the high pass."""

import numpy as np
import pytest

from app.control.abort import describe, offset_at_plane_m, should_abort

RIM_M = 0.305


def _height_at_plane_by_stepping(tip_m, tip_vel, drogue_m, drogue_vel, dt=1e-4):
    """Fly both points on straight lines until the tip reaches the drogue's plane."""
    tip, d = np.array(tip_m, float), np.array(drogue_m, float)
    while d[0] - tip[0] > 0:
        tip = tip + dt * np.asarray(tip_vel)
        d = d + dt * np.asarray(drogue_vel)
    return float(d[2] - tip[2])  # z down: the drogue lower than the tip is the tip above


def test_the_predicted_height_above_is_the_straight_line_height_at_the_plane():
    tip, tip_vel = np.array([-13.6, 0.1, 2.05]), np.array([2.7, 0.0, -0.7])
    drogue, drogue_vel = np.array([-12.0, 0.2, 2.3]), np.array([0.3, 0.0, -0.3])
    rel, rel_vel = drogue - tip, drogue_vel - tip_vel
    predicted = float(offset_at_plane_m(rel, rel_vel)[1])
    assert predicted == pytest.approx(
        _height_at_plane_by_stepping(tip, tip_vel, drogue, drogue_vel), abs=1e-3
    )
    assert predicted > 0.5  # the traced keep-out approach (seed 360087): a high pass
    below = float(offset_at_plane_m(np.array([1.6, 0.0, -0.4]), np.array([-2.0, 0.0, 0.0]))[1])
    assert below == pytest.approx(-0.4)  # a tip below the drogue stays below


def test_a_high_pass_breaks_away_inside_its_gap_only():
    high = dict(above_at_plane_m=0.7, high_gap_m=2.5, high_pass_m=0.5)
    assert should_abort(2.0, 0.0, RIM_M, lock_lost=False, **high) == "passing_high"
    assert should_abort(3.0, 0.0, RIM_M, lock_lost=False, **high) is None  # too far yet
    assert should_abort(-0.1, 0.0, RIM_M, lock_lost=False, **high) is None  # past the plane
    low = dict(
        above_at_plane_m=-0.7, high_gap_m=2.5, high_pass_m=0.5
    )  # passing below: the hose is not there
    assert should_abort(2.0, 0.0, RIM_M, lock_lost=False, **low) is None
    rim = dict(above_at_plane_m=0.4, high_gap_m=2.5, high_pass_m=0.5)  # about the rim: carry on
    assert should_abort(2.0, 0.0, RIM_M, lock_lost=False, **rim) is None


def test_an_overspeed_breaks_away_before_the_plane_and_not_at_latching_speeds():
    fast = dict(closure_mps=2.8, max_closure_mps=2.6, overspeed_gap_m=2.0)
    assert should_abort(1.5, 0.0, RIM_M, lock_lost=False, **fast) == "overspeed"
    assert should_abort(2.5, 0.0, RIM_M, lock_lost=False, **fast) is None
    latching = dict(closure_mps=2.4, max_closure_mps=2.6, overspeed_gap_m=2.0)
    assert should_abort(1.5, 0.0, RIM_M, lock_lost=False, **latching) is None
    # the defaults leave both new checks off: the paper's two reasons alone
    assert should_abort(0.5, 0.0, RIM_M, lock_lost=False, closure_mps=9.0) is None


def test_each_reason_reads_as_words():
    assert describe("predicted_miss", 1.234, 0.0) == "predicted miss 1.23 m"
    assert "2.80 m/s" in describe("overspeed", 0.0, 2.8)
    assert "high over the drogue" in describe("passing_high", 0.0, 0.0)
    assert describe("lock_lost", 0.0, 0.0) == "lock lost"
