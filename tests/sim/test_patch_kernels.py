"""The renderer's compiled patch kernels: the same bits as the former NumPy formulation
(tests/support/reference_blob_patches.py, on which the quoted campaigns were flown), NumPy's own
mean, and the physics of a disc (its area, its centroid on the truth pixel); the one-call
projection of the LED spheres against the separate ones."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.geometry.calibration import paper_calibration
from app.geometry.projection import project_stereo
from app.sim.stereo_render.blobs import LightSpot, blob_patches, project_spheres, sphere_shapes
from app.sim.stereo_render.patch_kernels import _pairwise_mean, paste_patch, spot_patch
from tests.support.reference_blob_patches import reference_blob_patches, reference_paste


def _random_spots(rng: np.random.Generator, count: int) -> list[LightSpot]:
    spots = []
    for _ in range(count):
        r = rng.uniform(0.6, 14.0)
        shape = np.array(
            [[r * (1 + rng.normal(0, 0.08)), rng.normal(0, 0.3)], [rng.normal(0, 0.3), r]]
        )
        centre = rng.uniform(-30.0, 700.0, 2)
        peak = float(rng.choice([235.0, 120.5, 61.3]))
        spots.append(LightSpot(centre, shape, peak, np.ones(3, np.float32)))
    return spots


@pytest.mark.parametrize("n", [1, 5, 7, 8, 9, 16, 17, 64, 100, 128])
def test_pairwise_mean_is_numpys_mean_bit_for_bit(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(200):
        v = rng.uniform(0.0, 1.0, n) * 10.0 ** rng.integers(-3, 4, n)
        assert _pairwise_mean(v, n) == v.mean()


@pytest.mark.parametrize(("supersample", "blur"), [(4, 0.7), (8, 0.7), (4, 0.0), (3, 1.3)])
def test_patches_equal_the_former_numpy_formulation(supersample: int, blur: float) -> None:
    rng = np.random.default_rng(supersample * 10 + int(10 * blur))
    for _ in range(40):
        spots = _random_spots(rng, int(rng.integers(1, 12)))
        new = blob_patches(spots, supersample, blur)
        ref = reference_blob_patches(spots, supersample, blur)
        assert len(new) == len(ref) == len(spots)
        for (x0, y0, p), (rx0, ry0, rp) in zip(new, ref, strict=True):
            assert (x0, y0) == (rx0, ry0)
            assert p.dtype == rp.dtype == np.float32
            assert np.array_equal(p, rp)


def test_a_patch_does_not_depend_on_the_other_blobs() -> None:
    spots = _random_spots(np.random.default_rng(3), 9)
    together = blob_patches(spots, 4, 0.7)
    for k, spot in enumerate(spots):
        alone = blob_patches([spot], 4, 0.7)[0]
        assert alone[:2] == together[k][:2]
        assert np.array_equal(alone[2], together[k][2])


@pytest.mark.parametrize("radius_px", [1.5, 4.0, 9.25])
def test_a_disc_has_its_area_and_its_centroid_on_the_centre(radius_px: float) -> None:
    # independent of the implementation: coverage integrates to π r² (the anti-aliased edge
    # is one sub-sample wide), the blur keeps the total, and the symmetric patch's
    # intensity-weighted centroid (eq. 11) is the projected centre (to 0.02 px: pixel
    # sampling biases a 1.5 px disc by ≈ 0.01 px)
    cx, cy = 40.3, 27.8
    shape = np.eye(2) * radius_px
    for taps in (np.zeros(0), np.array([0.25, 0.5, 0.25])):
        reach = (len(taps) - 1) // 2 if len(taps) else 0
        x0, y0, p = spot_patch(shape, np.linalg.inv(shape), cx, cy, reach, 16, 1.0, taps)
        assert p.shape == (2 * (math.ceil(radius_px) + 2 + reach) + 1,) * 2
        area = float(p.astype(np.float64).sum())
        assert area == pytest.approx(math.pi * radius_px**2, rel=0.01)
        ys, xs = np.mgrid[0 : p.shape[0], 0 : p.shape[1]]
        assert float((p * (xs + x0)).sum()) / area == pytest.approx(cx, abs=0.02)
        assert float((p * (ys + y0)).sum()) / area == pytest.approx(cy, abs=0.02)


@pytest.mark.parametrize("colour", [False, True])
def test_paste_equals_the_former_compositing(colour: bool) -> None:
    rng = np.random.default_rng(11 + colour)
    shape = (120, 160, 3) if colour else (120, 160)
    bgr = np.array([0.45, 1.0, 0.3], dtype=np.float32)
    grey = np.ones(1, dtype=np.float32)
    for _ in range(60):
        base = rng.integers(0, 256, shape, dtype=np.uint8)
        ref = base.copy()
        patch = rng.uniform(-40.0, 300.0, tuple(rng.integers(3, 40, 2))).astype(np.float32)
        x0, y0 = (int(v) for v in rng.integers(-30, 170, 2))
        rects: list[tuple[int, int, int, int]] | None = None
        if rng.integers(3):
            rects = []
            for _ in range(int(rng.integers(1, 4))):
                a, b = (int(v) for v in rng.integers(0, 150, 2))
                rects.append((a, b, min(a + int(rng.integers(1, 60)), 160), min(b + 30, 120)))
        boxes = np.array(rects or [], dtype=np.int64).reshape(-1, 4)
        canvas = base.reshape(shape[0], shape[1], -1)
        paste_patch(canvas, x0, y0, patch, bgr if colour else grey, boxes, rects is None)
        reference_paste(ref, x0, y0, patch, bgr if colour else None, rects)
        assert np.array_equal(base, ref)


def test_one_projection_of_centres_and_ellipses_agrees_with_two() -> None:
    # project_spheres (one projectPoints call per camera) against the centres projected on
    # their own and the ellipses from sphere_shapes; NaN for spheres behind the camera
    calib = paper_calibration()
    rng = np.random.default_rng(5)
    xyz = np.column_stack(
        [rng.uniform(-800, 800, 12), rng.uniform(-600, 600, 12), rng.uniform(400, 9000, 12)]
    )
    xyz[3, 2] = -50.0  # behind
    xyz[7, 2] = 0.5  # within 1 mm of the camera
    radius = rng.uniform(5.0, 15.0, 12)
    got = project_spheres(calib.left, xyz, radius)
    front = xyz[:, 2] >= 1.0
    assert np.isnan(got.center_px[~front]).all() and np.isnan(got.shape_px[~front]).all()
    ref_px = project_stereo(calib, xyz[front])[0]
    ref_shape = sphere_shapes(calib.left, xyz[front], radius[front])
    np.testing.assert_allclose(got.center_px[front], ref_px, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.shape_px[front], ref_shape, rtol=1e-9, atol=1e-12)
    # and the ellipse is the sphere's disc: its radius ≈ f·r/Z
    det = np.abs(np.linalg.det(got.shape_px[front])) ** 0.5
    np.testing.assert_allclose(det, calib.left.fx * radius[front] / xyz[front, 2], rtol=0.05)


def test_warmup_compiles_the_renderers_loops() -> None:
    """After ``app.sim.warmup``, the closed loop's renders (fast noise, windows or whole, grey
    or colour, with clutter and glints) and the full-noise renders compile nothing more."""
    from app.resources import load_default_calibration
    from app.sim import warmup
    from app.sim.led_ring import LedRing, stereo_center_x_mm, tilted_normal
    from app.sim.stereo_render import RenderSettings, render_pair
    from app.sim.stereo_render import patch_kernels as pk

    loops = [pk.render_spots, pk.spot_patch, pk.paste_patch, pk.spectral_norm_2x2]
    warmup.compile_kernels()
    prepared = {loop.__name__: len(loop.signatures) for loop in loops}
    assert prepared["render_spots"] >= 1 and prepared["spot_patch"] >= 1, prepared
    calib = load_default_calibration()
    w, h = calib.image_size
    for k, (color, fast, windows) in enumerate(
        [(False, True, True), (True, True, True), (False, True, False), (True, False, False)]
    ):
        z = 4000.0 if k % 2 else 1200.0
        wins = ([(0, 0, w // 2, h)], [(w // 3, 0, w, h // 2)]) if windows else None
        render_pair(
            calib,
            np.array([stereo_center_x_mm(calib, z), 10.0, z]),
            tilted_normal(8.0, 40.0),
            RenderSettings(color=color, fast_noise=fast, clutter=4, glints=2),
            ring=LedRing(radius_mm=305.0 if k % 2 else 75.0),
            seed=k,
            windows=wins,
        )
    assert {loop.__name__: len(loop.signatures) for loop in loops} == prepared
