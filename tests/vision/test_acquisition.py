"""Lean full-frame acquisition: blobs found only around the bright pixels (``detect_blobs``)
equal the reference full-frame chain (threshold → median → label → eq. 11) bit for bit."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.vision.bright_region_kernels import hot_tile_boxes
from app.vision.features import (
    BAND_ROWS,
    BlobGate,
    TooManyBlobs,
    band_maxima,
    bright_boxes,
    detect_blobs,
    extract_blobs,
)
from app.vision.preprocess import background_level, binarize, choose_threshold, median_filter
from tests.support.blob_scenes import blob_scene
from tests.support.bright_region_reference import hot_tile_boxes_reference


def _reference(img: np.ndarray, thr: int, bg: float, gate: BlobGate, ksize: int = 3):  # type: ignore[no-untyped-def]
    return extract_blobs(img, median_filter(binarize(img, thr), ksize), bg, gate)


def _key(blobs):  # type: ignore[no-untyped-def]
    return sorted(
        (b.bbox, round(b.centroid_px[0], 9), round(b.centroid_px[1], 9), b.area_px, b.peak, b.mass)
        for b in blobs
    )


@pytest.mark.parametrize("n", [0, 1, 5, 40, 300])
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("ksize", [3, 1, 5])
def test_detect_blobs_equals_the_full_frame_chain(n: int, seed: int, ksize: int) -> None:
    """The compiled box-by-box median (counts over the window, the box edge replicated)
    equals ``cv2.medianBlur`` on the whole frame, for every median size the config allows."""
    img = blob_scene(seed * 1000 + n, n)
    stats = background_level(img)
    thr = choose_threshold(img, "auto", stats)
    gate = BlobGate()
    ref, ref_rej = _reference(img, thr, stats[0], gate, ksize)
    got, got_rej = detect_blobs(img, thr, stats[0], gate, median_ksize=ksize)
    assert _key(got) == _key(ref)
    assert sorted((r.centroid_px, r.reason) for r in got_rej) == sorted(
        (r.centroid_px, r.reason) for r in ref_rej
    )
    if n >= 5:
        assert len(ref) > 0  # the scene has candidates at all (the test can fail)


def test_bright_boxes_hold_every_bright_pixel() -> None:
    img = blob_scene(7, 60)
    thr = 120
    boxes = bright_boxes(img, thr)
    covered = np.zeros(img.shape, bool)
    for x0, y0, x1, y1 in boxes:
        covered[y0:y1, x0:x1] = True
    assert np.all(covered[img >= thr])
    assert covered.mean() < 0.25  # and not the whole frame


@pytest.mark.parametrize("seed", range(6))
def test_hot_tile_boxes_equal_the_reference(seed: int) -> None:
    """The tile scan (a SIMD count per band row, tiles only on rows that reach the threshold)
    gives the boxes of the plain formulation (tile maxima, scipy's 8-connected labels), at
    every threshold from below the background to above 255 and at odd image sizes."""
    rng = np.random.default_rng(seed)
    checked = 0
    for _ in range(40):
        h, w = int(rng.integers(17, 160)), int(rng.integers(17, 220))
        img = rng.integers(0, 40, (h, w)).astype(np.uint8)
        for _ in range(int(rng.integers(0, 10))):
            y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
            img[y : y + int(rng.integers(1, 9)), x : x + int(rng.integers(1, 9))] = rng.integers(
                0, 256
            )
        bands = np.ascontiguousarray(band_maxima(img))
        for thr in (-5, 0, 1, 39, 40, 100, 200, 255, 256, 400, int(rng.integers(0, 256))):
            got = hot_tile_boxes(img, bands, BAND_ROWS, thr)
            want = hot_tile_boxes_reference(img, bands, BAND_ROWS, thr)
            np.testing.assert_array_equal(got, want)
            checked += len(want)
    assert checked > 100  # boxes were found (the comparison is not of empty lists)


def test_too_many_blobs_is_refused_as_before() -> None:
    img = np.full((400, 400), 10, np.uint8)
    for y in range(10, 390, 12):
        for x in range(10, 390, 12):
            cv2.circle(img, (x, y), 3, 250, -1)
    gate = BlobGate(max_blobs=100)
    with pytest.raises(TooManyBlobs):
        detect_blobs(img, 100, 10.0, gate)
    with pytest.raises(TooManyBlobs):
        _reference(img, 100, 10.0, gate)


def test_a_blob_whose_local_centroid_fails_keeps_eq11() -> None:
    """An LED on a bright stripe below the threshold (a sunlit rim edge through it): every
    support level the local centroid tries runs along the stripe to its window's edge, so it
    is not measured (σ NaN) and the acquisition computes eq. 11 for that blob (its centroid
    and mass as without the local centroid), while the LED beside it gets its local centroid
    and no eq. 11 (mass NaN)."""
    import math

    from app.vision.local_centroid import LocalCentroidConfig, refine_blobs

    img = np.full((200, 300), 12, np.uint8)
    img[97:104, :] = 225
    cv2.circle(img, (150, 100), 5, 250, -1)  # on the stripe
    cv2.circle(img, (60, 40), 4, 250, -1)  # on the dark background
    eq11, _ = detect_blobs(img, 230, 12.0, BlobGate())
    for cfg in (LocalCentroidConfig(), LocalCentroidConfig(support_frac=0.5)):
        got, _ = detect_blobs(img, 230, 12.0, BlobGate(), centroid=cfg)
        want = refine_blobs(img, eq11, cfg)
        assert [b.bbox for b in got] == [(57, 37, 7, 7), (146, 96, 9, 9)]
        free, on_stripe = got
        assert free.centroid_px == want[0].centroid_px and math.isnan(free.mass)
        assert not math.isnan((free.centroid_sigma_px or (math.nan,))[0])
        assert on_stripe.centroid_px == eq11[1].centroid_px == want[1].centroid_px
        assert on_stripe.mass == eq11[1].mass > 0
        assert all(math.isnan(v) for v in on_stripe.centroid_sigma_px or ())
        assert on_stripe.centroid_sigma_px is not None


@pytest.mark.parametrize("n", [0, 5, 40, 300])
def test_blobs_built_with_local_centroids_equal_refined_eq11_blobs(n: int) -> None:
    """``detect_blobs(..., centroid=cfg)`` builds each blob once with its local-support
    centroid: the same records as refining the eq. 11 blobs afterwards (``refine_blobs``,
    the reference), field for field, except eq. 11's ``mass``, which is computed only where
    the local centroid is not measured (NaN elsewhere); disabled, the eq. 11 blobs as they
    are."""
    import math

    from app.vision.local_centroid import LocalCentroidConfig, refine_blobs

    img = blob_scene(7000 + n, n)
    stats = background_level(img)
    thr = choose_threshold(img, "auto", stats)
    gate = BlobGate()
    eq11, rej = detect_blobs(img, thr, stats[0], gate)
    for cfg in (LocalCentroidConfig(), LocalCentroidConfig(support_frac=0.5), None):
        got, got_rej = detect_blobs(img, thr, stats[0], gate, centroid=cfg)
        want = eq11 if cfg is None else refine_blobs(img, eq11, cfg)
        assert got_rej == rej and len(got) == len(want)
        for a, b in zip(got, want, strict=True):
            for f in ("centroid_px", "area_px", "bbox", "peak", "color_bgr", "local_bg"):
                assert getattr(a, f) == getattr(b, f), f
            sa, sb = a.centroid_sigma_px, b.centroid_sigma_px
            measured = sa is not None and not math.isnan(sa[0])
            assert math.isnan(a.mass) if measured else a.mass == b.mass
            assert (sa is None) == (sb is None)
            if sa is not None and sb is not None:  # (NaN: not measured, in both)
                assert all(
                    x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(sa, sb, strict=True)
                )
    got, _ = detect_blobs(img, thr, stats[0], gate, centroid=LocalCentroidConfig(enabled=False))
    assert got == eq11
    if n >= 5:  # the local centroids are measured (the test can fail)
        measured, _ = detect_blobs(img, thr, stats[0], gate, centroid=LocalCentroidConfig())
        assert any(not math.isnan((b.centroid_sigma_px or (0.0,))[0]) for b in measured)
