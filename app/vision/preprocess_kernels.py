"""The frame statistics' compiled loops (numba, cached on disk) for eq. 10's threshold
(paper §4.1): the band maxima (the peak), the background's subsampled histogram and the
histogram of neighbouring pixels' differences (the noise), in one pass over the frame
(:func:`frame_summary`), and the background level and noise σ read off them
(:func:`frame_levels`). :mod:`app.vision.preprocess` holds the rules they serve
(:func:`~app.vision.preprocess.background_level`, :func:`~app.vision.preprocess.noise_sigma`,
:func:`~app.vision.preprocess.choose_threshold`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _histogram_row(row: np.ndarray, col_step: int, hist: np.ndarray) -> None:  # pragma: no cover
    """Add ``row[::col_step]`` to the 4 interleaved 256-bin histograms ``hist`` (4, 256)
    (interleaved: no store-to-load stall on runs of equal values)."""
    k = 0
    for x in range(0, row.shape[0], col_step):
        hist[k, row[x]] += 1
        k = (k + 1) & 3


@njit(cache=True, nogil=True)
def subsampled_histogram(
    gray: np.ndarray, row_step: int, col_step: int
) -> np.ndarray:  # pragma: no cover - compiled
    """256-bin histogram of ``gray[::row_step, ::col_step]`` (no copy of the subsample)."""
    hist = np.zeros((4, 256), np.int64)
    for y in range(0, gray.shape[0], row_step):
        _histogram_row(gray[y], col_step, hist)
    return hist[0] + hist[1] + hist[2] + hist[3]


@njit(cache=True, nogil=True)
def _histogram_rows(
    row: np.ndarray, col_step: int, hist: np.ndarray, dhist: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Add ``row[::col_step]`` to ``hist`` and, in the same loop, |I(x + 1) − I(x)| at the
    same columns (x + 1 inside the row) to ``dhist``, as :func:`subsampled_histogram` and
    :func:`difference_histogram` count them; both (4, 256) int32, one histogram per lane of
    four consecutive samples: the four increments of a step are independent, so runs of equal
    values (a flat background, a noise difference of 0 or 1) do not wait on each other's
    store."""
    last = row.shape[0] - 1
    s1, s2, s3 = col_step, 2 * col_step, 3 * col_step
    x = 0
    while x + s3 < last:  # four samples and their right neighbours, all inside the row
        a0, b0 = np.int64(row[x]), np.int64(row[x + 1])
        a1, b1 = np.int64(row[x + s1]), np.int64(row[x + s1 + 1])
        a2, b2 = np.int64(row[x + s2]), np.int64(row[x + s2 + 1])
        a3, b3 = np.int64(row[x + s3]), np.int64(row[x + s3 + 1])
        hist[0, a0] += 1
        hist[1, a1] += 1
        hist[2, a2] += 1
        hist[3, a3] += 1
        dhist[0, abs(a0 - b0)] += 1
        dhist[1, abs(a1 - b1)] += 1
        dhist[2, abs(a2 - b2)] += 1
        dhist[3, abs(a3 - b3)] += 1
        x += 4 * col_step
    while x < last:
        a, b = np.int64(row[x]), np.int64(row[x + 1])
        hist[0, a] += 1
        dhist[0, abs(a - b)] += 1
        x += col_step
    if x == last:  # the last column: no right neighbour
        hist[0, row[x]] += 1


@njit(cache=True, nogil=True)
def frame_summary(
    gray: np.ndarray, band_rows: int, row_step: int, col_step: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """One pass over the image for what the acquisition needs of the whole frame: the maximum
    of each column over bands of ``band_rows`` rows ((ceil(H / band_rows), W) uint8; their
    maximum is eq. 10's peak), the 256-bin histogram of ``gray[::row_step, ::col_step]``
    (the background level) and, on the same rows and columns, that of the differences of
    horizontally neighbouring pixels (the noise: :func:`difference_histogram`, equal count for
    count); ``row_step`` 0: no histograms, all zeros."""
    h, w = gray.shape
    nb = (h + band_rows - 1) // band_rows
    bands = np.zeros((nb, w), np.uint8)
    # per-lane counts in int32 (a lane holds at most a quarter of the sampled pixels)
    hist = np.zeros((4, 256), np.int32)
    dhist = np.zeros((4, 256), np.int32)
    for b in range(nb):
        out = bands[b]
        for y in range(b * band_rows, min(h, (b + 1) * band_rows)):
            row = gray[y]
            for x in range(w):
                if row[x] > out[x]:
                    out[x] = row[x]
            if row_step > 0 and y % row_step == 0:
                _histogram_rows(row, col_step, hist, dhist)
    hist_sum = np.zeros(256, np.int64)
    dhist_sum = np.zeros(256, np.int64)
    for k in range(4):
        for i in range(256):
            hist_sum[i] += hist[k, i]
            dhist_sum[i] += dhist[k, i]
    return bands, hist_sum, dhist_sum


@njit(cache=True, nogil=True)
def difference_histogram(
    gray: np.ndarray, row_step: int, col_step: int
) -> np.ndarray:  # pragma: no cover - compiled
    """256-bin histogram of |I(x + 1, y) − I(x, y)| over every ``row_step``-th row and every
    ``col_step``-th column (neighbouring pixels: their difference holds the noise, not the
    scene's slow variation)."""
    hist = np.zeros((4, 256), np.int64)
    for y in range(0, gray.shape[0], row_step):
        row = gray[y]
        k = 0
        for x in range(0, row.shape[0] - 1, col_step):
            a, b = int(row[x]), int(row[x + 1])
            hist[k, a - b if a >= b else b - a] += 1
            k = (k + 1) & 3
    return hist[0] + hist[1] + hist[2] + hist[3]


@njit(cache=True, nogil=True)
def frame_levels(hist: np.ndarray, dhist: np.ndarray) -> tuple[float, float]:  # pragma: no cover
    """(background level, noise σ) DN of :func:`frame_summary`'s histograms in one compiled
    call: ``preprocess.background_from_histogram(hist)[0]`` and
    ``preprocess.noise_from_histogram(dhist)``, the same numbers (tested equal; no Python
    array steps per frame)."""
    # the median bin: the first whose cumulative count reaches half the total
    half = 0.0
    for i in range(256):
        half += hist[i]
    half /= 2.0
    cum = 0
    med = 256
    for i in range(256):
        cum += hist[i]
        if cum >= half:
            med = i
            break
    # the differences' median, interpolated within its bin
    total = 0
    for i in range(256):
        total += dhist[i]
    if total == 0:
        return float(med), 0.5
    dhalf = 0.5 * float(total)
    cum = 0
    k = 256
    for i in range(256):
        if cum + dhist[i] >= dhalf:
            k = i
            break
        cum += dhist[i]
    frac = (dhalf - float(cum)) / max(float(dhist[k]), 1.0)
    median = 0.5 * frac if k == 0 else k - 0.5 + frac
    return float(med), max(1.4826 * median / np.sqrt(2.0), 0.5)
