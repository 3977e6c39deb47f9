"""Degraded stereo frames built independently of the project's renderer and image code.

The LED ring is drawn by :mod:`tests.support.cv_render` (OpenCV only); each degradation is
done with OpenCV and numpy alone, as a user's camera or tool chain would do it:

* ``jpeg``: ``cv2.imencode(".jpg")`` at OpenCV's default quality, decoded by ``cv2.imdecode``;
* ``gauss_blur``: a Gaussian optical blur (``cv2.GaussianBlur``) before the sensor noise;
* ``motion_blur``: a line kernel (``cv2.filter2D``) before the sensor noise;
* ``bloom``: bright LEDs (at the 8-bit ceiling) with a wide halo (two ``cv2.GaussianBlur`` of
  the LED image added back), clipped;
* ``sky``: a vertical sky gradient 40 → 170 DN behind the LEDs;
* ``all``: bloom, motion blur, sky and JPEG together;
* :func:`mjpg_clip`: a moving ring written by ``cv2.VideoWriter`` (MJPG ``.avi``, the writer's
  default quality, as a user records it) and read back by ``cv2.VideoCapture``.

Truth: the LED centres (mm, left camera frame) and the ring's centre. Poses: the ring faces
the cameras (tilt ≤ 20°), centred between them, at a random roll.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import StereoCalibration
from app.model.pose import PoseResult
from tests.support.cv_render import render_pair_cv, skew_free

RING_RADIUS_MM = 75.0
LED_COUNT = 5
LED_DIAMETER_MM = 5.0
NOISE_DN = 2.0  # sensor noise (1σ) added after the optics
FPS = 30.0

Image = NDArray[np.uint8]


@dataclass(frozen=True)
class DegradedPair:
    """One degraded stereo pair and its truth (mm, left camera frame)."""

    case: str
    left: Image
    right: Image
    led_xyz_mm: NDArray[np.float64]  # (5, 3)
    center_mm: NDArray[np.float64]  # (3,)


def calibration(calib: StereoCalibration) -> StereoCalibration:
    """The calibration the frames are rendered with (and must be solved with): skew-free,
    as ``cv2.projectPoints`` renders."""
    return skew_free(calib)


def ring_leds(
    calib: StereoCalibration, range_mm: float, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(LED centres (5, 3), ring centre (3,)) mm: the ring centred between the cameras at
    ``range_mm``, tilted ≤ 20° towards a random azimuth, at a random roll."""
    right_centre = -np.asarray(calib.R).T @ np.asarray(calib.T, dtype=np.float64).reshape(3)
    centre = 0.5 * right_centre + np.array([0.0, 0.0, range_mm])
    tilt, az = math.radians(rng.uniform(0.0, 20.0)), rng.uniform(0.0, 2 * math.pi)
    normal = np.array(
        [math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), -math.cos(tilt)]
    )
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    theta = rng.uniform(0, 2 * math.pi) + 2 * math.pi * np.arange(LED_COUNT) / LED_COUNT
    leds = centre + RING_RADIUS_MM * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2)
    return leds, centre


def _render(
    calib: StereoCalibration, leds: NDArray[np.float64], peak: float, background: float
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Noise-free float images (DN) of the LEDs, before any degradation."""
    left, right, _, _ = render_pair_cv(
        calib,
        leds,
        led_diameter_mm=LED_DIAMETER_MM,
        peak=peak,
        background=background,
        noise_sigma=0.0,
        blur_sigma_px=0.7,
    )
    return left.astype(np.float32), right.astype(np.float32)


LED_BGR = np.array([0.3, 1.0, 0.4], np.float32)  # a green LED's colour (B, G, R)
SKY_TOP_BGR = np.array([190.0, 160.0, 120.0], np.float32)  # a blue sky, top row (DN)
SKY_BOTTOM_BGR = np.array([120.0, 110.0, 95.0], np.float32)  # … and bottom row


def _sensor(img: NDArray[np.float32], rng: np.random.Generator) -> Image:
    noisy = img + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(NOISE_DN)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def jpeg(img: Image) -> Image:
    """A JPEG round trip at OpenCV's default quality (grey or BGR as given)."""
    ok, buf = cv2.imencode(".jpg", img)
    assert ok
    flag = cv2.IMREAD_GRAYSCALE if img.ndim == 2 else cv2.IMREAD_COLOR
    return np.asarray(cv2.imdecode(buf, flag), dtype=np.uint8)


def motion_kernel(length_px: int = 9, angle_deg: float = 30.0) -> NDArray[np.float32]:
    """A normalised line kernel of ``length_px`` at ``angle_deg`` (image x towards y)."""
    k = np.zeros((length_px, length_px), np.float32)
    c = (length_px - 1) / 2
    dx, dy = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    p0 = (round((c - c * dx) * 16), round((c - c * dy) * 16))
    p1 = (round((c + c * dx) * 16), round((c + c * dy) * 16))
    cv2.line(k, p0, p1, 1.0, 1, cv2.LINE_AA, 4)
    return k / k.sum()


def _bloom(led: NDArray[np.float32]) -> NDArray[np.float32]:
    """The LED image with its halo (background-free, DN)."""
    halo = 0.35 * cv2.GaussianBlur(led, (0, 0), 3.0) + 0.15 * cv2.GaussianBlur(led, (0, 0), 9.0)
    return led + np.float32(2.5) * halo.astype(np.float32)


def _sky(shape: tuple[int, int], colour: bool) -> NDArray[np.float32]:
    t = np.linspace(0.0, 1.0, shape[0], dtype=np.float32)[:, None]
    if not colour:
        return np.broadcast_to(40.0 + 130.0 * t, shape).astype(np.float32)
    rows = SKY_TOP_BGR + (SKY_BOTTOM_BGR - SKY_TOP_BGR) * t  # (H, 3)
    return np.broadcast_to(rows[:, None, :], (*shape, 3)).astype(np.float32)


@dataclass(frozen=True)
class CaseSpec:
    """How a case is made: the LED's peak over the background (DN), the background (DN; the
    sky replaces it), colour, and the optical steps on the background-free LED image."""

    peak: float = 235.0
    background: float = 12.0
    colour: bool = False
    gauss_px: float = 0.0
    motion: bool = False
    bloom: bool = False
    sky: bool = False
    jpeg: bool = False


SPECS: dict[str, CaseSpec] = {
    "jpeg": CaseSpec(jpeg=True),
    "jpeg_colour": CaseSpec(colour=True, jpeg=True),
    "gauss_blur": CaseSpec(gauss_px=1.6),
    "motion_blur": CaseSpec(motion=True),
    "bloom": CaseSpec(peak=255.0, bloom=True),
    "sky_colour": CaseSpec(peak=200.0, colour=True, sky=True),
    "all_colour": CaseSpec(peak=200.0, colour=True, motion=True, bloom=True, sky=True, jpeg=True),
}
CASES: tuple[str, ...] = tuple(SPECS)


def compose(led: NDArray[np.float32], spec: CaseSpec, rng: np.random.Generator) -> Image:
    """Camera output from a background-free LED image (DN at its peak): optics, scene,
    sensor noise, then the encoder."""
    if spec.gauss_px > 0:
        led = cv2.GaussianBlur(led, (0, 0), spec.gauss_px)
    if spec.bloom:
        led = _bloom(led)
    if spec.motion:
        led = cv2.filter2D(led, -1, motion_kernel())
    img = led[:, :, None] * LED_BGR if spec.colour else led
    if spec.sky:
        img = img + _sky(led.shape, spec.colour)
    else:
        img = img + np.float32(spec.background)
    out = _sensor(img.astype(np.float32), rng)
    return jpeg(out) if spec.jpeg else out


def _led_images(
    calib: StereoCalibration, leds: NDArray[np.float64], peak: float
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Background-free, noise-free LED images (DN), before any degradation."""
    left, right = _render(calib, leds, peak, 0.0)
    return left, right


def degraded_pair(
    calib: StereoCalibration, case: str, seed: int, range_mm: float = 1000.0
) -> DegradedPair:
    """One pair of ``case`` (:data:`CASES`) at a random pose drawn from ``seed``; ``calib``
    as :func:`calibration` gives it."""
    if case not in SPECS:
        raise ValueError(f"unknown degraded case {case!r}")
    spec = SPECS[case]
    rng = np.random.default_rng([seed, 31])
    leds, centre = ring_leds(calib, range_mm, rng)
    left, right = _led_images(calib, leds, spec.peak)
    return DegradedPair(case, compose(left, spec, rng), compose(right, spec, rng), leds, centre)


@dataclass(frozen=True)
class Clip:
    """A stereo clip read back from MJPG video files, with its truth per frame."""

    lefts: list[Image]
    rights: list[Image]
    led_xyz_mm: list[NDArray[np.float64]]
    centers_mm: list[NDArray[np.float64]]


def _write_read_mjpg(images: list[Image], path: Path) -> list[Image]:
    h, w = images[0].shape[:2]
    colour = images[0].ndim == 3
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (w, h), colour)
    assert vw.isOpened()
    for img in images:  # the writer's default quality, as a user records
        vw.write(img)
    vw.release()
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        if not colour and frame.ndim == 3:
            frame = np.ascontiguousarray(frame[:, :, 1])
        out.append(np.asarray(frame, dtype=np.uint8))
    cap.release()
    assert len(out) == len(images), (len(out), len(images))
    return out


def mjpg_clip(
    calib: StereoCalibration,
    frames: int,
    start_mm: float = 2500.0,
    end_mm: float = 1000.0,
    colour: bool = True,
    seed: int = 0,
) -> Clip:
    """A green-LED ring moving from ``start_mm`` to ``end_mm`` in range (drifting, rolling
    1°/frame) through an MJPG round trip (``calib`` as :func:`calibration` gives it)."""
    rng = np.random.default_rng([seed, 32])
    leds0, centre0 = ring_leds(calib, 1000.0, rng)
    spec = CaseSpec(colour=colour)
    lefts, rights, truth, centres = [], [], [], []
    for i in range(frames):
        f = i / max(frames - 1, 1)
        centre = centre0 + np.array(
            [-20.0 + 40.0 * f, 10.0 - 20.0 * f, start_mm + (end_mm - start_mm) * f - centre0[2]]
        )
        a = math.radians(i)
        ca, sa = math.cos(a), math.sin(a)
        # the roll: the ring turned about its centre, in the image plane
        rel = (leds0 - centre0) @ np.array([[ca, sa, 0.0], [-sa, ca, 0.0], [0.0, 0.0, 1.0]])
        leds = centre + rel
        left, right = _led_images(calib, leds, spec.peak)
        lefts.append(compose(left, spec, rng))
        rights.append(compose(right, spec, rng))
        truth.append(leds)
        centres.append(centre)
    with tempfile.TemporaryDirectory() as tmp:
        lefts = _write_read_mjpg(lefts, Path(tmp) / "left.avi")
        rights = _write_read_mjpg(rights, Path(tmp) / "right.avi")
    return Clip(lefts, rights, truth, centres)


WRONG_MM = 5.0  # a lock is wrong beyond this (centre, or an LED from every real LED)


@dataclass(frozen=True)
class Scored:
    """A result against its truth: lock, wrong lock, LED errors (mm), bound held."""

    lock: bool
    wrong: bool
    led_errors_mm: tuple[float, ...]
    center_error_mm: float
    within_bound: bool | None  # None: no lock or no bound reported
    reason: str | None


def score(
    result: PoseResult, led_xyz_mm: NDArray[np.float64], center_mm: NDArray[np.float64]
) -> Scored:
    """Each reported LED against the nearest true LED, the centre against the true centre,
    and whether every true error lies inside its reported 99.9 % protection level."""
    if not result.lock or result.drogue is None:
        return Scored(False, False, (), math.nan, None, result.reason)
    meas = np.array([led.xyz_mm for led in result.leds], dtype=np.float64).reshape(-1, 3)
    errs = np.linalg.norm(meas[:, None, :] - led_xyz_mm[None, :, :], axis=2).min(axis=1)
    c_err = float(np.linalg.norm(np.asarray(result.drogue.center_mm) - center_mm))
    wrong = c_err > WRONG_MM or bool(np.any(errs > WRONG_MM))
    held: bool | None = None
    pl = result.drogue.protection_level_mm
    if pl is not None:
        held = c_err <= pl and all(
            led.protection_level_mm is not None and e <= led.protection_level_mm
            for led, e in zip(result.leds, errs.tolist(), strict=True)
        )
    return Scored(True, wrong, tuple(errs.tolist()), c_err, held, None)


@dataclass(frozen=True)
class SetSummary:
    """Counts over a set of scored results; LED mean over correct locks (mm)."""

    runs: int
    locks: int
    wrong: int
    led_mean_mm: float
    bound_checked: int
    bound_held: int

    @classmethod
    def of(cls, scored: list[Scored]) -> SetSummary:
        errs = [e for s in scored if s.lock and not s.wrong for e in s.led_errors_mm]
        checked = [s.within_bound for s in scored if s.within_bound is not None]
        return cls(
            runs=len(scored),
            locks=sum(s.lock for s in scored),
            wrong=sum(s.wrong for s in scored),
            led_mean_mm=float(np.mean(errs)) if errs else math.nan,
            bound_checked=len(checked),
            bound_held=sum(bool(c) for c in checked),
        )
