"""The contact as the field defines it (:class:`app.sim.docking.outcomes.ContactReport`): the
probe head (radius 0.045 m) inside the rim (0.305 m) less its radius at a closure inside the
latch window is a capture; across the rim zone a rim strike; beyond it a miss, whose reason
says how far from the centre and how far outside the rim."""

from __future__ import annotations

import pytest

from app.sim.docking.outcomes import ContactReport

RIM, HEAD, WINDOW = 0.305, 0.045, (1.0, 2.6)


@pytest.mark.parametrize(
    ("miss_m", "closure_mps", "outcome"),
    [
        (0.10, 1.6, "captured"),
        (0.26, 1.6, "captured"),  # the head just inside the rim
        (0.27, 1.6, "rim_strike"),
        (0.35, 1.6, "rim_strike"),  # the head's edge on the rim
        (0.36, 1.6, "missed"),
        (0.10, 0.8, "missed"),  # too slow to latch
        (0.10, 2.8, "missed"),  # faster than the coupling latches
    ],
)
def test_each_crossing_is_judged_by_the_head_and_the_latch_window(
    miss_m: float, closure_mps: float, outcome: str
) -> None:
    report = ContactReport()
    assert report.crossing(miss_m, closure_mps, 0.3, RIM, HEAD, WINDOW) == outcome
    assert report.rim_strikes == (outcome == "rim_strike")
    assert report.whip_risk == (closure_mps > 2.6)


def test_a_miss_says_how_far_from_the_centre_and_outside_the_rim() -> None:
    report = ContactReport()
    report.crossing(0.373, 1.6, 0.3, RIM, HEAD, WINDOW)
    assert report.last_reason == (
        "missed the drogue: probe tip 0.373 m from the centre, 0.068 m outside the rim"
    )
