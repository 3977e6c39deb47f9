"""numpy/scipy formulations of :mod:`app.vision.bright_region_kernels` (what the compiled
loops must equal)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def hot_tile_boxes_reference(
    gray: np.ndarray, bands: np.ndarray, band_rows: int, threshold: int
) -> np.ndarray:
    """The ``band_rows``-px tiles whose band maximum reaches ``threshold``, 8-connected
    clusters in raster order of their first tile, each cluster's tile box shrunk to its
    pixels ≥ ``threshold`` (k, 4: x0, y0, x1, y1 half-open)."""
    h, w = gray.shape
    t = band_rows
    nb, nt = bands.shape[0], (w + t - 1) // t
    padded = np.zeros((nb, nt * t), np.int64)
    padded[:, :w] = bands
    tile_max = padded.reshape(nb, nt, t).max(axis=2)
    hot = tile_max >= threshold
    labels, k = ndimage.label(hot, structure=np.ones((3, 3), bool))
    out = np.zeros((k, 4), np.int64)
    for c in range(1, k + 1):
        ty, tx = np.nonzero(labels == c)
        x0, y0 = tx.min() * t, ty.min() * t
        x1, y1 = min(w, (tx.max() + 1) * t), min(h, (ty.max() + 1) * t)
        ys, xs = np.nonzero(gray[y0:y1, x0:x1].astype(np.int64) >= threshold)
        if len(ys):
            out[c - 1] = (x0 + xs.min(), y0 + ys.min(), x0 + xs.max() + 1, y0 + ys.max() + 1)
        else:  # (cannot happen: a hot tile holds a pixel ≥ threshold) bright_box's empty box
            out[c - 1] = (x1, y1, 0, 0)
    return out
