"""app.vision.local_centroid on synthetic blobs with a known centre (independent of the
pipeline): a Gaussian LED beside a dimmer reflection, and the blob records it returns."""

from __future__ import annotations

import dataclasses

import numpy as np

from app.vision.local_centroid import (
    LocalCentroidConfig,
    measure_blobs,
    read_rects,
    with_local_centroids,
)
from app.vision.types import Blob


def _scene(centre=(40.3, 30.7), reflection_dx=7.0, bg=20.0, peak=200.0, sigma=1.6):
    y, x = np.mgrid[0:64, 0:80].astype(np.float64)
    img = bg + peak * np.exp(-((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (2 * sigma**2))
    # the LED's own reflection on a polished rim: dimmer, a dark gap away
    rx = centre[0] + reflection_dx
    img += 0.15 * peak * np.exp(-((x - rx) ** 2 + (y - centre[1]) ** 2) / (2 * 1.2**2))
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def test_local_centroid_finds_the_led_centre_beside_its_reflection():
    gray = _scene()
    blob = Blob((40.0, 31.0), 21, (37, 28, 7, 7), 220.0, 1000.0)
    table = measure_blobs(gray, [blob], LocalCentroidConfig())
    (out,) = with_local_centroids([blob], table)
    assert np.hypot(out.centroid_px[0] - 40.3, out.centroid_px[1] - 30.7) < 0.03
    su, sv = out.centroid_sigma_px
    assert 0.02 < su < 0.2 and 0.02 < sv < 0.2  # σ: the 0.03 px floor plus pixel noise
    # the sensor model's share kept apart: at most the σ, which the image's own noise may raise
    mu, mv = out.model_sigma_px
    assert 0.02 < mu <= su and 0.02 < mv <= sv
    (sensor,) = with_local_centroids(
        [blob], measure_blobs(gray, [blob], LocalCentroidConfig(image_noise=False))
    )
    assert sensor.centroid_sigma_px == sensor.model_sigma_px == out.model_sigma_px
    assert abs(out.local_bg - 20.0) <= 1.0


def test_with_local_centroids_keeps_every_other_field():
    gray = _scene()
    blob = Blob((40.0, 31.0), 21, (37, 28, 7, 7), 220.0, 1000.0, color_bgr=(10.0, 200.0, 12.0))
    flat = np.zeros_like(gray)  # no contrast: not measured, eq. 11's centroid kept, σ NaN
    for image in (gray, flat):
        (out,) = with_local_centroids([blob], measure_blobs(image, [blob], LocalCentroidConfig()))
        changed = {"centroid_px", "centroid_sigma_px", "local_bg", "model_sigma_px"}
        for f in dataclasses.fields(Blob):
            if f.name not in changed:
                assert getattr(out, f.name) == getattr(blob, f.name), f.name
    assert out.centroid_px == blob.centroid_px and np.isnan(out.centroid_sigma_px[0])


def test_ring_median_from_counts_equals_numpy_median():
    """The background ring's median from a 256-bin count equals ``np.median`` of the ring
    (the reference, ``tests/support/local_centroid_reference.py``): odd and even counts, clipped at every image edge,
    constant and two-valued rings; the counts are left zero for the next blob."""
    from app.vision.local_centroid_kernels import ring_median_counts
    from tests.support.local_centroid_reference import ring_median

    rng = np.random.default_rng(4)
    counts = np.zeros(256, np.int64)
    images = [
        rng.integers(0, 256, (40, 50), dtype=np.uint8),
        np.full((40, 50), 17, np.uint8),
        (rng.random((40, 50)) < 0.5).astype(np.uint8) * 200,
        rng.integers(30, 34, (40, 50), dtype=np.uint8),
    ]
    for img in images:
        for _ in range(200):
            x0, y0 = int(rng.integers(-3, 50)), int(rng.integers(-3, 40))
            x1, y1 = x0 + int(rng.integers(1, 20)), y0 + int(rng.integers(1, 20))
            want = ring_median(img, x0, y0, x1, y1)
            got = ring_median_counts(img, x0, y0, x1, y1, counts)
            assert got == want or (np.isnan(got) and np.isnan(want))
            assert not counts.any()
    # a window covering the whole image: no ring pixel, NaN
    assert np.isnan(ring_median_counts(images[0], 0, 0, 50, 40, counts))


def test_the_read_rectangles_hold_every_pixel_the_centroids_read() -> None:
    """:func:`read_rects` holds every pixel the local centroids read (their widest window):
    an image equal to the real one there and garbage elsewhere measures the blobs exactly as
    the real one does (the colour pipeline converts only these rectangles to eq. 9's gray)."""
    rng = np.random.default_rng(4)
    img = rng.normal(60.0, 3.0, (300, 400))
    yy, xx = np.mgrid[0:300, 0:400]
    blobs = []
    for cx, cy, amp, r in [
        (30.2, 40.7, 150.0, 2.0),
        (200.6, 150.3, 90.0, 4.0),
        (388.4, 290.1, 120.0, 3.0),
    ]:
        img += amp * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * r * r))
        x0, y0 = int(cx - 2 * r), int(cy - 2 * r)
        blobs.append(Blob((cx, cy), 9, (x0, y0, int(4 * r) + 1, int(4 * r) + 1), amp, 1.0))
    # a brighter glint beside the middle LED, inside its window
    img += 200.0 * np.exp(-((xx - 209.0) ** 2 + (yy - 150.0) ** 2) / 8.0)
    gray = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    cfg = LocalCentroidConfig()
    whole = measure_blobs(gray, blobs, cfg)
    assert np.isfinite(whole[:, 0]).all()  # all measured, the one by the corner too
    for fill in (0, 255):
        lit = np.full_like(gray, fill)
        for x0, y0, x1, y1 in read_rects(blobs, 400, 300):
            lit[y0:y1, x0:x1] = gray[y0:y1, x0:x1]
        np.testing.assert_array_equal(measure_blobs(lit, blobs, cfg), whole)
        assert np.count_nonzero(lit != fill) < 0.2 * gray.size
