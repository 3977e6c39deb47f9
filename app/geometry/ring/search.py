"""The ring search's Python driver: :func:`find_ring` (paper §5.2).

Every candidate point is considered (no cap): the compiled seed search and refinement
(:mod:`app.geometry.ring.kernels`) give the distinct ring hypotheses, each gets its
a-contrario NFA (:mod:`app.geometry.ring.nfa`; tested only against a recent lock's
neighbourhood when it agrees with that lock), and the best is locked only if it is
distinctive, unambiguous and carries no extra points between its slots.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from app.geometry.circle_fit import Circle3D
from app.geometry.ring.kernels import radius_only_kernel, refine_kernel, ring_consts, seed_kernel
from app.geometry.ring.nfa import background_volume_mm3, log10_nfa, prior_volume_mm3
from app.geometry.ring.params import (
    RingFit,
    RingHypothesis,
    RingParams,
    RingPrior,
    RingRejection,
    agrees_with_prior,
)
from app.types import FloatArray

# the consistency rank of a hypothesis whose residuals agree with the strictest noise model
STRICT_RANK = 2
MAX_SEEDS = 20_000  # refinement budget; seeds are ordered by fit quality (never reached in tests)


def refined_hypotheses(
    p: FloatArray,
    triples: np.ndarray,
    seeds: np.ndarray,
    params: RingParams,
    consts: FloatArray,
) -> list[RingHypothesis]:
    """The distinct refined hypotheses of the seeds (:func:`refine_kernel`), NFA not yet set."""
    members, slots, resid, dist, info = refine_kernel(p, triples, seeds, consts)
    hyps = []
    for h in range(len(members)):
        m = int(np.count_nonzero(members[h] >= 0))
        fit = info[h]
        circle = Circle3D(
            fit[0:3].copy(), fit[3:6].copy(), float(fit[6]), float(fit[7]), float(fit[8])
        )
        hyps.append(
            RingHypothesis(
                members=members[h, :m],
                points=p[members[h, :m]],
                slots=slots[h, :m],
                resid_deg=resid[h, :m],
                circle=circle,
                offset_deg=float(fit[10]),
                cost=float(fit[11]),
                angle_tol=float(fit[12]),
                inlier_tol=float(fit[13]),
                extra_on_ring=int(fit[14]),
                distance_mm=dist[h, :m],
            )
        )
    return hyps


def _rivals(
    best: RingHypothesis,
    hyps: list[RingHypothesis],
    params: RingParams,
    prior: RingPrior | None,
    consistency: Callable[[RingFit], int] | None,
    index_map: np.ndarray,
    n: int,
) -> list[RingHypothesis]:
    """The hypotheses that compete with ``best`` (:func:`find_ring`'s docstring): outside it
    with as many points, or one fewer and an NFA within ``ambiguity_log10`` decades; and,
    when ``best`` is suspect (short of :data:`STRICT_RANK`), any disjoint meaningful ring."""
    m = len(best.members)
    best_set = set(best.members.tolist())
    rivals = [
        h
        for h in hyps[1:]
        if not set(h.members.tolist()) <= best_set
        and h.log10_nfa <= _nfa_limit(h, params, prior)
        and (
            len(h.members) == m
            or (len(h.members) == m - 1 and h.log10_nfa <= best.log10_nfa + params.ambiguity_log10)
        )
    ]
    taken = {id(h) for h in rivals}
    disjoint = [
        h
        for h in hyps[1:]
        if id(h) not in taken
        and best_set.isdisjoint(h.members.tolist())
        and h.log10_nfa <= _nfa_limit(h, params, prior)
    ]
    if (
        disjoint
        and consistency is not None
        and consistency(_ring_fit(best, index_map, n, len(hyps))) < STRICT_RANK
    ):
        rivals += disjoint
    return rivals


def find_ring(
    points: FloatArray,
    params: RingParams,
    prior: RingPrior | None = None,
    consistency: Callable[[RingFit], int] | None = None,
) -> RingFit | RingRejection:
    """Locate the LED ring among ``points`` (N×3, mm, left camera frame) with the integrity
    tests of :mod:`app.geometry.ring`. ``prior``: a recent lock (for 3-LED hypotheses).

    ``consistency``: how well a hypothesis' own residuals agree with the measurement noise
    (the caller's χ² test, :mod:`app.vision.error_bound`): 0 not at all, higher for agreement
    with a stricter noise model. When hypotheses compete ("ambiguous"), the one that alone
    reaches the highest rank any of them reaches is taken: a ring of sun glints on polished
    bolts fits the slots as well as the LEDs but its specular points triangulate off any
    circle by far more than the sensor's noise allows (χ² ≈ 270 for 6 dof against ≈ 1 for
    the LEDs on the held-back optics set). With none or several at that rank, the frame stays
    ambiguous. A competitor is a hypothesis outside the best with as many points, or one
    fewer and an NFA within ``params.ambiguity_log10`` decades; when the best falls short of
    :data:`STRICT_RANK`, also any hypothesis of any size that shares none of its points and is
    meaningful on its own (three LEDs beside a concentric ring of five bolt glints)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    index_map = np.flatnonzero(np.isfinite(pts).all(axis=1))
    p = pts[index_map]
    n, N = len(p), params.led_count
    if n < params.min_leds:
        return RingRejection(f"only {n} matched LED(s); need at least {params.min_leds}")
    consts = ring_consts(params)
    triples, seeds, _ = seed_kernel(p, consts)
    hyps = refined_hypotheses(p, triples, seeds[:MAX_SEEDS], params, consts) if len(seeds) else []
    if not hyps:
        most = radius_only_kernel(p, triples, consts)
        if most >= 4:
            return RingRejection(
                f"{most} points lie on a ring of radius {params.radius_mm:.0f} mm but not on "
                f"{N} evenly spaced slots: check led_count (the ring may carry a different "
                f"number of LEDs)"
            )
        return RingRejection(
            f"no 3 matched points lie on evenly spaced slots of a ring of radius "
            f"{params.radius_mm:.0f} mm ({n} candidate point(s))"
        )
    volume = background_volume_mm3(p, params)
    near_prior = -1  # candidates in the prior's neighbourhood (counted when first needed)
    for h in hyps:
        h.log10_nfa = log10_nfa(n, volume, h.circle, h.points, h.resid_deg, params, h.distance_mm)
        if prior is not None and agrees_with_prior(h.circle, prior):
            # a hypothesis predicted by a recent lock is tested only against its neighbourhood
            if near_prior < 0:
                d = np.linalg.norm(p - prior.center_mm, axis=1)
                near_prior = int(np.count_nonzero(d <= params.radius_mm + prior.gate_mm))
            local = log10_nfa(
                near_prior,
                prior_volume_mm3(params, prior),
                h.circle,
                h.points,
                h.resid_deg,
                params,
                h.distance_mm,
            )
            h.log10_nfa = min(h.log10_nfa, local)
    hyps.sort(key=lambda h: (-len(h.members), h.cost))
    best = hyps[0]
    m = len(best.members)
    limit = _nfa_limit(best, params, prior)
    if best.log10_nfa > limit:
        return RingRejection(
            f"not distinctive: a {m}-LED ring fit is expected by chance "
            f"(NFA 10^{best.log10_nfa:.1f} > 10^{limit:.1f}) among {n} candidate points"
        )
    rivals = _rivals(best, hyps, params, prior, consistency, index_map, n)
    if rivals:
        passing = _most_consistent([best, *rivals], consistency, index_map, n, len(hyps))
        if len(passing) != 1:
            noise = "" if consistency is None else f"; {len(passing)} consistent with the noise"
            return RingRejection(
                f"ambiguous: {len(rivals) + 1} ring hypotheses fit ({m} and "
                f"{len(rivals[0].members)} LEDs, NFA 10^{best.log10_nfa:.1f} vs "
                f"10^{rivals[0].log10_nfa:.1f}{noise})"
            )
        best = passing[0]
        m = len(best.members)
        limit = _nfa_limit(best, params, prior)
        if best.log10_nfa > limit:
            return RingRejection(
                f"ambiguous: the one ring hypothesis consistent with the noise ({m} LEDs) is "
                f"not distinctive (NFA 10^{best.log10_nfa:.1f} > 10^{limit:.1f})"
            )
    if best.extra_on_ring > params.max_extra_on_ring:
        return RingRejection(
            f"{best.extra_on_ring} points lie on the ring between its {N} LED slots: check "
            f"led_count (the ring may carry a different number of LEDs)"
        )
    if m < params.min_leds:
        return RingRejection(
            f"only {m} point(s) fit an evenly spaced ring of radius {params.radius_mm:.0f} mm; "
            f"need at least {params.min_leds}"
        )
    return _ring_fit(best, index_map, n, len(hyps))


def _most_consistent(
    hyps: list[RingHypothesis],
    consistency: Callable[[RingFit], int] | None,
    index_map: np.ndarray,
    candidates: int,
    hypotheses: int,
) -> list[RingHypothesis]:
    """The hypotheses at the highest consistency rank any of them reaches (none when that is
    0 or there is no test)."""
    if consistency is None:
        return []
    ranks = [consistency(_ring_fit(h, index_map, candidates, hypotheses)) for h in hyps]
    top = max(ranks)
    return [h for h, r in zip(hyps, ranks, strict=True) if r == top] if top > 0 else []


def _nfa_limit(h: RingHypothesis, params: RingParams, prior: RingPrior | None) -> float:
    """The largest log10 NFA a hypothesis may have to be locked: stricter with 3 LEDs unless a
    recent lock predicts it."""
    limit = params.log10_nfa_max
    if len(h.members) == 3 and not (prior is not None and agrees_with_prior(h.circle, prior)):
        limit -= params.three_led_log10_margin
    return limit


def _ring_fit(
    h: RingHypothesis, index_map: np.ndarray, candidates: int, hypotheses: int
) -> RingFit:
    """A hypothesis as a :class:`RingFit` (indices into the caller's points)."""
    return RingFit(
        circle=h.circle,
        indices=tuple(index_map[h.members].tolist()),
        slots=tuple(h.slots.tolist()),
        offset_deg=h.offset_deg,
        residual_deg=tuple(h.resid_deg.tolist()),
        log10_nfa=h.log10_nfa,
        candidates=candidates,
        hypotheses=hypotheses,
    )
