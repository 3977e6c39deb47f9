"""app.control.loop_margins: the margins against python-control's own disk margins and a
hand-solvable loop, and the A-4 design's floors (issue 30)."""

from __future__ import annotations

import math
import warnings
from functools import cache

import control
import numpy as np
import pytest

from app.control.loop_margins import DiskMargin, LoopMargins, design_margins, disk_margin
from app.sim.docking import DockingConfig
from app.sim.docking.plant_design import design_for
from app.sim.imperfections import HARSH, STANDARD

DT = 0.02


def test_disk_margin_matches_python_controls_on_a_siso_loop() -> None:
    """A SISO loop (python-control's own ``disk_margins`` needs no slycot there)."""
    loop = control.c2d(control.tf([4.0], [1.0, 2.0, 0.0]) * control.tf([1.0], [0.05, 1.0]), DT)
    ours = disk_margin(control.ss(loop), DT, points=2000)
    w = np.geomspace(1e-3, math.pi / DT * 0.999, 2000)
    dm, dgm, dpm = control.disk_margins(loop, w, skew=0.0)
    assert ours.alpha == pytest.approx(float(dm), rel=1e-3)
    assert ours.phase_margin_deg == pytest.approx(float(dpm), rel=1e-3)
    assert ours.gain_margin_db == pytest.approx(float(dgm), rel=1e-3)  # both in dB


def test_disk_margin_of_a_static_gain_is_the_closed_form() -> None:
    """L = k: (S − T)/2 = (1 − k)/(2(1 + k)), so α = 2(1 + k)/|1 − k|."""
    k = 3.0
    dm: DiskMargin = disk_margin(control.ss([], [], [], [[k]], DT), DT)
    assert dm.alpha == pytest.approx(2 * (1 + k) / abs(1 - k))


@cache
def _a4(lag_s: float) -> LoopMargins:
    design = design_for(DockingConfig(plant="jsbsim", vision=False)).design
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return design_margins(design, DT, lag_s)


def test_a4_per_loop_margins_with_the_standard_lag() -> None:
    """Each loop ≥ 6 dB either way and ≥ 45° with the `standard` servo lag (MIL-F-9490D)."""
    m = _a4(STANDARD.actuator_lag_s)
    for s in m.per_loop:
        assert s.gain_margin_db >= 6.0, s
        assert s.gain_reduction_margin_db <= -6.0, s
        assert abs(s.phase_margin_deg) >= 45.0, s


def test_a4_all_loops_at_once_and_delay_with_the_harsh_lag() -> None:
    """All four inputs perturbed at once ≥ ±4 dB / 30°, and every loop keeps ≥ 2 × the
    harsh camera latency (160 ms) of delay margin, with the `harsh` servo lag."""
    m = _a4(HARSH.actuator_lag_s)
    assert m.disk.gain_margin_db >= 4.0 and m.disk.phase_margin_deg >= 30.0, m.disk
    assert min(s.delay_margin_s for s in m.per_loop) >= 2 * HARSH.latency_s
