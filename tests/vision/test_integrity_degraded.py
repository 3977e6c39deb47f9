"""Integrity on degraded images we did not render ourselves (docs/integrity.md, "Degraded
images"): frames drawn and degraded with OpenCV only (``tests/support/degraded_frames.py``):
colour MJPG video from OpenCV's writer at its default quality, JPEG, blur, bloom and a sky.
Each lock must be correct and its true error inside its reported 99.9 % bound; compressed
frames must not be refused for noise the sensor model does not know."""

from __future__ import annotations

from dataclasses import replace

import pytest

from app.resources import load_default_calibration
from app.vision.local_centroid import LocalCentroidConfig
from app.vision.pipeline import NavigationPipeline, PipelineConfig
from app.vision.tracking import StereoTracker
from tests.support.degraded_frames import (
    SetSummary,
    calibration,
    degraded_pair,
    mjpg_clip,
    score,
)

# the defaults: the noise measured on each blob as well (LocalCentroidConfig.image_noise)
MEASURED = PipelineConfig()


@pytest.fixture(scope="module")
def calib():
    return calibration(load_default_calibration())


def test_colour_mjpg_video_locks_every_frame_inside_its_bound(calib) -> None:
    """A green-LED ring at 1.2 → 1 m through OpenCV's MJPG writer and reader: the chroma
    subsampling moves the green-excess centroids by ≈ 0.1 px, which the shot-noise model
    alone refused by the χ² test; the noise measured on each blob keeps those frames."""
    clip = mjpg_clip(calib, 12, start_mm=1200.0, end_mm=1000.0)
    tracker = StereoTracker(calib, MEASURED)
    scored = [
        score(tracker.update(left, right), leds, centre)
        for left, right, leds, centre in zip(
            clip.lefts, clip.rights, clip.led_xyz_mm, clip.centers_mm, strict=True
        )
    ]
    s = SetSummary.of(scored)
    assert s.locks == s.runs, [x.reason for x in scored if not x.lock]
    assert s.wrong == 0
    assert s.bound_held == s.bound_checked == s.locks


@pytest.mark.parametrize(
    "case", ["jpeg", "jpeg_colour", "gauss_blur", "motion_blur", "bloom", "sky_colour"]
)
def test_degraded_renders_lock_inside_their_bound(calib, case: str) -> None:
    scored = []
    for seed in range(3):
        p = degraded_pair(calib, case, seed)
        res = NavigationPipeline(calib, MEASURED).process(p.left, p.right)
        scored.append(score(res, p.led_xyz_mm, p.center_mm))
    s = SetSummary.of(scored)
    assert s.locks == s.runs, [x.reason for x in scored if not x.lock]
    assert s.wrong == 0
    assert s.bound_held == s.bound_checked == s.locks


def test_sensor_model_alone_refuses_the_compressed_colour_frames(calib) -> None:
    """The same clip with σ from the sensor model only: refused by the χ² test on some frames,
    which is what the image's own noise estimate fixes."""
    cfg = PipelineConfig(centroid=replace(LocalCentroidConfig(), image_noise=False))
    clip = mjpg_clip(calib, 12, start_mm=1200.0, end_mm=1000.0)
    tracker = StereoTracker(calib, cfg)
    results = [
        tracker.update(left, right) for left, right in zip(clip.lefts, clip.rights, strict=True)
    ]
    assert any("χ²" in (r.reason or "") for r in results if not r.lock)
