"""The compiled reference of the local centroid's background-ring median: ``np.median`` of the
ring's pixels (:func:`app.vision.local_centroid_kernels.ring_median_counts` gives the same
number from a 256-bin count; ``tests/vision/test_local_centroid.py``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def ring_median(gray: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> float:  # pragma: no cover
    """Median of the pixels on the one-pixel border just outside [x0, x1) × [y0, y1),
    clipped to the image (NaN when none is inside)."""
    h, w = gray.shape
    vals = np.empty(2 * (x1 - x0 + 2) + 2 * (y1 - y0), np.float64)
    n = 0
    for y in (y0 - 1, y1):
        if 0 <= y < h:
            for x in range(max(0, x0 - 1), min(w, x1 + 1)):
                vals[n] = gray[y, x]
                n += 1
    for x in (x0 - 1, x1):
        if 0 <= x < w:
            for y in range(max(0, y0), min(h, y1)):
                vals[n] = gray[y, x]
                n += 1
    if n == 0:
        return np.nan
    return float(np.median(vals[:n]))
