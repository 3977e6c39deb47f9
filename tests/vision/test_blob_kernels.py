"""The compiled eq. 11 centroids and label statistics equal an OpenCV-only formulation
(``connectedComponentsWithStats``, ``dilate``, ``moments``, ``minMaxLoc``) on OpenCV-drawn
scenes: the project's compiled loops are checked against code they do not share."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from app.vision.blob_kernels import label_runs, mask_runs
from app.vision.features import BlobGate, extract_blobs
from app.vision.preprocess import background_level, binarize, choose_threshold, median_filter
from tests.support.blob_scenes import blob_scene


def _opencv_blobs(gray: np.ndarray, mask: np.ndarray, bg: float, gate: BlobGate):  # type: ignore[no-untyped-def]
    """Eq. 11 with stock OpenCV calls only, one component at a time (the reference)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    h_img, w_img = gray.shape
    out = []
    for i in range(1, n):
        x, y, w, h, area = (int(v) for v in stats[i])
        aspect = max(w, h) / max(1, min(w, h))
        border = x == 0 or y == 0 or x + w >= w_img or y + h >= h_img
        if (
            area < gate.min_area_px
            or area > gate.max_area_px
            or aspect > gate.max_aspect
            or area / (w * h) < gate.min_fill
            or border
        ):
            continue
        pad = max(2, int(round(0.5 * math.sqrt(area))))
        x0, y0 = max(0, x - pad), max(0, y - pad)
        x1, y1 = min(w_img, x + w + pad), min(h_img, y + h + pad)
        lab = labels[y0:y1, x0:x1]
        comp = (lab == i).astype(np.uint8)
        support = cv2.dilate(comp, np.ones((2 * pad + 1, 2 * pad + 1), np.uint8))
        support[(lab != 0) & (comp == 0)] = 0
        window = gray[y0:y1, x0:x1].astype(np.float64)
        weights = np.clip(window - bg, 0.0, None) * support
        mom = cv2.moments(weights)
        peak = cv2.minMaxLoc(gray[y0:y1, x0:x1], comp)[1]
        u = mom["m10"] / mom["m00"] + x0
        v = mom["m01"] / mom["m00"] + y0
        out.append(((x, y, w, h), area, u, v, mom["m00"], float(peak)))
    return sorted(out)


@pytest.mark.parametrize("n", [1, 40, 300])
@pytest.mark.parametrize("bg_offset", [0.0, 0.37])
def test_compiled_centroids_equal_opencv_moments(n: int, bg_offset: float) -> None:
    img = blob_scene(7 * n + 1, n)
    stats = background_level(img)
    thr = choose_threshold(img, "auto", stats)
    bg = float(round(stats[0])) + bg_offset  # integer and fractional background levels
    mask = median_filter(binarize(img, thr), 3)
    gate = BlobGate()
    got, _ = extract_blobs(img, mask, bg, gate)
    ref = _opencv_blobs(img, mask, bg, gate)
    assert len(ref) > 0 and len(got) == len(ref)
    got_rows = sorted((b.bbox, b.area_px, *b.centroid_px, b.mass, b.peak) for b in got)
    for g, r in zip(got_rows, ref, strict=True):
        assert g[0] == r[0] and g[1] == r[1] and g[5] == r[5]
        # centroids: the same sums in float64 (summation order differs: ≤ 1e-9 px)
        assert abs(g[2] - r[2]) < 1e-9 and abs(g[3] - r[3]) < 1e-9
        assert abs(g[4] - r[4]) <= 1e-12 * r[4]


def _label_with_stats(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """The compiled labelling as OpenCV returns it: (n, int32 labels, (n, 5) stats)."""
    labels = np.zeros(mask.shape, np.int32)
    runs = mask_runs(mask)
    if len(runs) == 0:
        return 1, labels, np.zeros((1, 5), np.int64)
    stats = label_runs(runs, labels)
    return len(stats), labels, stats


@pytest.mark.parametrize("density", [0.2, 0.45, 0.6])
def test_run_labelling_equals_opencv_on_random_masks(density: float) -> None:
    """Random binary masks (diagonal-only contacts, U-shapes that merge two labels on a later
    row, runs touching the image border): the run-based union–find gives OpenCV's
    components and stats."""
    rng = np.random.default_rng(int(density * 100))
    for shape in [(64, 80), (37, 129), (200, 8)]:
        mask = (rng.random(shape) < density).astype(np.uint8) * 255
        n_ref, lab_ref, st_ref, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        n_got, lab_got, st_got = _label_with_stats(mask)
        assert n_got == n_ref
        fg = lab_got > 0
        assert np.array_equal(fg, lab_ref > 0)
        pairs = np.unique(np.stack([lab_got[fg], lab_ref[fg]]), axis=1)
        assert pairs.shape[1] == n_ref - 1  # one to one
        assert np.array_equal(st_got[pairs[0]], st_ref[pairs[1]].astype(np.int64))
        # numbered in raster order of each component's first pixel
        first = [np.flatnonzero(lab_got.ravel() == k)[0] for k in range(1, n_got)]
        assert first == sorted(first)


@pytest.mark.parametrize("n", [0, 1, 40, 300])
def test_labelling_equals_opencv_connected_components(n: int) -> None:
    """Algorithm 2 by union–find over the foreground: the same components (the label images
    equal up to a renumbering: OpenCV's parallel labelling numbers them its own way) and the
    same stats as ``cv2.connectedComponentsWithStats``."""
    img = blob_scene(11 * n + 3, n)
    stats = background_level(img)
    mask = median_filter(binarize(img, choose_threshold(img, "auto", stats)), 3)
    mask[::97, :] = 255  # long lines and a comb: components spanning many rows and merges
    mask[:, ::131] = 255
    n_ref, lab_ref, st_ref, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    n_got, lab_got, st_got = _label_with_stats(mask)
    assert n_got == n_ref
    assert np.array_equal(lab_got > 0, lab_ref > 0)
    fg = lab_got > 0
    pairs = np.unique(np.stack([lab_got[fg], lab_ref[fg]]), axis=1)
    assert pairs.shape[1] == n_ref - 1  # one to one
    assert len(np.unique(pairs[0])) == len(np.unique(pairs[1])) == n_ref - 1
    assert np.array_equal(st_got[pairs[0]], st_ref[pairs[1]].astype(np.int64))


def test_compiled_ihwt_equals_the_integral_image_formulation() -> None:
    """Eqs. 12–13: descriptors from per-point integral images (compiled) equal those from the
    whole frame's ``cv2.integral`` (the paper's formulation), also where the templates are
    clipped at the image border."""
    from app.vision.ihwt import describe, integral_image
    from app.vision.types import Blob

    img = blob_scene(5, 60, (240, 320))
    rng = np.random.default_rng(1)
    blobs = [
        Blob(
            centroid_px=(float(u), float(v)), area_px=int(a), bbox=(0, 0, 1, 1), peak=0.0, mass=1.0
        )
        for u, v, a in zip(
            rng.uniform(-3, 323, 200),
            rng.uniform(-3, 243, 200),
            rng.integers(1, 900, 200),
            strict=True,
        )
    ]
    got = describe(img, blobs)
    ref = describe(img, blobs, ii=integral_image(img))
    assert got.shape == (200, 64)
    assert np.max(np.abs(got - ref)) < 1e-12
    assert np.all(np.abs(np.linalg.norm(ref, axis=1) - 1.0) < 1e-9)  # not flat: can fail


def test_warmup_compiles_everything_frames_need() -> None:
    """Gray, colour, H×W×1 and strided inputs, full frames and tracked windows all reach the
    compiled loops with argument types ``app.sim.warmup`` has already compiled: nothing is
    compiled after it (no compile pause in the middle of a stream)."""
    from app.geometry import ring, triangulation_kernels
    from app.resources import load_default_calibration
    from app.sim.led_ring import stereo_center_x_mm, tilted_normal
    from app.sim.stereo_render import RenderSettings, render_pair
    from app.sim.warmup import compile_kernels
    from app.vision import (
        appearance_kernels,
        blob_kernels,
        ihwt_kernels,
        matching_kernels,
        preprocess_kernels,
    )
    from app.vision.pipeline import NavigationPipeline
    from app.vision.tracking import StereoTracker

    loops = [
        blob_kernels.extract_in_mask,
        blob_kernels.window_blobs,
        blob_kernels.detect_in_boxes,
        preprocess_kernels.frame_summary,
        preprocess_kernels.frame_levels,
        ihwt_kernels.describe_kernel,
        triangulation_kernels.linear_kernel,
        triangulation_kernels.refine_kernel,
        ring.ring_measures_kernel,
        ring.seed_kernel,
        ring.refine_kernel,
        ring.radius_only_kernel,
        matching_kernels.epipolar_kernel,
        matching_kernels.descriptor_kernel,
        matching_kernels.gated_cost,
        appearance_kernels.appearance_kernel,
    ]
    compile_kernels()
    prepared = {loop.__name__: len(loop.signatures) for loop in loops}
    assert all(n >= 1 for n in prepared.values()), prepared
    calib = load_default_calibration()
    x = stereo_center_x_mm(calib, 1000.0)
    for color in (False, True):
        pipe, tracker = NavigationPipeline(calib), StereoTracker(calib, describe=True)
        for i in range(4):
            pair = render_pair(
                calib,
                np.array([x + 4.0 * i, 0.0, 1000.0]),
                tilted_normal(12.0, 20.0),
                RenderSettings(color=color, clutter=6),
                seed=i,
            )
            left, right = pair.left, pair.right
            if not color and i == 1:
                left, right = left[:, :, None], right[:, :, None]  # H×W×1
            if not color and i == 2:  # strided views
                big = np.zeros((2,) + left.shape[:1] + (2 * left.shape[1],), np.uint8)
                big[0, :, ::2], big[1, :, ::2] = left, right
                left, right = big[0, :, ::2], big[1, :, ::2]
            assert pipe.process(left, right).lock
            assert tracker.update(left, right).lock
        assert tracker.stats.tracked >= 2  # the windowed path ran too
    after = {loop.__name__: len(loop.signatures) for loop in loops}
    assert after == prepared


def _numpy_grow_and_merge(boxes, width, height, ksize):  # type: ignore[no-untyped-def]
    """The numpy formulation the compiled merge replaced (the reference)."""
    if not boxes:
        return []
    b = np.array(boxes, dtype=np.int64)
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    m = np.maximum(2, np.ceil(0.5 * np.sqrt(area)).astype(np.int64)) + ksize // 2 + 2
    g = np.column_stack(
        [
            np.maximum(0, b[:, 0] - m),
            np.maximum(0, b[:, 1] - m),
            np.minimum(width, b[:, 2] + m),
            np.minimum(height, b[:, 3] + m),
        ]
    )
    while len(g) > 1:
        over = (
            (g[:, None, 0] < g[None, :, 2])
            & (g[None, :, 0] < g[:, None, 2])
            & (g[:, None, 1] < g[None, :, 3])
            & (g[None, :, 1] < g[:, None, 3])
        )
        np.fill_diagonal(over, False)
        if not over.any():
            break
        # merge every group of overlapping boxes into its bounding box (repeat until stable)
        group = np.arange(len(g))
        for i, j in zip(*np.nonzero(np.triu(over)), strict=True):
            gi, gj = group[i], group[j]
            if gi != gj:
                group[group == gj] = gi
        ids = np.unique(group)
        g = np.array(
            [
                [
                    g[group == k, 0].min(),
                    g[group == k, 1].min(),
                    g[group == k, 2].max(),
                    g[group == k, 3].max(),
                ]
                for k in ids
            ]
        )
    return [(int(r[0]), int(r[1]), int(r[2]), int(r[3])) for r in g]


def test_compiled_box_merge_equals_the_numpy_formulation() -> None:
    """Acquisition boxes grown and merged by the compiled loop equal the numpy formulation,
    order included, on random sets of up to 60 boxes (many overlapping, at the borders)."""
    from app.vision.bright_region_kernels import grow_and_merge_boxes

    rng = np.random.default_rng(0)
    merged_some = False
    for _ in range(400):
        k = int(rng.integers(1, 60))
        x0, y0 = rng.integers(0, 1270, k), rng.integers(0, 1010, k)
        w, h = rng.integers(1, 40, k), rng.integers(1, 40, k)
        boxes = [
            (int(a), int(b), int(min(1280, a + c)), int(min(1024, b + d)))
            for a, b, c, d in zip(x0, y0, w, h, strict=True)
        ]
        grown = grow_and_merge_boxes(np.array(boxes, np.int64), 1280, 1024, 3 // 2 + 2)
        got = [tuple(int(v) for v in r) for r in grown.tolist()]
        assert got == _numpy_grow_and_merge(boxes, 1280, 1024, 3)
        merged_some |= len(got) < len(boxes)
    assert merged_some  # overlaps happened: the merging was exercised
