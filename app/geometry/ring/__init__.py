"""Find the drogue's LED ring among triangulated points, with an integrity test (paper §5.2).

The LEDs sit on evenly spaced *slots* of a circle of known radius R. Every candidate point is
considered (no cap):

1. **Pairs** — two LEDs are a chord 2R·sin(πk/N) apart (k = 1..⌊N/2⌋); a table of pairwise
   distances keeps only pairs at a chord length (within the depth-dependent tolerances).
2. **Seeds** — triples whose three pairs are all chords, whose circumcircle has the expected
   radius, faces the cameras and puts the three points on distinct, evenly spaced slots.
3. **Hypotheses** — each seed is refined: plane + circle fit, slot offset, and *slot
   assignment* (one point per slot: the on-circle point nearest the slot's angle, never one
   that fits the slot worse than the point it displaces), iterated until stable.
4. **Integrity** — each hypothesis gets an a-contrario number of false alarms (NFA): the expected
   number of m-point configurations that would fit as well among the n candidates if the
   candidates were unrelated points spread over their bounding volume. The best hypothesis is
   locked only if its NFA is small (stricter with 3 LEDs), no competing hypothesis fits nearly
   as well ("ambiguous"), and the ring does not carry extra points off its slots (a ring of a
   different LED count).

The package, one step per module:

* :mod:`~app.geometry.ring.params` — the ring and its tolerances (:class:`RingParams`), a
  recent lock (:class:`RingPrior`), the outcomes (:class:`RingFit`, :class:`RingRejection`);
* :mod:`~app.geometry.ring.kernels` — steps 1–3 in two compiled loops per frame
  (:func:`seed_kernel`, :func:`refine_kernel`; numba, cached on disk) and the refusal's
  diagnosis (:func:`radius_only_kernel`); their numpy formulation is the reference of the
  tests (``tests/support/ring_reference.py``: the same seeds, in the same order, and the same
  hypotheses);
* :mod:`~app.geometry.ring.nfa` — step 4's number of false alarms and volumes;
* :mod:`~app.geometry.ring.measures` — slot angles and one ring's measures (the tracker's
  check);
* :mod:`~app.geometry.ring.search` — :func:`find_ring`, the Python driver.

Slot angles are measured clockwise from the camera's up direction (−y) projected on the ring
plane (:func:`app.geometry.circle_fit.plane_basis`); ids are assigned from the slot offset by
:mod:`app.geometry.led_ids`.
"""

from app.geometry.ring.kernels import (
    hypothesis_kernel,
    radius_only_kernel,
    refine_kernel,
    ring_consts,
    ring_measures_kernel,
    seed_kernel,
    slot_angles_kernel,
    slot_offset_kernel,
    slot_residuals_kernel,
)
from app.geometry.ring.measures import (
    RingMeasures,
    oriented,
    ring_measures,
    slot_angles_deg,
    slot_offset_deg,
    slot_residuals,
    view_angle_deg,
)
from app.geometry.ring.nfa import background_volume_mm3, log10_nfa, prior_volume_mm3
from app.geometry.ring.params import (
    RingFit,
    RingHypothesis,
    RingParams,
    RingPrior,
    RingRejection,
    agrees_with_prior,
)
from app.geometry.ring.search import MAX_SEEDS, STRICT_RANK, find_ring, refined_hypotheses

__all__ = [
    "MAX_SEEDS",
    "STRICT_RANK",
    "RingFit",
    "RingHypothesis",
    "RingMeasures",
    "RingParams",
    "RingPrior",
    "RingRejection",
    "agrees_with_prior",
    "background_volume_mm3",
    "find_ring",
    "hypothesis_kernel",
    "log10_nfa",
    "oriented",
    "prior_volume_mm3",
    "radius_only_kernel",
    "refine_kernel",
    "refined_hypotheses",
    "ring_consts",
    "ring_measures",
    "ring_measures_kernel",
    "seed_kernel",
    "slot_angles_deg",
    "slot_angles_kernel",
    "slot_offset_deg",
    "slot_offset_kernel",
    "slot_residuals",
    "slot_residuals_kernel",
    "view_angle_deg",
]
