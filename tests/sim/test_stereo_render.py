"""Stereo LED renderer: geometry, exactness of the LED image centres, clutter, CLI."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from app.cli.main import main as cli_main
from app.geometry.calibration import CameraIntrinsics, StereoCalibration, paper_calibration
from app.geometry.projection import project_stereo
from app.sim.led_ring import LedRing, normal_tilt_deg, random_pose, ring_points, tilted_normal
from app.sim.stereo_render import RenderSettings, render_pair

CALIB = paper_calibration()
QUIET = RenderSettings(noise_sigma=0.0)


def _manual_project(cam: CameraIntrinsics, xyz_cam: np.ndarray) -> np.ndarray:
    """Pinhole + radial/tangential distortion + skew written out (eqs. 2, 7), no OpenCV."""
    x = xyz_cam[:, 0] / xyz_cam[:, 2]
    y = xyz_cam[:, 1] / xyz_cam[:, 2]
    k1, k2, p1, p2, k3 = cam.dist
    r2 = x * x + y * y
    rad = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = cam.K
    return np.column_stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]])


def _centroid(img: np.ndarray, px: np.ndarray, half: int, background: float) -> np.ndarray:
    """Background-subtracted intensity-weighted centroid (eq. 11) over a square window."""
    x0, y0 = int(round(px[0])) - half, int(round(px[1])) - half
    win = img[y0 : y0 + 2 * half + 1, x0 : x0 + 2 * half + 1].astype(np.float64) - background
    ys, xs = np.mgrid[y0 : y0 + 2 * half + 1, x0 : x0 + 2 * half + 1]
    return np.array([(win * xs).sum() / win.sum(), (win * ys).sum() / win.sum()])


# ---------------------------------------------------------------- ring geometry ----------
def test_ring_points_geometry_head_on() -> None:
    ring = LedRing()
    c = np.array([10.0, -20.0, 1000.0])
    pts = ring_points(c, [0, 0, -1], ring)
    assert pts.shape == (5, 3)
    np.testing.assert_allclose(np.linalg.norm(pts - c, axis=1), 75.0, atol=1e-9)
    np.testing.assert_allclose(pts[:, 2], 1000.0, atol=1e-9)  # in the plane z = 1000
    # neighbours are one chord 2 r sin(π/5) apart
    chord = np.linalg.norm(pts - np.roll(pts, -1, axis=0), axis=1)
    np.testing.assert_allclose(chord, 2 * 75.0 * math.sin(math.pi / 5), atol=1e-9)
    # LED 1 at 36° clockwise from the top: up (−y) and to the right (+x) of the centre
    d = pts[0] - c
    np.testing.assert_allclose(
        d[:2], 75.0 * np.array([math.sin(0.2 * math.pi), -math.cos(0.2 * math.pi)])
    )
    # ids run clockwise in the image (y down): the image angle atan2(dx, -dy) increases
    ang = np.degrees(np.arctan2(pts[:, 0] - c[0], -(pts[:, 1] - c[1]))) % 360
    np.testing.assert_allclose(ang, [36, 108, 180, 252, 324], atol=1e-9)


def test_ring_points_tilted_lie_on_circle_in_plane() -> None:
    n = tilted_normal(25.0, 60.0)
    assert normal_tilt_deg(n) == pytest.approx(25.0)
    c = np.array([0.0, 30.0, 800.0])
    pts = ring_points(c, n, LedRing(radius_mm=60.0, count=7), roll_rad=0.3)
    np.testing.assert_allclose((pts - c) @ n, 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(pts - c, axis=1), 60.0, atol=1e-9)


def test_random_pose_keeps_ring_in_both_images() -> None:
    rng = np.random.default_rng(11)
    for range_mm in (600.0, 1000.0, 2500.0, 5000.0):
        for _ in range(5):
            c, n = random_pose(rng, range_mm, max_tilt_deg=20.0)
            assert abs(c[2] / range_mm - 1) <= 0.031
            assert normal_tilt_deg(n) <= 20.0 + 1e-9
            pair = render_pair(CALIB, c, n, QUIET, seed=1)
            assert pair.truth.visible.all()


# ---------------------------------------------------------------- truth pixels -----------
def test_truth_px_match_projection_and_independent_models() -> None:
    c, n = np.array([30.0, -15.0, 900.0]), tilted_normal(15.0, 200.0)
    t = render_pair(CALIB, c, n, QUIET, seed=0, roll_rad=0.2).truth
    pl, pr = project_stereo(CALIB, t.led_xyz_mm)
    np.testing.assert_allclose(t.led_left_px, pl, atol=1e-9)
    np.testing.assert_allclose(t.led_right_px, pr, atol=1e-9)
    # written-out camera model, skew included
    xyz_r = (CALIB.R @ t.led_xyz_mm.T).T + CALIB.T
    np.testing.assert_allclose(t.led_left_px, _manual_project(CALIB.left, t.led_xyz_mm), atol=1e-6)
    np.testing.assert_allclose(t.led_right_px, _manual_project(CALIB.right, xyz_r), atol=1e-6)

    # OpenCV cross-check on a copy of the rig without skew (projectPoints ignores skew)
    def no_skew(cam: CameraIntrinsics) -> CameraIntrinsics:
        K = cam.K.copy()
        K[0, 1] = 0.0
        return CameraIntrinsics(K=K, dist=cam.dist)

    flat = replace(CALIB, left=no_skew(CALIB.left), right=no_skew(CALIB.right))
    t0 = render_pair(flat, c, n, QUIET, seed=0, roll_rad=0.2).truth
    cl, _ = cv2.projectPoints(t0.led_xyz_mm, np.zeros(3), np.zeros(3), flat.left.K, flat.left.dist)
    rvec, _ = cv2.Rodrigues(flat.R)
    cr, _ = cv2.projectPoints(t0.led_xyz_mm, rvec, flat.T, flat.right.K, flat.right.dist)
    np.testing.assert_allclose(t0.led_left_px, cl.reshape(-1, 2), atol=1e-6)
    np.testing.assert_allclose(t0.led_right_px, cr.reshape(-1, 2), atol=1e-6)
    # the skew really moves the left image by γ·y_d (≈ several px): the test above can fail
    assert np.max(np.abs(t0.led_left_px[:, 0] - t.led_left_px[:, 0])) > 0.05


@pytest.mark.parametrize("range_mm", [600.0, 1000.0, 2500.0])
def test_rendered_centroid_equals_truth(range_mm: float) -> None:
    rng = np.random.default_rng(int(range_mm))
    errors = []
    for i in range(4):
        c, n = random_pose(rng, range_mm)
        pair = render_pair(CALIB, c, n, QUIET, seed=i, roll_rad=float(rng.uniform(0, 2 * np.pi)))
        t = pair.truth
        assert t.visible.all()
        for img, px, rad in (
            (pair.left, t.led_left_px, t.led_left_radius_px),
            (pair.right, t.led_right_px, t.led_right_radius_px),
        ):
            half = int(math.ceil(np.max(rad))) + 5
            for k in range(len(px)):
                errors.append(_centroid(img, px[k], half, QUIET.background) - px[k])
    err = np.array(errors)
    assert np.max(np.abs(err)) < 0.02
    assert np.all(np.abs(err.mean(axis=0)) < 0.01)  # no systematic bias


def test_far_led_is_still_a_visible_blob() -> None:
    pair = render_pair(CALIB, [-120.0, 0.0, 5000.0], [0, 0, -1], QUIET, seed=0)
    t = pair.truth
    assert t.visible.all()
    assert np.all(t.led_left_radius_px < 1.5)  # disc ≈ 2.4 px wide
    for px in t.led_left_px:
        u, v = int(round(px[0])), int(round(px[1]))
        assert pair.left[v - 1 : v + 2, u - 1 : u + 2].max() > QUIET.background + 100


# ---------------------------------------------------------------- noise / determinism ----
def test_deterministic_under_seed() -> None:
    s = RenderSettings(clutter=6, second_object=True)
    a = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], s, seed=7)
    b = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], s, seed=7)
    c = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], s, seed=8)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    np.testing.assert_array_equal(a.truth.clutter_left_px, b.truth.clutter_left_px)
    assert not np.array_equal(a.left, c.left)
    d = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], seed=None)
    e = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], seed=None)
    assert not np.array_equal(d.left, e.left)


@pytest.mark.parametrize("fast", [False, True])
def test_background_noise_statistics(fast: bool) -> None:
    s = RenderSettings(fast_noise=fast)
    pair = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], s, seed=3)
    for img in (pair.left, pair.right):
        corner = img[:300, :300].astype(np.float64)  # no LED there
        assert abs(corner.mean() - s.background) < 0.1
        assert abs(corner.std() - s.noise_sigma) < 0.15
    assert not np.array_equal(pair.left[:300, :300], pair.right[:300, :300])
    again = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], s, seed=3)
    assert np.array_equal(pair.left, again.left)


def test_fast_noise_keeps_led_centres() -> None:
    s = RenderSettings(fast_noise=True, noise_sigma=0.0)
    pair = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], s, seed=3)
    t = pair.truth
    for k in range(5):
        err = _centroid(pair.left, t.led_left_px[k], 12, s.background) - t.led_left_px[k]
        assert np.max(np.abs(err)) < 0.02


def test_color_images_have_green_leds() -> None:
    pair = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], RenderSettings(color=True), seed=0)
    assert pair.left.shape == (1024, 1280, 3) and pair.left.dtype == np.uint8
    for px in pair.truth.led_left_px:
        b, g, r = pair.left[int(round(px[1])), int(round(px[0]))].astype(int)
        assert g > 200 and g > b + 60 and g > r + 60


# ---------------------------------------------------------------- clutter / occlusion ----
def test_clutter_stays_outside_the_ring() -> None:
    for seed in range(4):
        s = RenderSettings(clutter=12, second_object=True, noise_sigma=0.0)
        pair = render_pair(CALIB, [20, 0, 1000], tilted_normal(10, 45 * seed), s, seed=seed)
        t = pair.truth
        assert t.clutter_left_px.shape == (12, 2) and t.clutter_right_px.shape == (12, 2)
        cl, cr = project_stereo(CALIB, t.center_mm[None, :])
        for img, clutter, leds, centre in (
            (pair.left, t.clutter_left_px, t.led_left_px, cl[0]),
            (pair.right, t.clutter_right_px, t.led_right_px, cr[0]),
        ):
            ring_r = np.max(np.linalg.norm(leds - centre, axis=1))
            items = clutter[np.all(np.isfinite(clutter), axis=1)]
            if t.second_object_left_px is not None:
                items = np.vstack(
                    [
                        items,
                        t.second_object_left_px if img is pair.left else t.second_object_right_px,
                    ]
                )
            assert len(items) >= 4
            d_centre = np.linalg.norm(items - centre, axis=1)
            assert np.all(d_centre > 1.4 * ring_r + 10.0)
            d_led = np.linalg.norm(items[:, None, :] - leds[None, :, :], axis=2)
            assert np.all(d_led > 15.0)
            for p in items:  # every listed item is really drawn, as bright as an LED
                u, v = int(round(p[0])), int(round(p[1]))
                assert img[v, u] > s.background + 100
        # LED centroids unaffected by the clutter
        for k in range(5):
            err = _centroid(pair.left, t.led_left_px[k], 12, s.background) - t.led_left_px[k]
            assert np.max(np.abs(err)) < 0.02


def test_occluded_leds_absent_and_not_visible() -> None:
    s = RenderSettings(occluded=(2, 4), noise_sigma=0.0)
    pair = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], s, seed=0)
    t = pair.truth
    np.testing.assert_array_equal(t.visible, [True, False, True, False, True])
    for img, pxs in ((pair.left, t.led_left_px), (pair.right, t.led_right_px)):
        for k, px in enumerate(pxs):
            u, v = int(round(px[0])), int(round(px[1]))
            peak = img[v - 8 : v + 9, u - 8 : u + 9].max()
            if t.led_ids[k] in (2, 4):
                assert peak <= s.background
            else:
                assert peak > s.background + 150


def test_partly_out_of_view_does_not_raise() -> None:
    pair = render_pair(CALIB, [200.0, 0.0, 1000.0], [0, 0, -1], seed=0)
    t = pair.truth
    assert 0 < t.visible.sum() < 5
    assert t.in_right.all() and not t.in_left.all()
    for k in np.flatnonzero(~t.in_left):  # not drawn: its projection is off the image
        u = t.led_left_px[k, 0]
        assert u < 0 or u > 1279
    behind = render_pair(CALIB, [0.0, 0.0, -500.0], [0, 0, -1], seed=0)
    assert not behind.truth.visible.any()
    assert behind.left.max() < 40  # background + noise only


@pytest.mark.parametrize(
    ("center", "normal", "kwargs"),
    [
        ([0, 0, float("nan")], [0, 0, -1], {}),
        ([0, 0, 1000], [0, 0, 0], {}),
        ([0, 0, 1000], [0, float("inf"), -1], {}),
        ([0, 0], [0, 0, -1], {}),
        ([0, 0, 1000], [0, 0, -1], {"settings": RenderSettings(occluded=(6,))}),
        ([0, 0, 1000], [0, 0, -1], {"roll_rad": float("nan")}),
    ],
)
def test_invalid_inputs_raise_value_error(center, normal, kwargs) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError):
        render_pair(CALIB, center, normal, **kwargs)


def test_invalid_settings_raise_value_error() -> None:
    with pytest.raises(ValueError):
        RenderSettings(supersample=0)
    with pytest.raises(ValueError):
        RenderSettings(noise_sigma=-1.0)
    with pytest.raises(ValueError):
        LedRing(radius_mm=0.0)


def test_truth_to_dict_is_json() -> None:
    s = RenderSettings(clutter=4)
    t = render_pair(CALIB, [20, 0, 1000], [0, 0, -1], s, seed=0).truth
    d = json.loads(json.dumps(t.to_dict(), allow_nan=False))
    assert len(d["led_xyz_mm"]) == 5 and d["led_ids"] == [1, 2, 3, 4, 5]
    assert len(d["clutter_left_px"]) == 4


# ---------------------------------------------------------------- CLI --------------------
def test_cli_writes_three_files(tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "pair"
    code = cli_main(
        ["render", "--range-mm", "1000", "--seed", "3", "--occlude", "2", "--out", str(out)]
    )
    assert code == 0
    left = cv2.imread(str(out / "left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(out / "right.png"), cv2.IMREAD_UNCHANGED)
    assert left.shape == (1024, 1280) and right.shape == (1024, 1280)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["seed"] == 3 and truth["settings"]["occluded"] == [2]
    assert truth["visible"] == [True, False, True, True, True]
    assert truth["center_mm"][2] == pytest.approx(1000.0)
    # the written truth pixels are where the LEDs are in the written images
    for px in np.array(truth["led_left_px"])[[0, 2, 3, 4]]:
        assert left[int(round(px[1])), int(round(px[0]))] > 150


def test_cli_bad_calibration_exits_2(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    bad = tmp_path / "calib.json"
    bad.write_text(json.dumps({"image_size": [1280, 1024]}))
    code = cli_main(
        ["render", "--range-mm", "1000", "--calib", str(bad), "--out", str(tmp_path / "o")]
    )
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "calibration field" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()
    assert cli_main(["render", "--range-mm", "-5", "--out", str(tmp_path / "o")]) == 2
    assert (
        cli_main(["render", "--range-mm", "1000", "--occlude", "a,b", "--out", str(tmp_path / "o")])
        == 2
    )


def test_calibration_roundtrip_used_by_cli_is_the_paper_rig() -> None:
    from app.resources import load_default_calibration

    c = load_default_calibration()
    assert isinstance(c, StereoCalibration)
    np.testing.assert_allclose(c.left.K, CALIB.left.K)
    np.testing.assert_allclose(c.T, CALIB.T)
