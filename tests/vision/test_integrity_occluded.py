"""Two LEDs occluded on the physically based optics set (issue 31 item 3): three visible LEDs
of the 305 mm drogue at 2.8–6 m are locked correctly with their true error inside the
reported bound; where a fourth point makes two 3-point rings fit within the noise (the 75 mm
ring at 2.25 m) the frame stays refused as ambiguous, never locked on a guess."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from app.sim.optics_eval import score
from app.sim.optics_set import OpticsCase, load_optics_set, sensor_pair
from app.vision.pipeline import NavigationPipeline, PipelineConfig

SETS = Path(__file__).resolve().parents[1] / "data" / "optics"


def _cases(name: str, *wanted: str) -> list[OpticsCase]:
    return [c for c in load_optics_set(SETS / name) if c.name in wanted]


def _config(case: OpticsCase, **changes) -> PipelineConfig:
    return replace(
        PipelineConfig(),
        ring_radius_mm=case.ring_radius_mm,
        led_count=case.led_count,
        led_diameter_mm=case.led_diameter_mm,
        **changes,
    )


def _run(calib, case: OpticsCase, seed: int, retry_min_area_px: int | None = 2, **changes):
    cfg = _config(case, retry_min_area_px=retry_min_area_px, **changes)
    left, right = sensor_pair(case, seed)
    return score(case, seed, NavigationPipeline(calib, cfg).process(left, right), ())


@pytest.mark.parametrize(
    ("name", "wanted"),
    [
        ("dev", ("dev_0603_occluded2", "dev_0604_occluded2", "dev_0605_occluded2")),
        ("holdout", ("holdout_0600_occluded2", "holdout_0601_occluded2")),
    ],
)
def test_three_visible_leds_of_the_flight_drogue_lock_inside_their_bound(calib, name, wanted):
    cases = _cases(name, *wanted)
    assert len(cases) == len(wanted)
    for case in cases:
        for seed in range(2):
            o = _run(calib, case, seed)
            assert o.lock, (case.name, seed, o.reason)
            assert len(o.led_errors_mm) == 3
            assert not o.wrong and not o.loose, (case.name, seed, o.worst_mm)
            assert o.within_bound, (case.name, seed, o.worst_mm, o.center_pl_mm)


def test_two_three_point_rings_within_the_noise_stay_ambiguous(calib):
    (case,) = _cases("dev", "dev_0602_occluded2")
    for seed in range(2):
        o = _run(calib, case, seed)
        assert not o.lock
        assert "ambiguous" in (o.reason or "")


def test_a_far_dim_led_lit_on_two_pixels_is_taken_in_the_second_pass(calib):
    """holdout 0602 (the flight drogue at 9.5 m in sunlight, LEDs 1–2 occluded): LED 3 lights
    only 2 px above eq. 10's threshold in the right image, under the gate's 3 px, and a glint
    on the occluding bar is matched instead. The second pass with 2 px blobs locks the three
    true LEDs inside their bound; so does the local-contrast pass alone (sunlight); without
    either the frame is refused."""
    (case,) = _cases("holdout", "holdout_0602_occluded2")
    for seed in range(2):
        o = _run(calib, case, seed)
        assert o.lock, (seed, o.reason)
        assert len(o.led_errors_mm) == 3
        assert not o.wrong and not o.loose, (seed, o.worst_mm)
        assert o.within_bound, (seed, o.worst_mm, o.center_pl_mm)
        local_only = _run(calib, case, seed, retry_min_area_px=None)
        assert local_only.lock and not local_only.wrong and local_only.within_bound, seed
        first_only = _run(calib, case, seed, None, retry_local_contrast_px=None)
        assert not first_only.lock
        assert "evenly spaced slots" in (first_only.reason or "")


@pytest.mark.parametrize(("name", "seed"), [("dev_0600_occluded2", 1), ("dev_0403_glint_mono", 1)])
def test_the_second_pass_leaves_a_locked_frame_alone(calib, name, seed):
    """A frame the first pass locks is never solved again: on these two, 2 px blobs taken on
    every frame (the gate's minimum lowered instead) add a rival ring and the frame turns
    ambiguous."""
    (case,) = _cases("dev", name)
    with_retry, first_only = _run(calib, case, seed), _run(calib, case, seed, None)
    assert with_retry.lock and first_only.lock
    assert with_retry.led_errors_mm == first_only.led_errors_mm
    gate = replace(PipelineConfig().gate, min_area_px=2)
    cfg = _config(case, gate=gate, retry_min_area_px=None, retry_local_contrast_px=None)
    left, right = sensor_pair(case, seed)
    always = NavigationPipeline(calib, cfg).process(left, right)
    assert not always.lock and "ambiguous" in (always.reason or "")
    # the local-contrast pass then solves the ambiguous frame again, and finds the true ring
    rescued = _run(calib, case, seed, None, gate=gate)
    assert rescued.lock and not rescued.wrong and rescued.within_bound
