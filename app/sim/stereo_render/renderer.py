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

import numpy as np

from app.geometry.calibration import StereoCalibration
from app.sim.led_ring import LedRing, check_pose, ring_points
from app.sim.stereo_render.blobs import (
    LightSpot,
    blob_patches,
    in_frame,
    patch_box,
    project_checked,
    sphere_shapes,
    to_right,
)
from app.sim.stereo_render.distractors import Clutter, Extras, Keepout, make_clutter, make_extras
from app.sim.stereo_render.scene import LED_BGR, RenderedPair, RenderSettings, RenderTruth
from app.sim.stereo_render.sensor import clip_rects, compose, overlaps
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
    """
    settings = settings or RenderSettings()
    wins = None if windows is None else _check_windows(windows)
    ring = ring or LedRing()
    c, n = check_pose(center_mm, normal)
    if not math.isfinite(float(roll_rad)):
        raise ValueError(f"roll_rad must be finite, got {roll_rad}")
    bad = [i for i in settings.occluded if not 1 <= i <= ring.count]
    if bad:
        raise ValueError(f"occluded LED ids must be in 1..{ring.count}, got {bad}")
    bad = [i for i, _ in settings.rim_reflections if not 1 <= i <= ring.count]
    if bad:
        raise ValueError(f"rim_reflections LED ids must be in 1..{ring.count}, got {bad}")
    rng = np.random.default_rng(seed)

    xyz = ring_points(c, n, ring, roll_rad)
    ids = ring.ids.astype(np.int64)
    pl, pr, _, _ = project_checked(calib, xyz)
    in_l = in_frame(pl, calib.image_size)
    in_r = in_frame(pr, calib.image_size)
    occ = np.isin(ids, np.array(settings.occluded, dtype=np.int64))
    draw_l, draw_r = in_l & ~occ, in_r & ~occ

    r_led = np.full(len(xyz), 0.5 * ring.led_diameter_mm)
    a_l = np.full((len(xyz), 2, 2), np.nan)
    a_r = np.full((len(xyz), 2, 2), np.nan)
    if np.any(in_l):
        a_l[in_l] = sphere_shapes(calib.left, xyz[in_l], r_led[in_l])
    xyz_r = to_right(calib, xyz)
    if np.any(in_r):
        a_r[in_r] = sphere_shapes(calib.right, xyz_r[in_r], r_led[in_r])
    rad_l = np.array(
        [np.sqrt(abs(np.linalg.det(a))) if k else np.nan for a, k in zip(a_l, in_l, strict=True)]
    )
    rad_r = np.array(
        [np.sqrt(abs(np.linalg.det(a))) if k else np.nan for a, k in zip(a_r, in_r, strict=True)]
    )

    color = settings.color
    led_bgr = LED_BGR if color else np.ones(3, dtype=np.float32)
    gray_bgr = np.ones(3, dtype=np.float32)
    blobs_l = [LightSpot(pl[k], a_l[k], settings.led_peak, led_bgr) for k in np.flatnonzero(draw_l)]
    blobs_r = [LightSpot(pr[k], a_r[k], settings.led_peak, led_bgr) for k in np.flatnonzero(draw_r)]

    clutter = Clutter()
    keep: tuple[Keepout, Keepout] | None = None
    glinting = settings.glints > 0 or settings.mono_glints > 0
    if settings.clutter > 0 or settings.second_object or glinting:
        cl, cr, _, _ = project_checked(calib, c[None, :])
        keep_l = Keepout(cl[0], pl, np.nan_to_num(rad_l, nan=0.0))
        keep_r = Keepout(cr[0], pr, np.nan_to_num(rad_r, nan=0.0))
        keep = (keep_l, keep_r)
    if settings.clutter > 0 or settings.second_object:
        range_mm = max(float(c[2]), 100.0)
        clutter = make_clutter(calib, settings, rng, range_mm, keep_l, keep_r, gray_bgr)

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
            n,
            float(roll_rad),
            keep if glinting else None,
            clutter,
            led_bgr,
        )

    w, h = calib.image_size
    shape: tuple[int, ...] = (h, w, 3) if color else (h, w)
    win_l, win_r = (None, None) if wins is None else wins
    all_l = blobs_l + clutter.left + extras.left
    all_r = blobs_r + clutter.right + extras.right
    if wins is not None and settings.fast_noise:  # only the blobs that reach a window
        box = settings.blur_sigma_px
        r_l, r_r = clip_rects(win_l or [], shape), clip_rects(win_r or [], shape)
        all_l = [b for b in all_l if overlaps(patch_box(b, box), r_l)]
        all_r = [b for b in all_r if overlaps(patch_box(b, box), r_r)]
    # the patches of both images in one batch (bit-identical to separate calls)
    made = blob_patches(all_l + all_r, settings.supersample, settings.blur_sigma_px)
    pts = [(x0, y0, p, b.bgr) for (x0, y0, p), b in zip(made, all_l + all_r, strict=True)]
    left = compose(shape, all_l, settings, rng, win_l, pts[: len(all_l)])
    right = compose(shape, all_r, settings, rng, win_r, pts[len(all_l) :])

    def rows(items: list[FloatArray], dim: int) -> FloatArray:
        return np.array(items, dtype=np.float64).reshape(-1, dim)

    truth = RenderTruth(
        led_xyz_mm=xyz,
        led_ids=ids,
        visible=draw_l & draw_r,
        led_left_px=pl,
        led_right_px=pr,
        center_mm=c,
        normal=n,
        radius_mm=float(ring.radius_mm),
        clutter_left_px=rows(clutter.left_px, 2),
        clutter_right_px=rows(clutter.right_px, 2),
        in_left=draw_l,
        in_right=draw_r,
        led_left_radius_px=rad_l,
        led_right_radius_px=rad_r,
        clutter_xyz_mm=rows(clutter.xyz, 3),
        second_object_left_px=clutter.second_left,
        second_object_right_px=clutter.second_right,
        roll_rad=float(roll_rad),
        glint_xyz_mm=rows(extras.glint_xyz, 3),
        glint_left_px=rows(extras.glint_left_px, 2),
        glint_right_px=rows(extras.glint_right_px, 2),
        mono_glint_left_px=rows(extras.mono_left_px, 2),
        mono_glint_right_px=rows(extras.mono_right_px, 2),
        reflection_xyz_mm=rows(list(extras.refl_xyz), 3),
        reflection_left_px=rows(list(extras.refl_left_px), 2),
        reflection_right_px=rows(list(extras.refl_right_px), 2),
    )
    return RenderedPair(left=left, right=right, truth=truth)
