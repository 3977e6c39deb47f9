"""The compiled / array forms of the matching, appearance and describe steps against the code
they replaced (kept here as the reference): the same matches (tie-breaking included), the same
descriptor distances to the bit, the same appearance verdicts and reasons."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from app.geometry.projection import undistort_pixels
from app.geometry.triangulation import triangulate_linear
from app.sim.led_ring import stereo_center_x_mm, tilted_normal
from app.sim.stereo_render import RenderSettings, render_pair
from app.vision import ihwt
from app.vision.appearance import AppearanceConfig, BlobTable, appearance_ok, appearance_reasons
from app.vision.ihwt_kernels import describe_kernel
from app.vision.matching import (
    descriptor_distances,
    epipolar_distances,
    match_epipolar,
    match_min_distance,
)
from app.vision.pipeline import NavigationPipeline, PipelineConfig
from app.vision.types import Blob, Match

_BIG = 1e6


# ------------------------------------------------------------------ the replaced code
def _ref_descriptor_distances(desc_left: np.ndarray, desc_right: np.ndarray) -> np.ndarray:
    diff = desc_left[:, None, :] - desc_right[None, :, :]
    return np.asarray(np.sqrt(np.sum(diff * diff, axis=-1)))


def _ref_match(i: int, j: int, desc_dist: np.ndarray, epi: np.ndarray) -> Match:
    return Match(
        left_index=i,
        right_index=j,
        descriptor_distance=float(desc_dist[i, j]),
        epipolar_px=float(epi[i, j]),
    )


def _ref_match_min_distance(desc_dist: np.ndarray, epi: np.ndarray) -> list[Match]:
    if desc_dist.size == 0:
        return []
    return [_ref_match(i, int(np.argmin(row)), desc_dist, epi) for i, row in enumerate(desc_dist)]


def _ref_assign(cost: np.ndarray, gate: np.ndarray) -> list[tuple[int, int]]:
    c = np.where(gate, cost, _BIG)
    rows, cols = linear_sum_assignment(c)
    return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if gate[i, j]]


def _ref_match_epipolar(
    desc_dist: np.ndarray,
    epi: np.ndarray,
    depth_mm: np.ndarray,
    tol_px: float = 2.0,
    depth_range_mm: tuple[float, float] = (100.0, 50_000.0),
    depth_coherence: float = 0.1,
) -> list[Match]:
    if desc_dist.size == 0:
        return []
    gate = (epi <= tol_px) & (depth_mm >= depth_range_mm[0]) & (depth_mm <= depth_range_mm[1])
    gate &= np.isfinite(depth_mm)
    cost = desc_dist + epi / tol_px
    pairs = _ref_assign(cost, gate)
    if len(pairs) >= 2:
        z_ref = float(np.median([depth_mm[i, j] for i, j in pairs]))
        with np.errstate(divide="ignore", invalid="ignore"):
            dev = np.abs(np.log(np.where(gate, depth_mm, z_ref) / z_ref))
        cost = cost + dev / depth_coherence
        pairs = _ref_assign(cost, gate)
    masked = np.where(gate, cost, _BIG)
    best_for_left = np.argmin(masked, axis=1)
    best_for_right = np.argmin(masked, axis=0)
    return [
        _ref_match(i, j, desc_dist, epi)
        for i, j in pairs
        if best_for_left[i] == j or best_for_right[j] == i
    ]


# ------------------------------------------------------------------ random problems
def _unit_rows(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    v = rng.normal(size=(n, d)) * 10.0 ** rng.uniform(-2, 2, size=(1, d))
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)


def _problem(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Descriptor distances, epipolar distances (px) and depths (mm) of a random candidate set:
    continuous or integer-valued (many exact ties), depths around a common range with outliers,
    out-of-range, infinite and NaN entries."""
    nl, nr = int(rng.integers(0, 30)), int(rng.integers(0, 30))
    tol = float(rng.choice([0.5, 2.0, 3.0]))
    kind = rng.random()
    if kind < 0.25:  # gated pairs that share no row or column (one LED ring, no clutter)
        ddist = descriptor_distances(_unit_rows(rng, nl, 64), _unit_rows(rng, nr, 64))
        epi = rng.uniform(1.01 * tol, 5.0 * tol, (nl, nr))
        m = int(rng.integers(0, min(nl, nr) + 1))
        rows, cols = rng.choice(nl, m, replace=False), rng.choice(nr, m, replace=False)
        epi[rows, cols] = rng.uniform(0.0, tol, m)
        depth = 1000.0 * np.exp(rng.normal(0.0, 0.3, (nl, nr)))
        depth[rng.random((nl, nr)) < 0.1] = 60.0  # some of them out of range
        if m and rng.random() < 0.1:
            ddist[rows[0], cols[0]] = np.nan  # the assignment refuses it (as before)
    elif kind < 0.55:  # ties everywhere
        ddist = rng.integers(0, 3, (nl, nr)).astype(np.float64)
        epi = rng.choice([0.0, 0.5 * tol, tol, 2.0 * tol], (nl, nr))
        depth = rng.choice([500.0, 1000.0, 2000.0, np.inf], (nl, nr))
    else:
        ddist = descriptor_distances(_unit_rows(rng, nl, 64), _unit_rows(rng, nr, 64))
        epi = rng.exponential(1.5 * tol, (nl, nr))
        depth = 1000.0 * np.exp(rng.normal(0.0, 0.3, (nl, nr)))
        odd = rng.random((nl, nr))
        depth[odd < 0.05] = 50.0  # too near
        depth[(odd >= 0.05) & (odd < 0.1)] = np.inf
        depth[(odd >= 0.1) & (odd < 0.12)] = np.nan
        depth[(odd >= 0.12) & (odd < 0.14)] = -800.0  # behind the rig
    return ddist, epi, depth, tol


def test_descriptor_distances_equal_the_numpy_formulation_to_the_bit() -> None:
    rng = np.random.default_rng(0)
    for d in (3, 8, 13, 64, 64, 64, 100, 128, 200):
        for _ in range(8):
            a = _unit_rows(rng, int(rng.integers(0, 40)), d)
            b = _unit_rows(rng, int(rng.integers(0, 40)), d)
            got = descriptor_distances(a, b)
            assert got.shape == (len(a), len(b))
            assert np.array_equal(got, _ref_descriptor_distances(a, b)), d
    with pytest.raises(ValueError, match="do not pair"):
        descriptor_distances(np.zeros((3, 64)), np.zeros((3, 32)))
    # non-contiguous input (a column slice) gives the same
    a = _unit_rows(rng, 20, 128)[:, ::2]
    b = _unit_rows(rng, 17, 64)
    assert np.array_equal(descriptor_distances(a, b), _ref_descriptor_distances(a, b))


def test_matchers_equal_the_replaced_code_ties_included() -> None:
    rng = np.random.default_rng(1)
    n_matched = n_refused = 0
    for _ in range(500):
        ddist, epi, depth, tol = _problem(rng)
        with np.errstate(invalid="ignore"):
            try:
                ref = _ref_match_epipolar(ddist, epi, depth, tol)
            except ValueError:  # a NaN cost inside the gate
                n_refused += 1
                with pytest.raises(ValueError):
                    match_epipolar(ddist, epi, depth, tol)
                continue
        got = match_epipolar(ddist, epi, depth, tol)
        assert got == ref
        assert match_min_distance(ddist, epi) == _ref_match_min_distance(ddist, epi)
        n_matched += len(ref)
    assert n_matched > 1000  # the problems do match (not only empty lists)
    assert n_refused >= 3


# ------------------------------------------------------------------ appearance
def _blob(rng: np.random.Generator, area: float, peak: float, color: bool) -> Blob:
    col = None
    if color:
        col = tuple(float(v) for v in rng.uniform(0, 255, 3))
        if rng.random() < 0.6:  # green-dominant, sometimes saturated
            col = (col[0] * 0.3, min(255.0, col[1] * 1.5 + 60.0), col[2] * 0.3)
    return Blob((0.0, 0.0), max(0, round(area)), (0, 0, 1, 1), peak, 1.0, col)


def test_appearance_verdicts_equal_the_per_pair_reasons() -> None:
    """Pairs drawn around an LED's size at their depth (near the bounds of every test), with
    stereo size and peak ratios around the limits, colours or none, and odd depths."""
    rng = np.random.default_rng(2)
    n_ok = n_rejected = 0
    for trial in range(40):
        cfg = AppearanceConfig(
            enabled=trial != 0,
            size_slack_px=float(rng.choice([0.0, 2.0])),
            stereo_size_ratio=float(rng.uniform(1.1, 2.0)),
            stereo_peak_ratio=float(rng.uniform(1.1, 2.0)),
        )
        color = trial % 2 == 1
        f_l, f_r = (float(v) for v in rng.uniform(800, 2500, 2))
        d_led = float(rng.uniform(3.0, 10.0))
        bg = (float(rng.uniform(0, 30)), float(rng.uniform(0, 30)))
        n = int(rng.integers(0, 40))
        z_l = rng.uniform(200.0, 4000.0, n)
        z_l[rng.random(n) < 0.05] = -300.0
        z_r = z_l + rng.normal(0.0, 30.0, n)
        rho = f_l * 0.5 * d_led / np.abs(z_l)
        r_l = rho * np.exp(rng.normal(0.0, 0.6, n))
        r_r = r_l * np.exp(rng.normal(0.0, 0.3, n))
        peak_l = rng.uniform(20.0, 255.0, n)
        peak_r = np.minimum(255.0, peak_l * np.exp(rng.normal(0.0, 0.3, n)))
        left = [_blob(rng, math.pi * r * r, p, color) for r, p in zip(r_l, peak_l, strict=True)]
        right = [
            _blob(rng, math.pi * r * r, p, color and rng.random() < 0.8)
            for r, p in zip(r_r, peak_r, strict=True)
        ]
        li, ri = rng.permutation(n), rng.permutation(n)  # blob lists in another order
        left = [left[k] for k in np.argsort(li)]
        right = [right[k] for k in np.argsort(ri)]
        ok = appearance_ok(
            BlobTable.of(left), BlobTable.of(right), li, ri, z_l, z_r, f_l, f_r, d_led, bg, cfg
        )
        assert ok.shape == (n,) and ok.dtype == np.bool_
        for k in range(n):
            reasons = appearance_reasons(
                left[li[k]], right[ri[k]], z_l[k], z_r[k], f_l, f_r, d_led, bg, cfg
            )
            assert bool(ok[k]) == (reasons == []), (trial, k, reasons)
            n_ok += bool(ok[k])
            n_rejected += not ok[k]
    assert n_ok > 100 and n_rejected > 100
    with pytest.raises(ValueError, match="do not agree"):
        one = np.zeros(1, np.int64)
        appearance_ok(
            BlobTable.of(left),
            BlobTable.of(right),
            one + len(left),
            one,
            z_l[:1],
            z_r[:1],
            f_l,
            f_r,
            d_led,
            bg,
            AppearanceConfig(),
        )


def test_pipeline_appearance_and_matches_equal_the_replaced_per_match_code(calib) -> None:
    """Colour frames with LED-like glints: the pipeline's matches are the replaced matcher's on
    the same inputs, and it records exactly the per-match reasons for the rejected matches."""
    x = stereo_center_x_mm(calib, 1000.0)
    settings = RenderSettings(color=True, glints=30, mono_glints=10)
    pair = render_pair(calib, np.array([x, 0.0, 1000.0]), tilted_normal(10.0, 30.0), settings)
    # eq. 9's gray and the colour gate off: the whitish glints reach the matcher and the
    # appearance test
    appearance = AppearanceConfig(colour_gate=False)
    for matcher in ("epipolar", "paper"):
        pipe = NavigationPipeline(
            calib, PipelineConfig(matcher=matcher, appearance=appearance, colour_detect="gray")
        )
        assert pipe.process(pair.left, pair.right).lock
        tr, cfg = pipe.trace, pipe.config
        assert tr.left is not None and tr.right is not None and tr.xyz_mm is not None
        xl = undistort_pixels(calib.left, tr.left.points_px)
        xr = undistort_pixels(calib.right, tr.right.points_px)
        ddist = _ref_descriptor_distances(tr.left.descriptors, tr.right.descriptors)
        epi = epipolar_distances(calib.fundamental, xl, xr)
        if matcher == "paper":
            ref = _ref_match_min_distance(ddist, epi)
        else:
            depth = np.full(ddist.shape, np.inf)
            il, ir = np.nonzero(epi <= cfg.epipolar_tol_px)
            depth[il, ir] = triangulate_linear(calib.P_left, calib.P_right, xl[il], xr[ir])[:, 2]
            ref = _ref_match_epipolar(ddist, epi, depth, cfg.epipolar_tol_px)
        assert tr.matches == ref
        rejected = {}
        for i, m in enumerate(tr.matches):
            X = tr.xyz_mm[i]
            reasons = appearance_reasons(
                tr.left.blobs[m.left_index],
                tr.right.blobs[m.right_index],
                float(X[2]),
                float(calib.R[2] @ X + calib.T[2]),
                calib.left.fx,
                calib.right.fx,
                cfg.led_diameter_mm,
                (tr.backgrounds[0][0], tr.backgrounds[1][0]),
                cfg.appearance,
            )
            if reasons:
                rejected[i] = reasons
        # (every match here triangulates consistently, so each one was judged)
        assert tr.appearance_rejected.keys() <= rejected.keys()
        assert tr.appearance_rejected == {i: rejected[i] for i in tr.appearance_rejected}
        assert len(tr.appearance_rejected) >= 5  # whitish glints fail the colour test


def test_describe_windows_follow_the_scalar_rule() -> None:
    """``describe`` computes all windows at once: the same as :func:`window_side_px` per blob."""
    rng = np.random.default_rng(3)
    img = rng.integers(0, 255, (120, 160), dtype=np.uint8)
    blobs = [
        Blob((float(u), float(v)), int(a), (0, 0, 1, 1), 0.0, 1.0)
        for u, v, a in zip(
            rng.uniform(0, 160, 60), rng.uniform(0, 120, 60), rng.integers(0, 2000, 60), strict=True
        )
    ]
    for factor, min_w in ((8.0, 16), (80.0, 16), (3.0, 5)):
        windows = np.array([ihwt.window_side_px(b.area_px, factor, min_w) for b in blobs])
        centers = np.array([b.centroid_px for b in blobs])
        ref = describe_kernel(img, centers, windows)
        assert np.array_equal(ihwt.describe(img, blobs, factor, min_w), ref)
    assert math.isclose(ihwt.window_side_px(0, 8.0, 16), 16.0)


@pytest.mark.parametrize("n", [0, 1])
def test_matchers_on_tiny_inputs(n: int) -> None:
    ddist, epi, depth = np.zeros((n, 3)), np.zeros((n, 3)), np.full((n, 3), 1000.0)
    assert match_epipolar(ddist, epi, depth) == _ref_match_epipolar(ddist, epi, depth)
    assert match_min_distance(ddist, epi) == _ref_match_min_distance(ddist, epi)
    with pytest.raises(ValueError, match="do not pair"):
        match_epipolar(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((3, 2)))


def test_matcher_with_a_zero_tolerance_behaves_as_the_replaced_code() -> None:
    """tol_px = 0: nothing matches where no pair is exactly on its epipolar line; where one is,
    its cost is 0/0 and the assignment refuses it, as before (no division error)."""
    rng = np.random.default_rng(4)
    ddist, epi, depth = rng.random((4, 5)), rng.uniform(0.1, 3.0, (4, 5)), np.full((4, 5), 900.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        assert match_epipolar(ddist, epi, depth, 0.0) == _ref_match_epipolar(ddist, epi, depth, 0.0)
        epi[1, 2] = 0.0
        for matcher in (match_epipolar, _ref_match_epipolar):
            with pytest.raises(ValueError):
                matcher(ddist, epi, depth, 0.0)
