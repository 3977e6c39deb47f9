"""Unit tests of each pipeline stage and property tests on arbitrary images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from app.geometry.calibration import StereoCalibration
from app.geometry.projection import project_stereo, undistort_pixels
from app.model.pose import PoseResult
from app.vision.features import BlobGate, extract_blobs
from app.vision.ihwt import DESCRIPTOR_SIZE, box_sum, describe_point, integral_image
from app.vision.matching import (
    descriptor_distances,
    epipolar_distances,
    match_epipolar,
    match_min_distance,
)
from app.vision.pipeline import NavigationPipeline
from app.vision.preprocess import (
    ImageError,
    binarize,
    choose_threshold,
    median_filter,
    to_gray,
    validate_image,
)


def gaussian_blob(shape, centre, sigma=1.5, peak=200.0, bg=10.0):
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]]
    g = bg + peak * np.exp(-((u - centre[0]) ** 2 + (v - centre[1]) ** 2) / (2 * sigma**2))
    return np.clip(np.rint(g), 0, 255).astype(np.uint8)


def test_gray_uses_eq9_weights():
    bgr = np.zeros((20, 20, 3), np.uint8)
    bgr[..., 0], bgr[..., 1], bgr[..., 2] = 50, 200, 100  # B, G, R
    assert int(to_gray(bgr)[0, 0]) == round(0.299 * 100 + 0.587 * 200 + 0.114 * 50)
    gray = np.arange(400, dtype=np.uint8).reshape(20, 20)
    assert to_gray(gray) is gray


def test_threshold_modes_and_binarisation():
    img = gaussian_blob((40, 40), (20, 20), peak=200)
    assert choose_threshold(img, 77) == 77
    auto = choose_threshold(img, "auto")
    assert 10 < auto < 210
    otsu = choose_threshold(img, "otsu")
    assert 10 < otsu < 210
    b = binarize(img, auto)
    assert set(np.unique(b)) == {0, 255}
    assert np.array_equal(b == 255, img >= auto)  # eq. 10 uses ≥
    for bad in (0, 256, "median", 1.5, True):
        with pytest.raises(ValueError):
            choose_threshold(img, bad)


def test_median_filter_removes_isolated_pixels_keeps_blobs():
    mask = np.zeros((30, 30), np.uint8)
    mask[5, 5] = 255
    mask[15:21, 15:21] = 255
    out = median_filter(mask, 3)
    assert out[5, 5] == 0 and out[17, 17] == 255


@pytest.mark.parametrize("centre", [(20.0, 20.0), (20.37, 19.81), (25.5, 14.25)])
def test_centroid_is_subpixel_accurate(centre):
    img = gaussian_blob((40, 48), centre)
    mask = median_filter(binarize(img, choose_threshold(img)), 3)
    blobs, rejected = extract_blobs(img, mask, background=10.0)
    assert len(blobs) == 1 and not rejected
    assert np.hypot(blobs[0].centroid_px[0] - centre[0], blobs[0].centroid_px[1] - centre[1]) < 0.02


def test_gating_rejects_elongated_border_and_tiny_blobs():
    img = np.full((60, 80), 10, np.uint8)
    img[10:13, 10:40] = 220  # a streak
    img[40:48, 0:6] = 220  # touches the left border
    img[30:38, 50:58] = 220  # a good blob
    mask = binarize(img, 100)
    blobs, rejected = extract_blobs(img, mask, 10.0, BlobGate(min_area_px=3))
    assert len(blobs) == 1
    reasons = " ".join(r.reason for r in rejected)
    assert "elongated" in reasons and "border" in reasons


def test_integral_image_box_sums_match_numpy():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (37, 53), dtype=np.uint8)
    ii = integral_image(img)
    for x0, y0, x1, y1 in [(0, 0, 53, 37), (3, 4, 10, 20), (10, 10, 11, 11)]:
        ref = img[y0:y1, x0:x1].astype(np.int64).sum()
        assert box_sum(ii, np.array(x0), np.array(y0), np.array(x1), np.array(y1)) == ref


def test_ihwt_descriptor_properties():
    img = gaussian_blob((80, 80), (30.3, 40.6), sigma=2.0)
    ii = integral_image(img)
    d = describe_point(ii, (30.3, 40.6), 24.0)
    assert d.shape == (DESCRIPTOR_SIZE,)
    assert np.linalg.norm(d) == pytest.approx(1.0)
    # brighter copy → same normalised descriptor; translated copy → same descriptor
    dim = gaussian_blob((80, 80), (30.3, 40.6), sigma=2.0, peak=100.0, bg=30.0)
    d_dim = describe_point(integral_image(dim), (30.3, 40.6), 24.0)
    assert np.linalg.norm(d - d_dim) < 0.02  # Haar responses: offset-free, gain-normalised
    shifted = np.roll(img, (5, 7), axis=(0, 1))
    d_shift = describe_point(integral_image(shifted), (37.3, 45.6), 24.0)
    assert np.linalg.norm(d - d_shift) < 1e-9
    # a different pattern (blob with a neighbour) → clearly different descriptor
    other = np.maximum(img, gaussian_blob((80, 80), (38.0, 40.6), sigma=2.0))
    d_other = describe_point(integral_image(other), (30.3, 40.6), 24.0)
    assert np.linalg.norm(d - d_other) > 0.2
    flat = describe_point(integral_image(np.full((50, 50), 7, np.uint8)), (25, 25), 20.0)
    assert np.all(flat == 0)


def test_epipolar_distance_is_zero_for_true_correspondences(calib):
    rng = np.random.default_rng(1)
    X = rng.uniform([-150, -150, 600], [150, 150, 3000], (20, 3))
    left, right = project_stereo(calib, X)
    xl, xr = undistort_pixels(calib.left, left), undistort_pixels(calib.right, right)
    epi = epipolar_distances(calib.fundamental, xl, xr)
    assert np.abs(np.diag(epi)).max() < 1e-6
    off = epi[~np.eye(20, dtype=bool)]
    assert np.median(off) > 5.0


def test_epipolar_matcher_never_matches_outside_the_gate():
    desc = np.eye(3)
    ddist = descriptor_distances(desc, desc)  # perfect descriptor matches on the diagonal
    epi = np.full((3, 3), 0.5)
    epi[0, 0] = 5.0  # but pair (0, 0) violates the epipolar gate
    depth = np.full((3, 3), 1000.0)
    matches = match_epipolar(ddist, epi, depth, tol_px=2.0)
    assert all(m.epipolar_px <= 2.0 for m in matches)
    assert (0, 0) not in {(m.left_index, m.right_index) for m in matches}
    paper = match_min_distance(ddist, epi)  # the paper's matcher has no such gate
    assert (0, 0) in {(m.left_index, m.right_index) for m in paper}


def test_epipolar_matcher_is_one_to_one_and_uses_depth_coherence():
    # Two left points on the same epipolar line as two right points, identical descriptors:
    # only depth coherence (most pairs at ~1 m) tells the right pairing.
    ddist = np.zeros((3, 3))
    epi = np.zeros((3, 3))
    depth = np.array([[1000.0, 1400.0, 5000.0], [700.0, 1000.0, 5000.0], [5000.0, 5000.0, 1010.0]])
    matches = match_epipolar(ddist, epi, depth)
    pairs = {(m.left_index, m.right_index) for m in matches}
    assert pairs == {(0, 0), (1, 1), (2, 2)}
    assert len({m.right_index for m in matches}) == len(matches)


def _small_calibration() -> StereoCalibration:
    K = [[120.0, 0.0, 40.0], [0.0, 120.0, 30.0], [0.0, 0.0, 1.0]]
    return StereoCalibration.from_dict(
        {
            "image_size": [80, 60],
            "left": {"K": K, "dist": [0.01, 0, 0, 0, 0]},
            "right": {"K": K, "dist": [0, 0, 0, 0, 0]},
            "R": np.eye(3).tolist(),
            "T": [-100.0, 0.0, 0.0],
        }
    )


SMALL = _small_calibration()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    left=arrays(
        np.uint8, st.sampled_from([(60, 80), (60, 80, 3), (61, 80), (10, 10), (60, 80, 2)])
    ),
    right=arrays(np.uint8, st.sampled_from([(60, 80), (60, 80, 3), (60, 81)])),
)
def test_random_images_raise_only_documented_errors(left, right):
    pipe = NavigationPipeline(SMALL)
    try:
        result = pipe.process(left, right)
    except ImageError as exc:
        assert str(exc)
        return
    assert isinstance(result, PoseResult)
    if not result.lock:
        assert result.reason
    else:
        assert result.drogue is not None and len(result.leds) >= 3


@settings(max_examples=30, deadline=None)
@given(noise=arrays(np.uint8, (1024, 1280), elements=st.integers(0, 255), fill=st.integers(0, 255)))
def test_random_full_size_frames_never_crash(calib, noise):
    res = NavigationPipeline(calib).process(noise, noise[::-1].copy())
    assert isinstance(res, PoseResult)


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((1024, 1280), np.float32),
        np.zeros((1024, 1280, 5), np.uint8),
        "image",
        np.zeros((8, 8), np.uint8),
    ],
)
def test_invalid_inputs_raise_image_error(calib, bad):
    with pytest.raises(ImageError):
        validate_image(bad)
    good = np.zeros((1024, 1280), np.uint8)
    with pytest.raises(ImageError):
        NavigationPipeline(calib).process(bad, good)


def test_wrong_size_for_calibration_is_reported(calib):
    img = np.zeros((480, 640), np.uint8)
    with pytest.raises(ImageError, match="calibration is for 1280×1024"):
        NavigationPipeline(calib).process(img, img)


def test_saturated_and_striped_frames(calib):
    w, h = calib.image_size
    white = np.full((h, w), 255, np.uint8)
    assert not NavigationPipeline(calib).process(white, white).lock
    stripes = np.zeros((h, w), np.uint8)
    stripes[:, ::7] = 255
    assert not NavigationPipeline(calib).process(stripes, stripes).lock
    cv2.circle(stripes, (100, 100), 5, 255, -1)


def test_background_level_matches_numpy_median_and_mad():
    rng = np.random.default_rng(3)
    img = np.clip(rng.normal(40, 5, (200, 240)), 0, 255).astype(np.uint8)
    from app.vision.preprocess import background_level

    med, sigma = background_level(img)
    sub = img[::8, ::4].astype(float)
    assert med == pytest.approx(np.median(sub), abs=0.5)
    assert sigma == pytest.approx(1.4826 * np.median(np.abs(sub - np.median(sub))), abs=1.5)
    assert 3.5 < sigma < 6.5


@pytest.mark.parametrize("case", ["noise", "flat", "zero", "sunlit", "odd", "narrow"])
def test_frame_summary_statistics_equal_the_separate_passes(case: str) -> None:
    """The one-pass summary's histograms equal the separate passes' count for count, and
    its compiled levels equal background_from_histogram's median and noise_sigma."""
    from app.vision.preprocess import (
        BACKGROUND_COL_STEP,
        BACKGROUND_ROW_STEP,
        background_from_histogram,
        noise_from_histogram,
        noise_sigma,
    )
    from app.vision.preprocess_kernels import (
        difference_histogram,
        frame_levels,
        frame_summary,
        subsampled_histogram,
    )

    rng = np.random.default_rng(11)
    shape = {"odd": (37, 61), "narrow": (300, 17)}.get(case, (240, 320))
    if case == "flat":
        img = np.full(shape, 40, np.uint8)
    elif case == "zero":
        img = np.zeros(shape, np.uint8)
    elif case == "sunlit":  # a gradient plus noise and a saturated patch
        ramp = np.linspace(20, 220, shape[1])[None, :] + rng.normal(0, 3, shape)
        img = np.clip(ramp, 0, 255).astype(np.uint8)
        img[50:60, 70:90] = 255
    else:
        img = np.clip(rng.normal(60, 7, shape), 0, 255).astype(np.uint8)
    rs, cs = BACKGROUND_ROW_STEP, BACKGROUND_COL_STEP
    _, hist, dhist = frame_summary(img, 16, rs, cs)
    assert np.array_equal(hist, subsampled_histogram(img, rs, cs))
    assert np.array_equal(dhist, difference_histogram(img, rs, cs))
    bg, sigma = frame_levels(hist, dhist)
    assert bg == background_from_histogram(hist)[0]
    assert sigma == noise_from_histogram(dhist) == noise_sigma(img)
    _, h0, d0 = frame_summary(img, 16, 0, cs)  # no histograms
    assert not h0.any() and not d0.any()
    assert frame_levels(h0, d0) == (0.0, 0.5) == (background_from_histogram(h0)[0], 0.5)


def test_descriptor_on_crop_equals_full_frame(calib):
    from app.sim.stereo_render import render_pair
    from app.vision.ihwt import describe

    pair = render_pair(calib, np.array([0.0, 0.0, 800.0]), np.array([0.0, 0.0, -1.0]), seed=2)
    img = pair.left
    mask = median_filter(binarize(img, choose_threshold(img)), 3)
    blobs, _ = extract_blobs(img, mask, 12.0)
    assert len(blobs) == 5
    assert np.allclose(describe(img, blobs), describe(img, blobs, ii=integral_image(img)))


def test_epipolar_distances_equal_opencv_epilines(calib):
    """The compiled symmetric epipolar distance equals one built on
    ``cv2.computeCorrespondEpilines`` (lines normalised to a² + b² = 1)."""
    rng = np.random.default_rng(2)
    xl = rng.uniform([0, 0], [1280, 1024], (7, 2))
    xr = rng.uniform([0, 0], [1280, 1024], (9, 2))
    F = calib.fundamental
    lines_r = cv2.computeCorrespondEpilines(xl.reshape(-1, 1, 2), 1, F).reshape(-1, 3)
    lines_l = cv2.computeCorrespondEpilines(xr.reshape(-1, 1, 2), 2, F).reshape(-1, 3)
    d_right = np.abs(lines_r[:, :2] @ xr.T + lines_r[:, 2:3])  # (7, 9): x_r to F x_l
    d_left = np.abs(lines_l[:, :2] @ xl.T + lines_l[:, 2:3]).T  # (7, 9): x_l to Fᵀ x_r
    ref = 0.5 * (d_right + d_left)
    got = epipolar_distances(F, xl, xr)
    assert got.shape == (7, 9) and np.median(ref) > 1.0
    assert np.allclose(got, ref, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("pair", ["pair_1000mm", "pair_1000mm_clutter"])
def test_rejected_candidates_are_the_renderers_clutter_lights(pair: str) -> None:
    """The result names the candidates it did not use: on the clutter pair, exactly the
    rendered distractor lights in view (renderer truth, within 0.2 px); none on a clean pair."""
    import json
    from pathlib import Path

    from app.resources import load_default_calibration

    d = Path(__file__).resolve().parents[2] / "sample_data" / pair
    truth = json.loads((d / "truth.json").read_text())
    left = cv2.imread(str(d / "left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(d / "right.png"), cv2.IMREAD_UNCHANGED)
    res = NavigationPipeline(load_default_calibration()).process(left, right)
    assert res.lock
    for side in ("left", "right"):
        rejected = np.array(getattr(res, f"rejected_{side}_px")).reshape(-1, 2)
        clutter = np.array(
            [p for p in truth.get(f"clutter_{side}_px", []) if p[0] is not None], float
        ).reshape(-1, 2)
        assert len(rejected) == len(clutter)
        for u, v in rejected:
            assert np.min(np.linalg.norm(clutter - (u, v), axis=1)) < 0.2
        leds = np.array([led.left_px if side == "left" else led.right_px for led in res.leds])
        for u, v in rejected:  # never an LED of the lock
            assert np.min(np.linalg.norm(leds - (u, v), axis=1)) > 3.0
