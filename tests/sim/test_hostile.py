"""Hostile renderer extras (LED-like glints, monocular glints, rim reflections) and the
independent OpenCV-only renderer used to cross-check the project's image formation."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from app.geometry.calibration import CameraIntrinsics, paper_calibration
from app.geometry.projection import project_stereo
from app.sim.led_ring import LedRing, led_angles_rad, ring_basis, stereo_center_x_mm, tilted_normal
from app.sim.stereo_render import LED_BGR, RenderSettings, RenderTruth, render_pair
from tests.support.cv_render import project_cv, render_pair_cv, skew_free

CALIB = paper_calibration()
FLAT = skew_free(CALIB)
RING = LedRing()
DEPTH = 1500.0
CENTER = np.array([stereo_center_x_mm(CALIB, DEPTH), 0.0, DEPTH])
NORMAL = tilted_normal(12.0, 30.0)
BG = 12.0


def _centroid(img: np.ndarray, px: np.ndarray, half: int, background: float) -> np.ndarray:
    """Background-subtracted intensity-weighted centroid over a square window."""
    x0, y0 = int(round(px[0])) - half, int(round(px[1])) - half
    win = img[y0 : y0 + 2 * half + 1, x0 : x0 + 2 * half + 1].astype(np.float64) - background
    ys, xs = np.mgrid[y0 : y0 + 2 * half + 1, x0 : x0 + 2 * half + 1]
    return np.array([(win * xs).sum() / win.sum(), (win * ys).sum() / win.sum()])


def _blob(img: np.ndarray, px: np.ndarray, half: int = 12) -> tuple[float, int, float]:
    """(peak above background, pixels above half of it, summed intensity) around ``px``."""
    u, v = int(round(px[0])), int(round(px[1]))
    win = img[v - half : v + half + 1, u - half : u + half + 1].astype(np.float64) - BG
    peak = float(win.max())
    return peak, int(np.count_nonzero(win > 0.5 * peak)), float(np.clip(win, 0, None).sum())


def _radius_px(cam_f: float, z_mm: float) -> float:
    return cam_f * 0.5 * RING.led_diameter_mm / z_mm


def _f(cam: CameraIntrinsics) -> float:
    return 0.5 * (cam.fx + cam.fy)


# ---------------------------------------------------------------- independent renderer ---
def test_cv_renderer_refuses_skew() -> None:
    assert CALIB.left.skew != 0.0
    with pytest.raises(ValueError, match="skew"):
        render_pair_cv(CALIB, np.array([[0.0, 0.0, 1000.0]]))
    assert FLAT.left.skew == 0.0 and FLAT.right.skew == 0.0


@pytest.mark.parametrize(("depth", "roll"), [(700.0, 0.3), (1500.0, 1.1), (3000.0, 2.0)])
def test_cv_renderer_centres_agree_with_project_renderer(depth: float, roll: float) -> None:
    c = np.array([stereo_center_x_mm(FLAT, depth), 20.0, depth])
    s = RenderSettings(noise_sigma=0.0, glints=3, rim_reflections=((2, 20.0),))
    t = render_pair(FLAT, c, tilted_normal(15.0, 200.0), s, seed=1, roll_rad=roll).truth
    assert len(t.glint_xyz_mm) == 3
    xyz = np.vstack([t.led_xyz_mm, t.glint_xyz_mm, t.reflection_xyz_mm])
    _, _, pl, pr = render_pair_cv(
        FLAT, t.led_xyz_mm, np.vstack([t.glint_xyz_mm, t.reflection_xyz_mm])
    )
    np.testing.assert_allclose(
        pl, np.vstack([t.led_left_px, t.glint_left_px, t.reflection_left_px]), atol=1e-6
    )
    np.testing.assert_allclose(
        pr, np.vstack([t.led_right_px, t.glint_right_px, t.reflection_right_px]), atol=1e-6
    )
    # the check can fail: with the paper's skew the project's pixels move by γ·y_d
    t_skew = render_pair(CALIB, c, tilted_normal(15.0, 200.0), s, seed=1, roll_rad=roll).truth
    pl_skew, _, _, _ = project_cv(FLAT, xyz[:5])
    assert np.max(np.abs(pl_skew - t_skew.led_left_px)) > 0.05


def test_cv_renderer_disc_centroids_are_the_projections() -> None:
    rng = np.random.default_rng(5)
    pts = []
    for i, depth in enumerate((600.0, 1500.0, 3500.0)):  # one image row of discs per depth
        for u0 in (250.0, 450.0, 650.0, 850.0, 1050.0):
            u, v = u0 + rng.uniform(0, 1), 200.0 + 300.0 * i + rng.uniform(0, 1)
            xn, yn = (u - FLAT.left.u0) / FLAT.left.fx, (v - FLAT.left.v0) / FLAT.left.fy
            pts.append([xn * depth, yn * depth, depth])
    xyz = np.array(pts)
    left, right, pl, pr = render_pair_cv(FLAT, xyz[:7], xyz[7:], noise_sigma=0.0, seed=0)
    assert left.dtype == np.uint8 and left.shape == (1024, 1280)
    w, h = FLAT.image_size
    errs = []
    for img, px, cam, z in (
        (left, pl, FLAT.left, xyz[:, 2]),
        (right, pr, FLAT.right, ((FLAT.R @ xyz.T).T + FLAT.T)[:, 2]),
    ):
        for k in range(len(xyz)):
            r = _radius_px(_f(cam), z[k])
            half = int(math.ceil(r)) + 5
            if not (half <= px[k, 0] <= w - 1 - half and half <= px[k, 1] <= h - 1 - half):
                continue
            assert img[int(round(px[k, 1])), int(round(px[k, 0]))] > BG + 100
            errs.append(_centroid(img, px[k], half, BG) - px[k])
    err = np.abs(np.array(errs))
    assert len(err) >= 25
    assert err.max() < 0.05, err.max()


def test_both_renderers_draw_the_same_led_size_and_brightness() -> None:
    """Independent check of the project's sphere image (radius f·r/Z, peak, blur)."""
    s = RenderSettings(noise_sigma=0.0)
    for depth in (800.0, 2000.0):
        c = np.array([stereo_center_x_mm(FLAT, depth), 0.0, depth])
        pair = render_pair(FLAT, c, NORMAL, s, seed=0)
        t = pair.truth
        left, right, _, _ = render_pair_cv(FLAT, t.led_xyz_mm, noise_sigma=0.0)
        for ours, theirs, px in (
            (pair.left, left, t.led_left_px),
            (pair.right, right, t.led_right_px),
        ):
            for p in px:
                a, b = _blob(ours, p, 20), _blob(theirs, p, 20)
                assert a[0] == pytest.approx(b[0], rel=0.05)  # peak
                assert a[2] == pytest.approx(b[2], rel=0.02)  # integrated intensity ∝ area


# ---------------------------------------------------------------- 3-D glints -------------
def _keepout_ok(t: RenderTruth, side: str, p: np.ndarray, r: float) -> tuple[float, float]:
    """(margin to the ring keep-out disc, smallest gap to an LED blob) in px."""
    cl, cr = project_stereo(CALIB, t.center_mm[None, :])
    centre = cl[0] if side == "left" else cr[0]
    leds = t.led_left_px if side == "left" else t.led_right_px
    led_r = t.led_left_radius_px if side == "left" else t.led_right_radius_px
    ring_r = float(np.max(np.linalg.norm(leds - centre, axis=1) + led_r))
    margin = float(np.linalg.norm(p - centre)) - r - (1.4 * ring_r + 10.0)
    gap = float(np.min(np.linalg.norm(leds - p, axis=1) - led_r - r))
    return margin, gap


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_glints_geometry_and_keepout(seed: int) -> None:
    s = RenderSettings(glints=8, mono_glints=3, clutter=4, noise_sigma=0.0)
    pair = render_pair(CALIB, CENTER, tilted_normal(10.0, 90.0 * seed), s, seed=seed)
    t = pair.truth
    assert t.glint_xyz_mm.shape == (8, 3)
    assert t.glint_left_px.shape == (8, 2) and t.glint_right_px.shape == (8, 2)
    # truth px = projection of the glint centre (project's model with the paper's skew)
    pl, pr = project_stereo(CALIB, t.glint_xyz_mm)
    np.testing.assert_allclose(t.glint_left_px, pl, atol=1e-9)
    np.testing.assert_allclose(t.glint_right_px, pr, atol=1e-9)
    # default depth window: drogue depth × (0.87, 1.13)
    z = t.glint_xyz_mm[:, 2]
    assert np.all((z >= 0.87 * CENTER[2]) & (z <= 1.13 * CENTER[2]))
    w, h = CALIB.image_size
    z_r = ((CALIB.R @ t.glint_xyz_mm.T).T + CALIB.T)[:, 2]
    for side, px, img, zz, cam in (
        ("left", t.glint_left_px, pair.left, z, CALIB.left),
        ("right", t.glint_right_px, pair.right, z_r, CALIB.right),
    ):
        r = np.array([_radius_px(_f(cam), zk) for zk in zz])
        assert np.all(px[:, 0] - r >= 0) and np.all(px[:, 0] + r <= w - 1)
        assert np.all(px[:, 1] - r >= 0) and np.all(px[:, 1] + r <= h - 1)
        for k in range(len(px)):
            margin, gap = _keepout_ok(t, side, px[k], r[k])
            assert margin > -0.5 and gap >= 15.0 - 0.5
            assert img[int(round(px[k, 1])), int(round(px[k, 0]))] > BG + 150
        # separate blobs: ≥ 4 px between the discs of any two glints
        d = np.linalg.norm(px[:, None] - px[None, :], axis=2) - r[:, None] - r[None, :]
        d[np.arange(len(px)), np.arange(len(px))] = np.inf
        assert d.min() >= 4.0 - 0.5
    # clutter is still there, and the main random stream untouched (same as without glints)
    plain = render_pair(
        CALIB,
        CENTER,
        tilted_normal(10.0, 90.0 * seed),
        RenderSettings(clutter=4, noise_sigma=0.0),
        seed=seed,
    ).truth
    np.testing.assert_array_equal(t.clutter_left_px, plain.clutter_left_px)
    np.testing.assert_array_equal(t.clutter_xyz_mm, plain.clutter_xyz_mm)


def test_many_glints_are_separate_led_sized_blobs() -> None:
    """Crowded: 60 near glints (≈ 11 px radius) would touch by chance; none may."""
    s = RenderSettings(glints=60, glint_depth_mm=(500.0, 600.0), noise_sigma=0.0)
    pair = render_pair(CALIB, CENTER, NORMAL, s, seed=11)
    t = pair.truth
    assert len(t.glint_xyz_mm) == 60
    z_r = ((CALIB.R @ t.glint_xyz_mm.T).T + CALIB.T)[:, 2]
    for img, px, zz, cam in (
        (pair.left, t.glint_left_px, t.glint_xyz_mm[:, 2], CALIB.left),
        (pair.right, t.glint_right_px, z_r, CALIB.right),
    ):
        r = np.array([_radius_px(_f(cam), zk) for zk in zz])
        w, h = CALIB.image_size
        assert np.all((px - r[:, None] >= 0) & (px + r[:, None] <= [w - 1, h - 1]))  # unclipped
        d = np.linalg.norm(px[:, None] - px[None, :], axis=2) - r[:, None] - r[None, :]
        d[np.arange(len(px)), np.arange(len(px))] = np.inf
        assert d.min() >= 4.0 - 0.5
        n, _ = cv2.connectedComponents((img > BG + 60).astype(np.uint8), connectivity=8)
        assert n - 1 == 5 + 60


def test_extras_are_drawn_at_their_truth_pixels() -> None:
    """Centroid of every isolated extra blob = its truth pixel (as for the LEDs)."""
    s = RenderSettings(
        glints=8, mono_glints=4, rim_reflections=((1, 36.0), (3, -36.0)), noise_sigma=0.0
    )
    pair = render_pair(CALIB, CENTER, NORMAL, s, seed=12, roll_rad=0.4)
    t = pair.truth
    checked = 0
    for img, glints, mono, refl, leds in (
        (pair.left, t.glint_left_px, t.mono_glint_left_px, t.reflection_left_px, t.led_left_px),
        (
            pair.right,
            t.glint_right_px,
            t.mono_glint_right_px,
            t.reflection_right_px,
            t.led_right_px,
        ),
    ):
        mono = mono[np.all(np.isfinite(mono), axis=1)]
        items = np.vstack([glints, mono, refl, leds])
        half = int(math.ceil(_radius_px(_f(CALIB.left), 0.87 * CENTER[2]))) + 3
        for k, p in enumerate(items[: len(items) - len(leds)]):
            others = np.delete(items, k, axis=0)
            if np.min(np.linalg.norm(others - p, axis=1)) < 2 * half + 6:
                continue  # another blob within the window
            if np.any(p < half) or np.any(p > np.array(CALIB.image_size) - 1 - half):
                continue  # window cut by the border
            err = _centroid(img, p, half, BG) - p
            assert np.max(np.abs(err)) < 0.02, (k, err)
            checked += 1
    assert checked >= 20


def test_glints_in_custom_depth_window_project_like_opencv() -> None:
    c = np.array([stereo_center_x_mm(FLAT, DEPTH), 0.0, DEPTH])
    s = RenderSettings(glints=10, glint_depth_mm=(1200.0, 1300.0), noise_sigma=0.0)
    t = render_pair(FLAT, c, NORMAL, s, seed=3).truth
    assert len(t.glint_xyz_mm) == 10
    assert np.all((t.glint_xyz_mm[:, 2] >= 1200.0) & (t.glint_xyz_mm[:, 2] <= 1300.0))
    cl, _ = cv2.projectPoints(t.glint_xyz_mm, np.zeros(3), np.zeros(3), FLAT.left.K, FLAT.left.dist)
    rvec, _ = cv2.Rodrigues(FLAT.R)
    cr, _ = cv2.projectPoints(t.glint_xyz_mm, rvec, FLAT.T, FLAT.right.K, FLAT.right.dist)
    np.testing.assert_allclose(t.glint_left_px, cl.reshape(-1, 2), atol=1e-6)
    np.testing.assert_allclose(t.glint_right_px, cr.reshape(-1, 2), atol=1e-6)


def test_glints_look_like_leds() -> None:
    s = RenderSettings(glints=6, glint_depth_mm=(1450.0, 1550.0), noise_sigma=0.0)
    pair = render_pair(CALIB, CENTER, NORMAL, s, seed=4)
    t = pair.truth
    assert len(t.glint_xyz_mm) == 6
    for img, leds, glints in (
        (pair.left, t.led_left_px, t.glint_left_px),
        (pair.right, t.led_right_px, t.glint_right_px),
    ):
        led = np.array([_blob(img, p)[:2] for p in leds], dtype=float)
        gl = np.array([_blob(img, p)[:2] for p in glints], dtype=float)
        ref_peak, ref_area = led[:, 0].mean(), led[:, 1].mean()
        assert ref_peak > 200 and ref_area > 20
        assert np.all(np.abs(gl[:, 0] / ref_peak - 1) <= 0.2), gl[:, 0] / ref_peak
        assert np.all(np.abs(gl[:, 1] / ref_area - 1) <= 0.2), gl[:, 1] / ref_area
    # default window (±13 % depth): the size follows the depth like an LED's would
    pair = render_pair(CALIB, CENTER, NORMAL, RenderSettings(glints=6, noise_sigma=0.0), seed=5)
    t = pair.truth
    led_area = np.mean([_blob(pair.left, p)[1] for p in t.led_left_px])
    for p, z in zip(t.glint_left_px, t.glint_xyz_mm[:, 2], strict=True):
        expected = led_area * (CENTER[2] / z) ** 2
        assert _blob(pair.left, p)[1] == pytest.approx(expected, rel=0.2)


def test_glint_colours() -> None:
    base = dict(glints=4, mono_glints=2, color=True, noise_sigma=0.0)
    pair = render_pair(CALIB, CENTER, NORMAL, RenderSettings(**base, glint_led_color=True), seed=0)
    t = pair.truth

    def bgr(img: np.ndarray, p: np.ndarray) -> np.ndarray:
        return img[int(round(p[1])), int(round(p[0]))].astype(float) - BG

    led = np.mean([bgr(pair.left, p) for p in t.led_left_px], axis=0)
    np.testing.assert_allclose(led / led[1], LED_BGR, atol=0.03)
    mono = [p for p in t.mono_glint_left_px if np.all(np.isfinite(p))]
    for p in [*t.glint_left_px, *mono]:
        c = bgr(pair.left, p)
        np.testing.assert_allclose(c / c[1], LED_BGR, atol=0.05)  # exactly LED green
    pair = render_pair(CALIB, CENTER, NORMAL, RenderSettings(**base), seed=0)
    for p in pair.truth.glint_left_px:
        c = bgr(pair.left, p)
        assert c.min() > 0.6 * c.max()  # whitish, not LED green


def test_glint_places_do_not_depend_on_colour_mode() -> None:
    t = [
        render_pair(CALIB, CENTER, NORMAL, RenderSettings(glints=4, mono_glints=2, **kw), seed=3)
        for kw in ({}, {"color": True}, {"color": True, "glint_led_color": True})
    ]
    for other in t[1:]:
        np.testing.assert_array_equal(t[0].truth.glint_xyz_mm, other.truth.glint_xyz_mm)
        np.testing.assert_array_equal(t[0].truth.mono_glint_left_px, other.truth.mono_glint_left_px)


# ---------------------------------------------------------------- monocular glints -------
def test_mono_glints_one_image_each_and_separate_blobs() -> None:
    s = RenderSettings(
        glints=5, mono_glints=5, rim_reflections=((1, 36.0), (4, -30.0)), noise_sigma=0.0
    )
    pair = render_pair(CALIB, CENTER, NORMAL, s, seed=6)
    t = pair.truth
    ml, mr = t.mono_glint_left_px, t.mono_glint_right_px
    assert ml.shape == (5, 2) and mr.shape == (5, 2)
    in_l = np.all(np.isfinite(ml), axis=1)
    in_r = np.all(np.isfinite(mr), axis=1)
    np.testing.assert_array_equal(in_l, [True, False, True, False, True])  # alternating
    np.testing.assert_array_equal(in_r, ~in_l)
    led_area = np.mean([_blob(pair.left, p)[1] for p in t.led_left_px])
    for p in ml[in_l]:
        peak, area, _ = _blob(pair.left, p)
        assert peak > 200 and area == pytest.approx(led_area, rel=0.2)
        margin, gap = _keepout_ok(t, "left", p, _radius_px(_f(CALIB.left), CENTER[2]))
        assert margin > -0.5 and gap >= 14.5
    # every drawn item is its own blob, and a monocular glint is absent from the other image
    for img, n_mono in ((pair.left, 3), (pair.right, 2)):
        n, _ = cv2.connectedComponents((img > BG + 100).astype(np.uint8), connectivity=8)
        assert n - 1 == 5 + 5 + n_mono + 2


# ---------------------------------------------------------------- rim reflections --------
@pytest.mark.parametrize("roll", [0.0, 0.7])
def test_rim_reflections_on_the_rim_at_their_offset(roll: float) -> None:
    refl = ((1, 20.0), (3, -36.0), (5, 190.0), (2, 0.0))
    s = RenderSettings(rim_reflections=refl, noise_sigma=0.0)
    pair = render_pair(CALIB, CENTER, NORMAL, s, seed=0, roll_rad=roll)
    t = pair.truth
    assert t.reflection_xyz_mm.shape == (4, 3)
    d = t.reflection_xyz_mm - t.center_mm
    in_plane = d @ t.normal
    radial = np.linalg.norm(d - np.outer(in_plane, t.normal), axis=1)
    assert np.all(np.hypot(radial - RING.radius_mm, in_plane) < 1e-9)  # on the circle
    # angle clockwise from the top as seen by the camera, like the LEDs
    e_up, e_right = ring_basis(t.normal)
    ang = np.degrees(np.arctan2(d @ e_right, d @ e_up))
    dl = t.led_xyz_mm - t.center_mm
    led_ang = np.degrees(np.arctan2(dl @ e_right, dl @ e_up))
    wrap = (led_ang - np.degrees(led_angles_rad(RING, roll)) + 180.0) % 360.0 - 180.0
    assert np.all(np.abs(wrap) < 1e-9)  # same convention as the LEDs' θ_k
    for k, (led_id, off) in enumerate(refl):
        diff = (ang[k] - led_ang[led_id - 1] - off + 180.0) % 360.0 - 180.0
        assert abs(diff) < 1e-9
    np.testing.assert_allclose(t.reflection_xyz_mm[3], t.led_xyz_mm[1], atol=1e-9)
    pl, pr = project_stereo(CALIB, t.reflection_xyz_mm)
    np.testing.assert_allclose(t.reflection_left_px, pl, atol=1e-9)
    np.testing.assert_allclose(t.reflection_right_px, pr, atol=1e-9)
    # drawn in both images with the LED's size and brightness
    led = np.array([_blob(pair.left, p)[:2] for p in t.led_left_px], dtype=float).mean(axis=0)
    for img, px in ((pair.left, pl), (pair.right, pr)):
        for p in px[:3]:
            peak, area, _ = _blob(img, p, 8)
            assert peak == pytest.approx(led[0], rel=0.1)
            assert area == pytest.approx(led[1], rel=0.2)


def test_reflection_drawn_when_its_led_is_occluded() -> None:
    s = RenderSettings(occluded=(2,), rim_reflections=((2, 25.0),), noise_sigma=0.0)
    pair = render_pair(CALIB, CENTER, NORMAL, s, seed=0)
    t = pair.truth
    assert not t.visible[1]
    for img, led, refl in (
        (pair.left, t.led_left_px[1], t.reflection_left_px[0]),
        (pair.right, t.led_right_px[1], t.reflection_right_px[0]),
    ):
        assert np.linalg.norm(led - refl) > 25  # separate places
        assert _blob(img, led, 8)[0] <= 0.5  # the LED: not drawn
        assert _blob(img, refl, 8)[0] > 200  # its reflection: drawn


def test_reflection_colour_is_the_led_colour() -> None:
    s = RenderSettings(color=True, rim_reflections=((3, 30.0),), noise_sigma=0.0)
    pair = render_pair(CALIB, CENTER, NORMAL, s, seed=0)
    p = pair.truth.reflection_left_px[0]
    c = pair.left[int(round(p[1])), int(round(p[0]))].astype(float) - BG
    np.testing.assert_allclose(c / c[1], LED_BGR, atol=0.05)


# ---------------------------------------------------------------- compatibility ----------
@pytest.mark.parametrize("color", [False, True])
def test_extras_off_is_byte_identical(color: bool) -> None:
    a = render_pair(CALIB, CENTER, NORMAL, RenderSettings(clutter=5, color=color), seed=9)
    inert = RenderSettings(
        clutter=5, color=color, glint_depth_mm=(900.0, 1000.0), glint_led_color=True
    )
    b = render_pair(CALIB, CENTER, NORMAL, inert, seed=9)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert b.truth.glint_xyz_mm.shape == (0, 3) and b.truth.mono_glint_left_px.shape == (0, 2)
    assert b.truth.reflection_left_px.shape == (0, 2)


@pytest.mark.parametrize("fast", [False, True])
def test_extras_change_only_their_own_pixels(fast: bool) -> None:
    """The extras use their own random stream: noise and clutter are as without them."""
    base = dict(clutter=4, second_object=True, fast_noise=fast)
    a = render_pair(CALIB, CENTER, NORMAL, RenderSettings(**base), seed=2)
    s = RenderSettings(**base, glints=4, mono_glints=2, rim_reflections=((1, 30.0),))
    b = render_pair(CALIB, CENTER, NORMAL, s, seed=2)
    np.testing.assert_array_equal(a.truth.clutter_left_px, b.truth.clutter_left_px)
    t = b.truth
    for img_a, img_b, pts in (
        (a.left, b.left, [t.glint_left_px, t.mono_glint_left_px, t.reflection_left_px]),
        (a.right, b.right, [t.glint_right_px, t.mono_glint_right_px, t.reflection_right_px]),
    ):
        mask = np.zeros(img_a.shape, dtype=bool)
        for p in np.vstack(pts):
            if np.all(np.isfinite(p)):
                u, v = int(round(p[0])), int(round(p[1]))
                mask[max(v - 12, 0) : v + 13, max(u - 12, 0) : u + 13] = True
        assert np.array_equal(img_a[~mask], img_b[~mask])
        assert not np.array_equal(img_a[mask], img_b[mask])


def test_extras_deterministic_under_seed() -> None:
    s = RenderSettings(glints=5, mono_glints=2)
    a = render_pair(CALIB, CENTER, NORMAL, s, seed=7)
    b = render_pair(CALIB, CENTER, NORMAL, s, seed=7)
    c = render_pair(CALIB, CENTER, NORMAL, s, seed=8)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    np.testing.assert_array_equal(a.truth.glint_xyz_mm, b.truth.glint_xyz_mm)
    assert not np.allclose(a.truth.glint_xyz_mm, c.truth.glint_xyz_mm)
    d = render_pair(CALIB, CENTER, NORMAL, s, seed=None).truth
    assert d.glint_xyz_mm.shape == (5, 3)


# ---------------------------------------------------------------- validation / JSON ------
@pytest.mark.parametrize(
    "kwargs",
    [
        {"glints": -1},
        {"glints": 1.5},
        {"glints": True},
        {"mono_glints": -2},
        {"glint_depth_mm": (1600.0, 1400.0)},
        {"glint_depth_mm": (0.0, 1400.0)},
        {"glint_depth_mm": (float("nan"), 1400.0)},
        {"glint_depth_mm": (1400.0,)},
        {"glint_depth_mm": "near"},
        {"glint_led_color": "yes"},
        {"rim_reflections": ((0, 10.0),)},
        {"rim_reflections": ((1, float("inf")),)},
        {"rim_reflections": ((1.5, 10.0),)},
        {"rim_reflections": ((1,),)},
        {"rim_reflections": 3},
    ],
)
def test_bad_settings_raise_value_error(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError, match="RenderSettings"):
        RenderSettings(**kwargs)


def test_reflection_of_unknown_led_raises() -> None:
    s = RenderSettings(rim_reflections=((6, 10.0),))
    with pytest.raises(ValueError, match="rim_reflections"):
        render_pair(CALIB, CENTER, NORMAL, s, seed=0)
    render_pair(CALIB, CENTER, NORMAL, s, ring=LedRing(count=6), seed=0)  # 6 LEDs: fine


def test_settings_and_truth_to_dict_are_json() -> None:
    s = RenderSettings(
        glints=3, mono_glints=2, glint_depth_mm=(1300, 1700), rim_reflections=[[2, 15]], clutter=2
    )
    assert s.glint_depth_mm == (1300.0, 1700.0) and s.rim_reflections == ((2, 15.0),)
    d = json.loads(json.dumps(s.to_dict(), allow_nan=False))
    assert d["rim_reflections"] == [[2, 15.0]] and d["glint_depth_mm"] == [1300.0, 1700.0]
    assert RenderSettings(**d) == s
    t = render_pair(CALIB, CENTER, NORMAL, s, seed=0).truth
    td = json.loads(json.dumps(t.to_dict(), allow_nan=False))
    assert len(td["glint_xyz_mm"]) == 3 and len(td["glint_left_px"]) == 3
    assert td["mono_glint_left_px"][1] == [None, None]  # NaN row: not in the left image
    assert len(td["reflection_xyz_mm"]) == 1 and len(td["reflection_right_px"]) == 1
