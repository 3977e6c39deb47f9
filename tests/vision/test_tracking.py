"""StereoTracker: windowed tracking equals the full-frame pipeline, and falls back safely."""

from __future__ import annotations

import copy
from collections.abc import Iterator

import cv2
import numpy as np
import pytest

import app.vision.features as features_mod
import app.vision.pipeline as pipeline_mod
import app.vision.preprocess as preprocess_mod
import app.vision.tracking as tracking_mod
from app.model.pose import PoseResult
from app.resources import load_default_calibration
from app.sim.led_ring import stereo_center_x_mm, tilted_normal
from app.sim.stereo_render import RenderedPair, RenderSettings, render_pair
from app.vision.pipeline import NavigationPipeline
from app.vision.preprocess import ImageError
from app.vision.tracking import StereoTracker

TOL_MM = 0.05
FULL = (1024, 1280)


@pytest.fixture(scope="module")
def calib():  # type: ignore[no-untyped-def]
    return load_default_calibration()


def _pose(calib, depth: float, i: int) -> tuple[np.ndarray, np.ndarray, float]:  # type: ignore[no-untyped-def]
    """A moving (≈ 10 px/frame at 1 m), tilting and rolling (3.4°/frame) drogue."""
    x = stereo_center_x_mm(calib, depth)
    centre = np.array([x + 4.0 * i, -3.0 + 2.5 * i, depth + 8.0 * i])
    return centre, tilted_normal(8.0 + 0.5 * i, 30.0), 0.06 * i


def _frames(calib, depth: float, n: int, settings) -> Iterator[RenderedPair]:  # type: ignore[no-untyped-def]
    for i in range(n):
        centre, normal, roll = _pose(calib, depth, i)
        s = settings(i) if callable(settings) else settings
        yield render_pair(calib, centre, normal, s, seed=i, roll_rad=roll)


def _max_diff_mm(a: PoseResult, b: PoseResult) -> float:
    assert a.lock and b.lock and a.drogue is not None and b.drogue is not None
    assert [led.id for led in a.leds] == [led.id for led in b.leds]
    d = float(np.max(np.abs(np.subtract(a.drogue.center_mm, b.drogue.center_mm))))
    for la, lb in zip(a.leds, b.leds, strict=True):
        d = max(d, float(np.max(np.abs(np.subtract(la.xyz_mm, lb.xyz_mm)))))
        assert la.left_px == pytest.approx(lb.left_px, abs=1e-6)
        assert la.right_px == pytest.approx(lb.right_px, abs=1e-6)
        if lb.descriptor_distance >= 0:  # computed (``describe=True`` or an acquisition)
            assert la.descriptor_distance == pytest.approx(lb.descriptor_distance, abs=1e-9)
    return d


def _compare_sequence(
    calib, depth: float, n: int, settings, describe: bool = False
) -> tuple[list[str], float]:  # type: ignore[no-untyped-def]
    ref = NavigationPipeline(calib)
    tracker = StereoTracker(calib, describe=describe)
    modes: list[str] = []
    worst = 0.0
    for pair in _frames(calib, depth, n, settings):
        a = ref.process(pair.left, pair.right)
        b = tracker.update(pair.left, pair.right)
        modes.append(tracker.last_mode)
        assert a.lock == b.lock, (len(modes), a.reason, b.reason)
        if a.lock:
            worst = max(worst, _max_diff_mm(a, b))
    return modes, worst


@pytest.mark.parametrize("depth", [1000.0, 2500.0])
@pytest.mark.parametrize("glints", [0, 30])
def test_tracked_poses_equal_full_frame(calib, depth: float, glints: int) -> None:  # type: ignore[no-untyped-def]
    modes, worst = _compare_sequence(calib, depth, 8, RenderSettings(glints=glints))
    assert modes[0] == "acquired"
    assert modes[1:] == ["tracked"] * 7
    assert worst <= TOL_MM


def test_descriptors_on_tracked_frames_when_asked(calib) -> None:  # type: ignore[no-untyped-def]
    modes, worst = _compare_sequence(calib, 1000.0, 6, RenderSettings(glints=30), describe=True)
    assert modes == ["acquired"] + ["tracked"] * 5
    assert worst <= TOL_MM


def test_occlusion_gap_relocks_on_first_good_frame(calib) -> None:  # type: ignore[no-untyped-def]
    def settings(i: int) -> RenderSettings:
        if 3 <= i < 6:
            return RenderSettings(occluded=(1, 2, 3, 4, 5))
        if 8 <= i < 10:
            return RenderSettings(occluded=(2,))
        return RenderSettings()

    modes, worst = _compare_sequence(calib, 1000.0, 12, settings)
    assert modes[:3] == ["acquired", "tracked", "tracked"]
    assert modes[3:6] == ["lost"] * 3
    assert modes[6] == "acquired"  # the first good frame relocks
    assert modes[7] == "tracked"
    # LED 2 hidden: a tracked LED vanishes → acquisition, then tracking with four LEDs
    # (and a search window on LED 2's slot); it returns → tracked with five again
    assert modes[8] == "acquired" and modes[9] == "tracked"
    assert modes[10:] == ["tracked"] * 2
    assert worst <= TOL_MM


def test_bgr_sequence_equal(calib) -> None:  # type: ignore[no-untyped-def]
    modes, worst = _compare_sequence(calib, 1500.0, 5, RenderSettings(color=True))
    assert modes == ["acquired"] + ["tracked"] * 4
    assert worst <= TOL_MM


def test_tracked_frames_do_no_full_frame_work(calib, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    shapes: list[tuple[str, tuple[int, ...]]] = []

    def spy(name, fn):  # type: ignore[no-untyped-def]
        def wrapped(img, *args, **kwargs):  # type: ignore[no-untyped-def]
            shapes.append((name, tuple(img.shape[:2])))
            return fn(img, *args, **kwargs)

        return wrapped

    # graying: eq. 9 or the green excess of a colour frame (preprocess.detection_image)
    gray = preprocess_mod.to_gray
    monkeypatch.setattr(preprocess_mod, "to_gray", spy("to_gray", gray))
    detect = preprocess_mod.detection_image
    for mod in (pipeline_mod, tracking_mod):
        monkeypatch.setattr(mod, "detection_image", spy("to_gray", detect))
    for name in ("medianBlur", "threshold", "cvtColor", "split"):
        monkeypatch.setattr(cv2, name, spy(name, getattr(cv2, name)))
    # eq. 10, the median filter, the labelling (Algorithm 2) and eq. 11, compiled, and the
    # image they read: the acquisition's and the tracker's
    monkeypatch.setattr(features_mod, "detect_in_boxes", spy("label", features_mod.detect_in_boxes))
    monkeypatch.setattr(tracking_mod, "window_blobs", spy("label", tracking_mod.window_blobs))
    tracker = StereoTracker(calib)
    per_frame = []
    for pair in _frames(calib, 1000.0, 4, RenderSettings(color=True)):
        shapes.clear()
        assert tracker.update(pair.left, pair.right).lock
        per_frame.append((tracker.last_mode, list(shapes)))
    assert per_frame[0][0] == "acquired"
    assert any(s == FULL for _, s in per_frame[0][1])  # the spies see acquisition's work
    for mode, calls in per_frame[1:]:
        assert mode == "tracked"
        assert {n for n, _ in calls} >= {"to_gray", "label"}
        assert all(s != FULL for _, s in calls), calls
        assert all(s[0] * s[1] < FULL[0] * FULL[1] / 5 for _, s in calls), calls


def _stamp(img: np.ndarray, src: tuple[float, float], dst: tuple[float, float], r: int) -> None:
    """Copy the (2r+1)² patch around ``src`` to ``dst`` (a second, identical LED)."""
    su, sv = (int(round(c)) for c in src)
    du, dv = (int(round(c)) for c in dst)
    img[dv - r : dv + r + 1, du - r : du + r + 1] = img[sv - r : sv + r + 1, su - r : su + r + 1]


def test_fake_led_in_a_window_falls_back(calib) -> None:  # type: ignore[no-untyped-def]
    frames = list(_frames(calib, 1000.0, 4, RenderSettings()))
    tracker = StereoTracker(calib)
    ref = NavigationPipeline(calib)
    for pair in frames[:3]:
        ref.process(pair.left, pair.right)
        tracker.update(pair.left, pair.right)
    assert tracker.last_mode == "tracked"
    pair = frames[3]
    same_history = copy.deepcopy(ref)
    truth = ref.process(pair.left, pair.right)
    led = truth.leds[0]
    left, right = pair.left.copy(), pair.right.copy()
    # an LED-like blob 18 px beside LED 1 in both images: inside its tracking windows
    _stamp(left, led.left_px, (led.left_px[0] + 18, led.left_px[1]), 8)
    _stamp(right, led.right_px, (led.right_px[0] + 18, led.right_px[1]), 8)
    res = tracker.update(left, right)
    assert tracker.last_mode in ("acquired", "lost")
    assert tracker.last_fallback is not None and "blobs in the" in tracker.last_fallback
    full = same_history.process(left, right)  # the full frame decides, with the same track
    assert res.lock == full.lock
    if full.lock:
        assert _max_diff_mm(full, res) <= TOL_MM


def test_dimmed_led_fails_the_appearance_test_and_falls_back(calib) -> None:  # type: ignore[no-untyped-def]
    """One LED dimmed to 40 % in the left image only (a partly occluded LED, or a reflection
    standing in for it): the tracked frame's stereo appearance check sends it to acquisition,
    naming the LED, and the result is the full frame's with the same history."""
    frames = list(_frames(calib, 1000.0, 4, RenderSettings()))
    tracker = StereoTracker(calib)
    ref = NavigationPipeline(calib)
    for pair in frames[:3]:
        ref.process(pair.left, pair.right)
        tracker.update(pair.left, pair.right)
    assert tracker.last_mode == "tracked"
    pair = frames[3]
    same_history = copy.deepcopy(ref)
    led = ref.process(pair.left, pair.right).leds[1]
    left = pair.left.copy()
    u, v = (int(round(c)) for c in led.left_px)
    patch = left[v - 12 : v + 13, u - 12 : u + 13].astype(np.float64)
    bg = float(np.median(left))
    left[v - 12 : v + 13, u - 12 : u + 13] = np.clip(bg + 0.4 * (patch - bg), 0, 255).astype(
        np.uint8
    )
    res = tracker.update(left, pair.right)
    assert tracker.last_mode in ("acquired", "lost")
    assert tracker.last_fallback is not None
    assert tracker.last_fallback.startswith(f"LED {led.id} fails the appearance test")
    full = same_history.process(left, pair.right)
    assert res.lock == full.lock
    if full.lock:
        assert _max_diff_mm(full, res) <= TOL_MM


def test_jump_of_200_px_falls_back_and_relocks(calib) -> None:  # type: ignore[no-untyped-def]
    tracker = StereoTracker(calib)
    ref = NavigationPipeline(calib)
    dx = 200.0 * 1000.0 / calib.left.fx  # 200 px at 1 m
    for i in range(6):
        centre, normal, roll = _pose(calib, 1000.0, i)
        if i >= 3:
            centre = centre + np.array([dx, 0.0, 0.0])
        pair = render_pair(calib, centre, normal, RenderSettings(), seed=i, roll_rad=roll)
        a = ref.process(pair.left, pair.right)
        b = tracker.update(pair.left, pair.right)
        assert b.lock
        assert _max_diff_mm(a, b) <= TOL_MM
        if i == 3:
            assert tracker.last_mode == "acquired" and tracker.last_fallback is not None
            assert b.reason is not None and b.reason.startswith("acquired")
        elif i > 3:
            assert tracker.last_mode == "tracked" and b.reason == "tracked"
    assert tracker.stats.fallbacks == 1


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((1024, 1280), np.float32),
        np.zeros((10, 10), np.uint8),
        np.zeros((512, 640), np.uint8),
        "not an image",
        np.zeros((1024, 1280, 2), np.uint8),
    ],
)
def test_bad_input_raises_the_pipelines_image_error(calib, bad) -> None:  # type: ignore[no-untyped-def]
    good = np.zeros(FULL, np.uint8)
    with pytest.raises(ImageError) as expected:
        NavigationPipeline(calib).process(bad, good)
    with pytest.raises(ImageError) as got:
        StereoTracker(calib).update(bad, good)
    assert str(got.value) == str(expected.value)


def test_bad_input_while_tracking_keeps_the_lock(calib) -> None:  # type: ignore[no-untyped-def]
    frames = list(_frames(calib, 1000.0, 3, RenderSettings()))
    tracker = StereoTracker(calib)
    tracker.update(frames[0].left, frames[0].right)
    with pytest.raises(ImageError):
        tracker.update(frames[1].left, np.zeros((4, 4), np.uint8))
    assert tracker.locked
    tracker.update(frames[1].left, frames[1].right)
    assert tracker.last_mode == "tracked"


def test_reset_forgets_the_lock(calib) -> None:  # type: ignore[no-untyped-def]
    pair = next(_frames(calib, 1000.0, 1, RenderSettings()))
    tracker = StereoTracker(calib)
    tracker.update(pair.left, pair.right)
    assert tracker.locked
    tracker.reset()
    assert not tracker.locked
    tracker.update(pair.left, pair.right)
    assert tracker.last_mode == "acquired"


def _only_windows(image: np.ndarray, rects: list[tuple[int, int, int, int]]) -> np.ndarray:
    out = np.zeros_like(image)
    for x0, y0, x1, y1 in rects:
        out[y0:y1, x0:x1] = image[y0:y1, x0:x1]
    return out


def test_next_windows_are_all_a_tracked_frame_reads(calib) -> None:  # type: ignore[no-untyped-def]
    """Images blank outside ``next_windows`` give the full images' result; an acquisition
    (no windows, or a fallback) asks ``full_frame`` for the whole pair."""

    def settings(i: int) -> RenderSettings:
        # frame 5: LED 2 hidden → a tracked LED vanishes → fallback to the full frame
        return RenderSettings(occluded=(2,)) if i == 5 else RenderSettings(glints=10)

    # exact_peak=False: the threshold's peak from the windows only (the rest is unknown)
    ref = StereoTracker(calib, exact_peak=False)
    tracker = StereoTracker(calib, exact_peak=False)
    asked: list[int] = []
    windowed = 0
    for i, pair in enumerate(_frames(calib, 1000.0, 9, settings)):
        a = ref.update(pair.left, pair.right)
        rects = tracker.next_windows()
        if rects is None:
            left, right = pair.left, pair.right
        else:
            windowed += 1
            left, right = _only_windows(pair.left, rects[0]), _only_windows(pair.right, rects[1])
            # each window is a square of one common side inside the image
            sides = {(x1 - x0, y1 - y0) for x0, y0, x1, y1 in rects[0] + rects[1]}
            assert len(sides) == 1 and next(iter(sides))[0] == next(iter(sides))[1]

        def full(i: int = i, p: RenderedPair = pair) -> tuple[np.ndarray, np.ndarray]:
            asked.append(i)
            return p.left, p.right

        b = tracker.update(left, right, full_frame=full)
        assert tracker.last_mode == ref.last_mode, (i, tracker.last_fallback)
        assert a.lock == b.lock
        if a.lock:
            assert _max_diff_mm(a, b) <= 1e-9
    assert windowed == 8  # every frame after the first lock is windowed
    assert asked == [5]  # the occluded frame: fallback → the full pair


def test_prior_gates_grow_with_the_depth_noise(calib) -> None:  # type: ignore[no-untyped-def]
    """At docking range the gates are the defaults; far out they follow 6σ_Z."""
    from app.geometry.ring import RingPrior

    params = NavigationPipeline(calib).ring_params
    near = RingPrior.at_range(np.array([0.0, 0.0, 1000.0]), np.array([0.0, 0.0, -1.0]), params)
    assert (near.gate_mm, near.gate_deg) == (30.0, 15.0)
    far = RingPrior.at_range(np.array([0.0, 0.0, 12000.0]), np.array([0.0, 0.0, -1.0]), params)
    assert far.gate_mm == pytest.approx(6.0 * float(params.sigma_z(12000.0)))
    assert far.gate_mm > 30.0 and far.gate_deg > 15.0


def test_flight_scale_ring_far_out_stays_tracked(calib) -> None:  # type: ignore[no-untyped-def]
    """A 305 mm ring at 9–10 m (the approach of a docking run): the frame-to-frame depth noise
    of its centre is tens of mm, which a fixed 30 mm "moved away from the last lock" gate took
    for a jump (re-acquiring on ≈ 1 frame in 3). Every frame after the first is tracked, and
    equals the full-frame pipeline's pose."""
    from app.sim.led_ring import LedRing
    from app.vision.pipeline import PipelineConfig

    ring = LedRing(radius_mm=305.0, led_diameter_mm=20.0)
    cfg = PipelineConfig(ring_radius_mm=305.0, led_diameter_mm=20.0)
    ref, tracker = NavigationPipeline(calib, cfg), StereoTracker(calib, cfg)
    x = stereo_center_x_mm(calib, 9500.0)
    modes, worst = [], 0.0
    for i in range(16):
        centre = np.array([x + 5.0 * i, 20.0 - 3.0 * i, 9800.0 - 25.0 * i])
        pair = render_pair(
            calib, centre, tilted_normal(5.0, 30.0), RenderSettings(), ring=ring, seed=i
        )
        a = ref.process(pair.left, pair.right)
        b = tracker.update(pair.left, pair.right)
        modes.append(tracker.last_mode)
        assert a.lock and b.lock, (i, a.reason, b.reason)
        worst = max(worst, _max_diff_mm(a, b))
    assert modes == ["acquired"] + ["tracked"] * 15, tracker.last_fallback
    assert worst <= TOL_MM


def test_saturated_windows_skip_the_full_frame_read(calib) -> None:  # type: ignore[no-untyped-def]
    """Eq. 10's peak on a tracked frame: the whole frame is read only when no window pixel
    is saturated (a saturated window already holds the frame's largest value, 255); either
    way the threshold is the rule's on the frame's true peak."""

    class Frame:
        def __init__(self, peak: int) -> None:
            self.peak, self.reads = peak, 0

        def max(self) -> int:
            self.reads += 1
            return self.peak

    tracker = StereoTracker(calib)
    bg = (12.0, 2.0)
    unsaturated = np.full((20, 20), 12, np.uint8)
    unsaturated[8:12, 8:12] = 230
    glint = Frame(250)  # a glint brighter than the LEDs elsewhere in the frame
    thr = tracker._threshold(unsaturated, glint, bg, 0)  # type: ignore[arg-type]
    assert glint.reads == 1 and thr == round(12 + 0.25 * (250 - 12))
    saturated = unsaturated.copy()
    saturated[9, 9] = 255
    frame = Frame(255)
    thr = tracker._threshold(saturated, frame, bg, 0)  # type: ignore[arg-type]
    assert frame.reads == 0 and thr == round(12 + 0.25 * (255 - 12))


def test_saturated_led_sequence_equal(calib) -> None:  # type: ignore[no-untyped-def]
    """Saturated LEDs (flat tops at 255) and LED-like glints: tracked frames, which then read
    no whole frame for the peak, equal the full-frame pipeline."""
    settings = RenderSettings(led_peak=400.0, glints=10)
    pair = next(iter(_frames(calib, 1000.0, 1, settings)))
    assert int(pair.left.max()) == 255  # the LEDs saturate (the test can fail)
    modes, worst = _compare_sequence(calib, 1000.0, 6, settings)
    assert modes == ["acquired"] + ["tracked"] * 5
    assert worst <= TOL_MM
