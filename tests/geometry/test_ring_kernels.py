"""The ring search's compiled loops against the numpy/Python formulation they replaced.

``seed_kernel`` (chord-compatible pairs → triples → circumcircles → radius → slot check →
ordered seeds) and ``refine_kernel`` / ``hypothesis_kernel`` (plane + circle fit, slot offset,
slot assignment, iterated) must give what ``seeds_reference`` and ``fit_hypothesis`` (``tests/support/ring_reference.py``) give, on
hostile point sets: clutter around a ring, two rings, 3-LED rings, near-collinear and repeated
points, 60 candidates, repeated LEDs, other LED counts and depth-noise models.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from app.geometry import ring
from app.geometry.circle_fit import Circle3D
from app.geometry.ring import RingFit, RingParams, RingPrior, find_ring
from app.geometry.ring import search as ring_search
from tests.support.ring_reference import (
    fit_hypothesis,
    hypotheses_reference,
    radius_only_count,
    seeds_reference,
)


def _ring_points(
    rng: np.random.Generator,
    center: np.ndarray,
    normal: np.ndarray,
    count: int = 5,
    present: list[int] | None = None,
    noise_mm: float = 0.3,
) -> np.ndarray:
    n = normal / np.linalg.norm(normal)
    e1 = np.cross(n, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    k = np.arange(count) if present is None else np.array(present)
    th = rng.uniform(0.0, 2.0 * np.pi) + 2.0 * np.pi * k / count
    pts = center + 75.0 * (np.outer(np.cos(th), e1) + np.outer(np.sin(th), e2))
    return pts + rng.normal(0.0, noise_mm, (len(k), 3))


def _hostile_sets(seed: int, sets: int) -> Iterator[tuple[str, np.ndarray, RingParams]]:
    """(kind, finite points (mm), params) of every hostile kind in turn."""
    rng = np.random.default_rng(seed)
    noisy = RingParams(depth_sigma_per_mm=2e-7, fov_tan=(0.8, 0.64))
    for i in range(sets):
        kind = i % 7
        c = np.array([rng.uniform(-200, 200), rng.uniform(-150, 150), rng.uniform(800, 3000)])
        nrm = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), -1.0])
        led = _ring_points(rng, c, nrm)
        if kind == 0:
            name = "ring in clutter"
            pts = np.vstack([led, c + rng.normal(0, 80, (int(rng.integers(5, 30)), 3))])
        elif kind == 1:
            name = "two rings"
            other = _ring_points(rng, c + rng.normal(0, 120, 3), nrm + rng.normal(0, 0.2, 3))
            pts = np.vstack([led, other, c + rng.normal(0, 100, (8, 3))])
        elif kind == 2:
            name = "3-LED ring"
            three = _ring_points(rng, c, nrm, present=[0, 1, 3])
            pts = np.vstack([three, c + rng.normal(0, 100, (int(rng.integers(0, 12)), 3))])
        elif kind == 3:
            name = "near-collinear"
            d = rng.normal(0, 1, 3)
            d /= np.linalg.norm(d)
            line = c + np.outer(np.linspace(-150, 150, 9), d) + rng.normal(0, 1e-6, (9, 3))
            chords = c + np.outer([0.0, 88.17, 176.34], d)  # two 72° chords in a row
            pts = np.vstack([led, line, chords])
        elif kind == 4:
            name = "60 points"
            pts = np.vstack([led, c + rng.normal(0, 120, (55, 3))])
        elif kind == 5:
            name = "repeated LEDs"  # equal slot residuals: the tie-break decides
            pts = np.vstack([led, led[:2], c + rng.normal(0, 100, (6, 3))])
        else:
            name = "other LED count, repeated points"
            other = _ring_points(rng, c, nrm, count=int(rng.choice([4, 6, 8])))
            pts = np.vstack([other, c + rng.normal(0, 90, (10, 3))])
            pts = np.vstack([pts, pts[:2]])
        pts = np.ascontiguousarray(pts[rng.permutation(len(pts))])
        if i % 4:
            params = noisy
        else:
            params = RingParams(
                led_count=int(rng.choice([4, 5, 6])),
                depth_sigma_per_mm=float(rng.choice([0.0, 2e-7, 1e-6])),
            )
        yield name, pts, params


SETS = list(_hostile_sets(11, 42))


def test_compiled_seeds_equal_the_numpy_formulation() -> None:
    """Same chord-compatible triples, same seeds in the same order (up to exact ties of the
    slot residuals), same sums of squared residuals."""
    seeded = rejected = 0
    for name, p, params in SETS:
        triples, seeds, keys = ring.seed_kernel(p, ring.ring_consts(params))
        ref_triples, ref_seeds, ref_keys = seeds_reference(p, params)
        assert np.array_equal(triples, ref_triples), name
        assert sorted(seeds.tolist()) == sorted(ref_seeds.tolist()), name
        assert np.allclose(keys, ref_keys, rtol=0.0, atol=1e-9), name
        for t, (a, b) in enumerate(zip(seeds, ref_seeds, strict=True)):
            if a != b:  # only where the residuals tie
                assert abs(keys[t] - ref_keys[t]) < 1e-9, name
        assert np.all(np.diff(keys) >= 0.0)
        seeded += len(seeds) > 0
        rejected += len(seeds) < len(triples)
    # the sets exercise both outcomes of the radius and slot checks
    assert seeded >= len(SETS) // 2 and rejected >= len(SETS) // 2


def _same_hypothesis(got: ring.RingHypothesis, ref: ring.RingHypothesis) -> None:
    assert got.members.tolist() == ref.members.tolist()
    assert got.slots.tolist() == ref.slots.tolist()
    assert got.extra_on_ring == ref.extra_on_ring
    assert got.cost == pytest.approx(ref.cost, rel=0.0, abs=1e-9)
    assert got.offset_deg == pytest.approx(ref.offset_deg, rel=0.0, abs=1e-9)
    assert np.allclose(got.resid_deg, ref.resid_deg, rtol=0.0, atol=1e-9)
    assert got.distance_mm is not None and ref.distance_mm is not None
    assert np.allclose(got.distance_mm, ref.distance_mm, rtol=0.0, atol=1e-9)
    assert np.allclose(got.circle.center, ref.circle.center, rtol=0.0, atol=1e-9)
    assert np.allclose(got.circle.normal, ref.circle.normal, rtol=0.0, atol=1e-12)
    assert got.circle.radius == pytest.approx(ref.circle.radius, rel=0.0, abs=1e-9)
    assert got.circle.rms == pytest.approx(ref.circle.rms, rel=0.0, abs=1e-9)
    assert got.angle_tol == ref.angle_tol and got.inlier_tol == ref.inlier_tol


def test_compiled_refinement_equals_fit_hypothesis_on_every_seed() -> None:
    """Each seed refined by ``hypothesis_kernel`` gives ``fit_hypothesis``'s hypothesis (or
    none where it gives none), covered seeds included."""
    found = refused = 0
    for name, p, params in SETS:
        consts = ring.ring_consts(params)
        triples, seeds, _ = ring.seed_kernel(p, consts)
        for t in seeds[:60]:
            ok, members, slots, resid, dist, info = ring.hypothesis_kernel(p, triples[t], consts)
            ref = fit_hypothesis(p, triples[t], params)
            assert ok == (ref is not None), name
            if ref is None:
                refused += 1
                continue
            found += 1
            got = ring.RingHypothesis(
                members=members,
                points=p[members],
                slots=slots,
                resid_deg=resid,
                circle=Circle3D(info[0:3], info[3:6], info[6], info[7], info[8]),
                offset_deg=info[10],
                cost=info[11],
                angle_tol=info[12],
                inlier_tol=info[13],
                extra_on_ring=int(info[14]),
                distance_mm=dist,
            )
            _same_hypothesis(got, ref)
    assert found >= 50 and refused >= 10  # both outcomes exercised


def test_compiled_hypothesis_loop_equals_the_python_loop() -> None:
    """The distinct hypotheses of all seeds, in order (covered seeds skipped, repeats kept
    once), as the Python loop finds them."""
    several = 0
    for name, p, params in SETS:
        consts = ring.ring_consts(params)
        triples, seeds, _ = ring.seed_kernel(p, consts)
        got = ring.refined_hypotheses(p, triples, seeds, params, consts)
        ref = hypotheses_reference(p, triples, seeds, params)
        assert len(got) == len(ref), name
        for g, r in zip(got, ref, strict=True):
            _same_hypothesis(g, r)
        several += len(got) >= 2
    assert several >= 5  # competing hypotheses: the skip/repeat logic was exercised


def _summary(result: RingFit | ring.RingRejection) -> tuple[object, ...]:
    if isinstance(result, RingFit):
        return (result.indices, result.slots, result.hypotheses, round(result.log10_nfa, 9))
    return (result.reason,)


def test_find_ring_gives_what_the_reference_formulation_gives(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Whole ring searches (with and without a prior, non-finite points among the
    candidates) lock the same points, slots and NFA, or refuse for the same reason."""
    cases = []
    rng = np.random.default_rng(5)
    for i, (_, p, params) in enumerate(SETS):
        pts = p.copy()
        if i % 3 == 0:
            pts[rng.integers(len(pts))] = np.nan
        prior = None
        if i % 2 == 0:
            prior = RingPrior.at_range(np.median(p, axis=0), np.array([0.0, 0.0, -1.0]), params)
        cases.append((pts, params, prior))
    compiled = [_summary(find_ring(*case)) for case in cases]

    def seeds_ref(p, consts):  # type: ignore[no-untyped-def]
        names = ("radius_mm", "led_count", "radius_tol_frac", "inlier_tol_mm", "angle_tol_deg")
        names += ("max_angle_tol_deg", "depth_sigma_per_mm", "max_view_angle_deg")
        values = dict(zip(names, consts.tolist(), strict=True))
        values["led_count"] = int(values["led_count"])
        return seeds_reference(p, RingParams(**values))  # type: ignore[arg-type]

    monkeypatch.setattr(ring_search, "seed_kernel", seeds_ref)
    monkeypatch.setattr(
        ring_search,
        "refined_hypotheses",
        lambda p, t, s, params, consts: hypotheses_reference(p, t, s, params),
    )
    reference = []
    for pts, params, prior in cases:
        reference.append(_summary(find_ring(pts, params, prior)))
    assert compiled == reference
    assert sum(isinstance(c[0], tuple) for c in compiled) >= len(cases) // 3  # locks
    assert sum(isinstance(c[0], str) for c in compiled) >= 3  # and refusals


def test_degenerate_candidates() -> None:
    """Collinear and coincident points (no circumcircle) give no seed in either formulation,
    and find_ring refuses them without an error."""
    loose = RingParams(depth_sigma_per_mm=1e-6)  # σ_Z = 9 mm at 3 m: wide chord tolerances
    line = np.outer(np.linspace(0.0, 600.0, 12), [1.0, 0.5, 0.2]) + [0.0, 0.0, 3000.0]
    same = np.tile([10.0, 20.0, 3000.0], (6, 1))
    for p in (np.ascontiguousarray(line), same):
        triples, seeds, _ = ring.seed_kernel(p, ring.ring_consts(loose))
        ref_triples, ref_seeds, _ = seeds_reference(p, loose)
        assert np.array_equal(triples, ref_triples) and len(seeds) == len(ref_seeds) == 0
        assert not isinstance(find_ring(p, loose), RingFit)
        if p is not same:
            assert len(triples) > 0  # chord-compatible triples reached the circle check


def test_compiled_radius_only_count_equals_the_numpy_formulation() -> None:
    """The refusal's diagnosis (most points on one circle of the ring's radius, slots
    ignored) with every triple (≤ 30 points) or the chord-compatible ones (more)."""
    counts = []
    for name, p, params in SETS:
        consts = ring.ring_consts(params)
        triples = ring.seed_kernel(p, consts)[0]
        got = ring.radius_only_kernel(p, triples, consts)
        assert got == radius_only_count(p, params, triples), name
        counts.append((len(p) <= 30, got))
    assert {small for small, _ in counts} == {True, False}  # both kinds of triples
    assert len({got for _, got in counts}) >= 3
