"""The pair renderer: the drogue's LED ring in both cameras with exact ground truth (paper §3–5).

Each LED is a small emitting sphere, so its image is a disc whatever the drogue tilt. The
disc is centred on the projection of the LED centre through the full camera model
(distortion and skew, eqs. 2 and 7, via :func:`app.geometry.projection.project_stereo`) and
shaped by the local Jacobian of that projection (radius f·r/Z, slightly elliptical where the
skew or the distortion stretch the image). It is drawn with anti-aliased supersampled
coverage, blurred with a symmetric Gaussian, and placed on a noisy background. Every step is
point-symmetric about the projected centre, so an intensity-weighted centroid (eq. 11) of
the noise-free blob returns the truth pixel to well under 0.01 px.

Clutter and the hostile extras (:mod:`app.sim.stereo_render.distractors`) are added on
request; the extras draw from their own random stream, so a render without them is
byte-identical to one made before they existed. Background, noise and the windows:
:mod:`app.sim.stereo_render.sensor`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import StereoCalibration
from app.sim.led_ring import LedRing, check_pose, ring_points
from app.sim.stereo_render.blobs import (
    LightSpot,
    blob_patches,
    in_frame,
    project_checked,
    project_spheres,
    to_right,
)
from app.sim.stereo_render.distractors import Clutter, Extras, Keepout, make_clutter, make_extras
from app.sim.stereo_render.scene import LED_BGR, RenderedPair, RenderSettings, RenderTruth
from app.sim.stereo_render.sensor import compose
from app.types import FloatArray, Rect

EXTRAS_STREAM = 0x676C6E74  # second seed word of the hostile extras' random stream


def _check_windows(windows: object) -> tuple[list[Rect], list[Rect]]:
    msg = "windows must be (left, right) lists of (x0, y0, x1, y1) integer pixel rectangles"
    sides: list[list[Rect]] = []
    try:
        for side in windows:  # type: ignore[attr-defined]
            rects: list[Rect] = []
            for r in side:
                x0, y0, x1, y1 = (int(v) for v in r)
                if x1 < x0 or y1 < y0:
                    raise ValueError
                rects.append((x0, y0, x1, y1))
            sides.append(rects)
    except (TypeError, ValueError):
        raise ValueError(f"{msg}, got {windows!r}") from None
    if len(sides) != 2:
        raise ValueError(f"{msg}, got {windows!r}")
    return sides[0], sides[1]


@dataclass(frozen=True)
class RingPose:
    """The drogue ring's pose: centre (mm, left camera frame), unit normal, roll (rad)."""

    center_mm: FloatArray
    normal: FloatArray
    roll_rad: float


@dataclass(frozen=True)
class LedImages:
    """Where the ring's LEDs land in both images (the truth the blobs are drawn from).

    Per LED (rows in ring order): ``xyz_mm`` (N, 3) centres in the left camera frame (mm),
    ``ids`` (N,) ring ids, ``left_px``/``right_px`` (N, 2) projected centres through the full
    camera model (eqs. 2, 7; px); ``draw_left``/``draw_right`` in the image and not occluded;
    ``shape_left``/``shape_right`` (N, 2, 2) the sphere's image ellipse (unit disc → px, NaN
    where out of frame); ``radius_left_px``/``radius_right_px`` its equivalent radius
    √|det A| (px, NaN where out of frame)."""

    xyz_mm: FloatArray
    ids: NDArray[np.int64]
    left_px: FloatArray
    right_px: FloatArray
    draw_left: NDArray[np.bool_]
    draw_right: NDArray[np.bool_]
    shape_left: FloatArray
    shape_right: FloatArray
    radius_left_px: FloatArray
    radius_right_px: FloatArray


@dataclass(frozen=True)
class Distractors:
    """What is drawn besides the LEDs: ``clutter`` (main random stream) and the hostile
    ``extras`` (their own stream); both empty when ``settings`` asks for none."""

    clutter: Clutter
    extras: Extras


@dataclass(frozen=True)
class ImagePair:
    """The two composed images (uint8, (h, w) or (h, w, 3) with colour)."""

    left: NDArray[np.uint8]
    right: NDArray[np.uint8]


def _check_request(settings: RenderSettings, ring: LedRing, roll_rad: float) -> None:
    """ValueError for a non-finite roll (rad) or LED ids outside 1..``ring.count``."""
    if not math.isfinite(float(roll_rad)):
        raise ValueError(f"roll_rad must be finite, got {roll_rad}")
    bad = [i for i in settings.occluded if not 1 <= i <= ring.count]
    if bad:
        raise ValueError(f"occluded LED ids must be in 1..{ring.count}, got {bad}")
    bad = [i for i, _ in settings.rim_reflections if not 1 <= i <= ring.count]
    if bad:
        raise ValueError(f"rim_reflections LED ids must be in 1..{ring.count}, got {bad}")


def _equivalent_radii(shapes: FloatArray, seen: NDArray[np.bool_]) -> FloatArray:
    """√|det A| of each 2×2 image ellipse (px); NaN where not ``seen``."""
    out = np.full(len(shapes), np.nan)
    if np.any(seen):
        out[seen] = np.sqrt(np.abs(np.linalg.det(shapes[seen])))
    return out


def project_leds(
    calib: StereoCalibration,
    ring: LedRing,
    pose: RingPose,
    occluded: Sequence[int],
) -> LedImages:
    """Project the ring's LEDs at ``pose`` into both cameras: centres through the full model
    (eqs. 2, 7), each LED sphere's image ellipse from the local Jacobian (radius ≈ f·r/Z px),
    and which LEDs are drawn (in frame, not ``occluded``)."""
    xyz = ring_points(pose.center_mm, pose.normal, ring, pose.roll_rad)
    ids = ring.ids.astype(np.int64)
    r_led = np.full(len(xyz), 0.5 * ring.led_diameter_mm)
    left = project_spheres(calib.left, xyz, r_led)
    right = project_spheres(calib.right, to_right(calib, xyz), r_led)
    pl, pr = left.center_px, right.center_px
    in_l = in_frame(pl, calib.image_size)
    in_r = in_frame(pr, calib.image_size)
    occ = np.isin(ids, np.array(occluded, dtype=np.int64))
    a_l, a_r = left.shape_px, right.shape_px
    a_l[~in_l] = np.nan
    a_r[~in_r] = np.nan
    return LedImages(
        xyz_mm=xyz,
        ids=ids,
        left_px=pl,
        right_px=pr,
        draw_left=in_l & ~occ,
        draw_right=in_r & ~occ,
        shape_left=a_l,
        shape_right=a_r,
        radius_left_px=_equivalent_radii(a_l, in_l),
        radius_right_px=_equivalent_radii(a_r, in_r),
    )


def make_distractors(
    calib: StereoCalibration,
    settings: RenderSettings,
    ring: LedRing,
    leds: LedImages,
    pose: RingPose,
    rng: np.random.Generator,
    seed: int | None,
    led_bgr: NDArray[np.float32],
) -> Distractors:
    """Clutter (drawn from ``rng``, the main stream) and the hostile extras (their own stream
    from ``seed`` and :data:`EXTRAS_STREAM`), kept off the LEDs' and the ring centre's images."""
    c = pose.center_mm
    clutter = Clutter()
    keep: tuple[Keepout, Keepout] | None = None
    glinting = settings.glints > 0 or settings.mono_glints > 0
    if settings.clutter > 0 or settings.second_object or glinting:
        cl, cr, _, _ = project_checked(calib, c[None, :])
        keep = (
            Keepout(cl[0], leds.left_px, np.nan_to_num(leds.radius_left_px, nan=0.0)),
            Keepout(cr[0], leds.right_px, np.nan_to_num(leds.radius_right_px, nan=0.0)),
        )
    if keep is not None and (settings.clutter > 0 or settings.second_object):
        range_mm = max(float(c[2]), 100.0)
        gray_bgr = np.ones(3, dtype=np.float32)
        clutter = make_clutter(calib, settings, rng, range_mm, keep[0], keep[1], gray_bgr)

    extras = Extras()
    if glinting or settings.rim_reflections:
        # own stream, so the main one (clutter, noise) is the same with or without extras
        rng_x = np.random.default_rng(None if seed is None else [int(seed), EXTRAS_STREAM])
        extras = make_extras(
            calib,
            settings,
            ring,
            rng_x,
            c,
            pose.normal,
            pose.roll_rad,
            keep if glinting else None,
            clutter,
            led_bgr,
        )
    return Distractors(clutter=clutter, extras=extras)


def compose_pair(
    image_size: tuple[int, int],
    settings: RenderSettings,
    spots: tuple[list[LightSpot], list[LightSpot]],
    rng: np.random.Generator,
    wins: tuple[list[Rect], list[Rect]] | None,
) -> ImagePair:
    """Background, noise and the light ``spots`` (left, right) → both images. With windows
    (``wins``) and ``fast_noise`` only the spots reaching a window are rendered. The noise
    is drawn from ``rng``, left image first."""
    w, h = image_size
    shape: tuple[int, ...] = (h, w, 3) if settings.color else (h, w)
    win_l, win_r = (None, None) if wins is None else wins
    all_l, all_r = spots
    if settings.fast_noise:  # each blob drawn straight into its image (and its windows)
        left = compose(shape, all_l, settings, rng, win_l)
        right = compose(shape, all_r, settings, rng, win_r)
        return ImagePair(left=left, right=right)
    # the patches of both images in one batch (bit-identical to separate calls)
    made = blob_patches(all_l + all_r, settings.supersample, settings.blur_sigma_px)
    pts = [(x0, y0, p, b.bgr) for (x0, y0, p), b in zip(made, all_l + all_r, strict=True)]
    left = compose(shape, all_l, settings, rng, win_l, pts[: len(all_l)])
    right = compose(shape, all_r, settings, rng, win_r, pts[len(all_l) :])
    return ImagePair(left=left, right=right)


def _rows(items: list[FloatArray], dim: int) -> FloatArray:
    """Points as an (n, ``dim``) float64 array (n may be 0)."""
    return np.array(items, dtype=np.float64).reshape(-1, dim)


def render_truth(
    leds: LedImages,
    pose: RingPose,
    ring: LedRing,
    distractors: Distractors,
) -> RenderTruth:
    """The render's ground truth: the LEDs' 3-D centres (mm) and pixels, what was drawn,
    and every distractor's position (mm, px)."""
    clutter, extras = distractors.clutter, distractors.extras
    return RenderTruth(
        led_xyz_mm=leds.xyz_mm,
        led_ids=leds.ids,
        visible=leds.draw_left & leds.draw_right,
        led_left_px=leds.left_px,
        led_right_px=leds.right_px,
        center_mm=pose.center_mm,
        normal=pose.normal,
        radius_mm=float(ring.radius_mm),
        clutter_left_px=_rows(clutter.left_px, 2),
        clutter_right_px=_rows(clutter.right_px, 2),
        in_left=leds.draw_left,
        in_right=leds.draw_right,
        led_left_radius_px=leds.radius_left_px,
        led_right_radius_px=leds.radius_right_px,
        clutter_xyz_mm=_rows(clutter.xyz, 3),
        second_object_left_px=clutter.second_left,
        second_object_right_px=clutter.second_right,
        roll_rad=pose.roll_rad,
        glint_xyz_mm=_rows(extras.glint_xyz, 3),
        glint_left_px=_rows(extras.glint_left_px, 2),
        glint_right_px=_rows(extras.glint_right_px, 2),
        mono_glint_left_px=_rows(extras.mono_left_px, 2),
        mono_glint_right_px=_rows(extras.mono_right_px, 2),
        reflection_xyz_mm=_rows(list(extras.refl_xyz), 3),
        reflection_left_px=_rows(list(extras.refl_left_px), 2),
        reflection_right_px=_rows(list(extras.refl_right_px), 2),
    )


def render_pair(
    calib: StereoCalibration,
    center_mm: object,
    normal: object,
    settings: RenderSettings | None = None,
    ring: LedRing | None = None,
    seed: int | None = 0,
    roll_rad: float = 0.0,
    windows: tuple[Sequence[Rect], Sequence[Rect]] | None = None,
) -> RenderedPair:
    """Render the LED ring at (centre mm, normal) into both cameras of ``calib``.

    Deterministic for a given ``seed`` (``None`` → fresh randomness). LEDs behind a camera
    or outside an image are not drawn there (``truth.visible`` False); poses partly out of
    view never raise. Raises ValueError for a non-finite pose, a zero normal or bad ids.

    The hostile extras of ``settings`` (``glints``, ``mono_glints``, ``rim_reflections``)
    use a second random stream derived from ``seed``: with them off, the images are exactly
    those of a renderer without them; with them on, the LEDs, clutter and noise are
    unchanged and only the extras' own pixels differ.

    ``windows``: (left rectangles, right rectangles), each ``(x0, y0, x1, y1)`` px, half-open
    (a tracker's windows). Only those pixels are rendered — every random draw is still made,
    and only the blobs reaching a window are drawn — so inside them the images are
    bit-identical to the full render with the same seed; pixels outside are 0. The truth is
    the full render's. With ``fast_noise`` this costs only the windows' pixels.

    Phases: project the LEDs (:func:`project_leds`) → distractors
    (:func:`make_distractors`) → images (:func:`compose_pair`) → truth
    (:func:`render_truth`).
    """
    settings = settings or RenderSettings()
    wins = None if windows is None else _check_windows(windows)
    ring = ring or LedRing()
    c, n = check_pose(center_mm, normal)
    _check_request(settings, ring, roll_rad)
    rng = np.random.default_rng(seed)
    pose = RingPose(center_mm=c, normal=n, roll_rad=float(roll_rad))
    leds = project_leds(calib, ring, pose, settings.occluded)
    led_bgr = LED_BGR if settings.color else np.ones(3, dtype=np.float32)
    spots_l = [
        LightSpot(leds.left_px[k], leds.shape_left[k], settings.led_peak, led_bgr)
        for k in np.flatnonzero(leds.draw_left)
    ]
    spots_r = [
        LightSpot(leds.right_px[k], leds.shape_right[k], settings.led_peak, led_bgr)
        for k in np.flatnonzero(leds.draw_right)
    ]
    extra = make_distractors(calib, settings, ring, leds, pose, rng, seed, led_bgr)
    spots = (
        spots_l + extra.clutter.left + extra.extras.left,
        spots_r + extra.clutter.right + extra.extras.right,
    )
    images = compose_pair(calib.image_size, settings, spots, rng, wins)
    truth = render_truth(leds, pose, ring, extra)
    return RenderedPair(left=images.left, right=images.right, truth=truth)
