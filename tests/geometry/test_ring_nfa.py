"""The a-contrario NFA with precision cells that follow the stereo noise
(:func:`app.geometry.ring.nfa.log10_nfa`, ``RingParams.lateral_sigma_per_mm``)."""

from __future__ import annotations

import math

import numpy as np

from app.geometry.circle_fit import fit_circle_3d
from app.geometry.ring import (
    RingFit,
    RingParams,
    find_ring,
    log10_nfa,
    refined_hypotheses,
    ring_consts,
    seed_kernel,
)
from app.geometry.ring.nfa import background_volume_mm3

F_PX, BASELINE_MM, SIGMA_D_PX = 2394.0, 115.0, 0.05
R_MM = 305.0


def _params(lateral: bool) -> RingParams:
    return RingParams(
        radius_mm=R_MM,
        depth_sigma_per_mm=SIGMA_D_PX / (F_PX * BASELINE_MM),
        lateral_sigma_per_mm=SIGMA_D_PX / F_PX if lateral else None,
        fov_tan=(1280 / F_PX, 1024 / F_PX),
    )


def _three_leds(z_mm: float) -> np.ndarray:
    """Three LEDs of a face-on 305 mm, 5-LED ring at ``z_mm`` (slots 0, 1, 3)."""
    a = np.radians([10.0, 82.0, 226.0])
    return np.stack([R_MM * np.cos(a), R_MM * np.sin(a), np.full(3, z_mm)], axis=1)


def test_lateral_noise_sharpens_the_nfa_of_a_far_three_led_ring() -> None:
    """At 4.5 m the depth noise σ_Z ≈ 3.7 mm is 40× the lateral noise: an isotropic cell of
    3σ_Z made three exact LEDs among five points 'expected by chance' (NFA > 10^-3, the 3-LED
    limit); cells that follow the noise find them distinctive. Without the lateral noise the
    NFA is the isotropic one, and it never falls below the anisotropic one."""
    leds = _three_leds(4500.0)
    pts = np.vstack([leds, [[-900.0, 400.0, 4300.0], [700.0, -500.0, 4900.0]]])
    circle = fit_circle_3d(leds)
    resid = np.zeros(3)
    iso, aniso = _params(False), _params(True)
    v = background_volume_mm3(pts, iso)
    nfa_iso = log10_nfa(len(pts), v, circle, leds, resid, iso)
    nfa_aniso = log10_nfa(len(pts), v, circle, leds, resid, aniso)
    assert nfa_iso > iso.log10_nfa_max - iso.three_led_log10_margin
    assert nfa_aniso < nfa_iso - 1.0
    assert nfa_aniso <= aniso.log10_nfa_max - aniso.three_led_log10_margin
    fit = find_ring(pts, aniso)
    assert isinstance(fit, RingFit) and sorted(fit.indices) == [0, 1, 2]
    assert not isinstance(find_ring(pts, iso), RingFit)


def _best_log10_nfa(pts: np.ndarray, params: RingParams) -> float:
    """The smallest NFA (log10) of any ring hypothesis among ``pts`` (inf: none)."""
    consts = ring_consts(params)
    triples, seeds, _ = seed_kernel(pts, consts)
    if not len(seeds):
        return math.inf
    v = background_volume_mm3(pts, params)
    return min(
        (
            log10_nfa(len(pts), v, h.circle, h.points, h.resid_deg, params, h.distance_mm)
            for h in refined_hypotheses(pts, triples, seeds, params, consts)
        ),
        default=math.inf,
    )


def test_unrelated_points_stay_within_what_the_nfa_promises() -> None:
    """Unrelated points (uniform in the field at 4–5 m, 60 per frame, the flight drogue's
    ring sought): the fraction of frames whose best hypothesis has NFA ≤ 10^k stays below 10^k
    — the NFA's definition, an upper bound on the expected number of chance fits."""
    params = _params(True)
    rng = np.random.default_rng(11)
    best = []
    for _ in range(200):
        z = rng.uniform(4000.0, 5000.0, 60)
        x = rng.uniform(-0.5, 0.5, 60) * z * params.fov_tan[0]
        y = rng.uniform(-0.5, 0.5, 60) * z * params.fov_tan[1]
        best.append(_best_log10_nfa(np.stack([x, y, z], axis=1), params))
    b = np.array(best)
    print("frames with a hypothesis:", int(np.isfinite(b).sum()), "best:", np.sort(b)[:5])
    assert np.isfinite(b).sum() >= 20  # chance fits are common: the test has teeth
    for k in (0.0, -1.0, -2.0):
        assert np.mean(b <= k) <= 10.0**k
