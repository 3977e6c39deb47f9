"""Robust dropping of outlier views in a checkerboard calibration.

While a view's RMS reprojection error ``e`` (px, both cameras) has a robust z-score
``0.6745 · (e − median) / MAD > 3.5`` (Iglewicz–Hoaglin) *and* ``e > 2 · median`` *and*
``e > median + 0.1 px``, the worst such view is dropped and the joint refinement repeated —
at most :data:`MAX_DROP_FRACTION` of the views (the loop is in
:func:`~app.calibration.stereo_calibration.calibrate_from_detections`).
"""

from __future__ import annotations

import math

import numpy as np

from app.types import FloatArray

OUTLIER_Z = 3.5  # robust z-score threshold (Iglewicz & Hoaglin)
OUTLIER_RATIO = 2.0  # ... and at least this multiple of the median view RMS
OUTLIER_MIN_EXCESS_PX = 0.1  # ... and at least this much above the median (px)
MAX_DROP_FRACTION = 0.25


def robust_outlier(errors: FloatArray) -> tuple[int, float] | None:
    """Index and robust z-score of the worst view if it is an outlier, else None.

    Rule: z = 0.6745·(e − median)/MAD > ``OUTLIER_Z`` (3.5, Iglewicz & Hoaglin's modified
    z-score), e > ``OUTLIER_RATIO`` × median and e − median > ``OUTLIER_MIN_EXCESS_PX``
    (so that a set of uniformly tight views with a tiny MAD drops nothing)."""
    e = np.asarray(errors, dtype=np.float64)
    med = float(np.median(e))
    mad = float(np.median(np.abs(e - med)))
    k = int(np.argmax(e))
    z = 0.6745 * (e[k] - med) / mad if mad > 0 else (math.inf if e[k] > med else 0.0)
    if z > OUTLIER_Z and e[k] > OUTLIER_RATIO * med and e[k] - med > OUTLIER_MIN_EXCESS_PX:
        return k, float(z)
    return None
