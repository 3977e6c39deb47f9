"""The acquisition's cheaper record building equals the per-blob one: ``local_blobs`` gives the
same :class:`~app.vision.types.Blob` records as ``local_blob`` per blob (measured and
unmeasured local centroids alike)."""

from __future__ import annotations

import numpy as np

from app.vision.local_centroid import LocalCentroidConfig, box_table, local_blob, local_blobs
from app.vision.local_centroid_kernels import local_centroids


def _image() -> np.ndarray:
    """Gaussian LEDs of several sizes and brightnesses on a noisy background, one flat patch."""
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:120, 0:160].astype(np.float64)
    img = 20.0 + rng.normal(0.0, 1.5, y.shape)
    for cx, cy, s, pk in (
        (30.3, 25.6, 1.2, 180.0),
        (80.1, 60.4, 2.5, 300.0),
        (130.7, 95.2, 0.8, 90.0),
    ):
        img += pk * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    img[92:112, 0:16] = 20.0  # flat: no contrast
    return np.asarray(np.clip(np.round(img), 0, 255), dtype=np.uint8)


def test_local_blobs_equal_local_blob_per_blob() -> None:
    gray = _image()
    # (x, y, w, h, area) and (u, v, mass, peak) rows as the extraction gives them; the last
    # box holds no contrast (its local centroid is not measured: eq. 11's kept, σ NaN)
    stats = np.array(
        [[28, 24, 5, 5, 17], [76, 56, 9, 9, 61], [129, 94, 3, 3, 7], [5, 100, 3, 3, 9]], np.int64
    )
    cents = [[30.2, 25.5, 900.0, 200.0], [80.0, 60.5, 5000.0, 255.0], [130.6, 95.1, 100.0, 110.0]]
    cents.append([6.0, 101.0, 4.0, 24.0])
    table = local_centroids(gray, box_table(stats), LocalCentroidConfig().params())
    assert np.isnan(table[-1, 0]) and not np.isnan(table[:-1, 0]).any()
    want = [
        local_blob((cu, cv), area, (x, y, w, h), pk, m, None, row)
        for (x, y, w, h, area), (cu, cv, m, pk), row in zip(
            stats.tolist(), cents, table.tolist(), strict=True
        )
    ]
    got = local_blobs(stats.tolist(), cents, table)
    assert repr(got) == repr(want)  # field for field, NaN included
    for a, b in zip(got, want, strict=True):
        assert [type(v) for v in vars(a).values()] == [type(v) for v in vars(b).values()]
