"""Feature-point extraction (paper §4.2): one-pass connected components and eq. 11 centroids."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from app.types import UInt8Array
from app.vision.blob_kernels import detect_in_boxes, extract_in_mask
from app.vision.bright_region_kernels import hot_tile_boxes
from app.vision.local_centroid import LocalCentroidConfig, local_blobs
from app.vision.preprocess_kernels import frame_summary
from app.vision.types import Blob, RejectedBlob

MAX_REJECTED_REPORTED = 100
_NO_PARAMS = np.empty(0)  # detect_in_boxes without local centroids
ROI_MARGIN_PX = 48  # > the largest centroid margin (0.5·sqrt(max_area_px) + dilation)

Box = tuple[int, int, int, int]  # (x0, y0, x1, y1) px, half-open


@dataclass(frozen=True)
class BlobGate:
    """Area/shape limits that a component must pass to be an LED candidate."""

    min_area_px: int = 3
    max_area_px: int = 6000
    max_aspect: float = 2.5  # bounding-box long side / short side
    min_fill: float = 0.45  # area / bounding-box area (a disc fills π/4 ≈ 0.785)
    max_blobs: int = 512  # more candidates than this: refuse the frame (never drop LEDs)


class TooManyBlobs(ValueError):
    """More LED candidates than ``BlobGate.max_blobs``: the frame is refused, not trimmed."""

    def __init__(self, count: int, limit: int) -> None:
        super().__init__(
            f"{count} LED-sized bright blobs (more than {limit}): refusing the frame rather "
            f"than dropping candidates (flooded or overexposed image?)"
        )
        self.count = count


def _gate(area: int, w: int, h: int, gate: BlobGate) -> str | None:
    if area < gate.min_area_px:
        return f"area {area} px < {gate.min_area_px} px"
    if area > gate.max_area_px:
        return f"area {area} px > {gate.max_area_px} px"
    aspect = max(w, h) / max(1, min(w, h))
    if aspect > gate.max_aspect:
        return f"elongated (aspect {aspect:.1f} > {gate.max_aspect})"
    fill = area / float(w * h)
    if fill < gate.min_fill:
        return f"not compact (fill {fill:.2f} < {gate.min_fill})"
    return None


def gate_array(gate: BlobGate) -> np.ndarray:
    """(min area px, max area px, max aspect, min fill) for the compiled loops."""
    return np.array(
        [gate.min_area_px, gate.max_area_px, gate.max_aspect, gate.min_fill], np.float64
    )


def _blobs(
    found: tuple[np.ndarray, np.ndarray, np.ndarray, int],
    gate: BlobGate,
    local: np.ndarray | None = None,
) -> tuple[list[Blob], list[RejectedBlob]]:
    """Blobs and rejected blobs from a compiled extraction's outputs (kept rows, their
    centroids, rejected rows, the number passing the gate); raises ``TooManyBlobs``. With
    ``local`` (the kept blobs' local centroids, :mod:`app.vision.local_centroid`), each blob
    is built once with its local-support centroid."""
    kept, cents, rej, count = found
    if count > gate.max_blobs:
        raise TooManyBlobs(int(count), gate.max_blobs)
    if local is not None and len(kept):
        blobs = local_blobs(kept.tolist(), cents.tolist(), local)
    else:
        blobs = [
            Blob((cu, cv), area, (x, y, w, h), pk, m)
            for (x, y, w, h, area), (cu, cv, m, pk) in zip(
                kept.tolist(), cents.tolist(), strict=True
            )
        ]
    return blobs, _rejected_blobs(rej, gate)


def extract_blobs(
    gray: UInt8Array,
    mask: UInt8Array,
    background: float,
    gate: BlobGate | None = None,
    crop: bool = True,
) -> tuple[list[Blob], list[RejectedBlob]]:
    """Label ``mask`` in one pass (Algorithm 2, OpenCV's connected components) and compute each
    component's intensity-weighted centroid on ``gray`` (eq. 11).

    The centroid weights are ``P_i = gray − background`` over the component dilated by a
    margin (so the blurred fringe of the LED below the threshold is counted symmetrically),
    which gives sub-pixel accuracy; coordinates are pixel centres (u right, v down), px.
    With ``crop``, only the bounding box of the foreground (widened by the largest centroid
    margin) is labelled; without, the whole (small) mask, e.g. a tracker's mosaic. One
    compiled call (:func:`app.vision.blob_kernels.extract_in_mask`).
    """
    gate = gate or BlobGate()
    height, width = gray.shape
    x0, y0, x1, y1 = 0, 0, width, height
    if crop:
        bx, by, bw, bh = cv2.boundingRect(mask)
        if bw == 0 or bh == 0:
            return [], []
        m = ROI_MARGIN_PX
        x0, y0 = max(0, bx - m), max(0, by - m)
        x1, y1 = min(width, bx + bw + m), min(height, by + bh + m)
    sub = np.ascontiguousarray(mask[y0:y1, x0:x1])
    found = extract_in_mask(
        gray,
        sub,
        x0,
        y0,
        float(background),
        gate_array(gate),
        gate.max_blobs,
        MAX_REJECTED_REPORTED,
    )
    return _blobs(found, gate)


BAND_ROWS = 16  # rows per band of :func:`band_maxima` (the tile side of :func:`bright_boxes`)


def band_maxima(gray: UInt8Array) -> np.ndarray:
    """Maximum of each column over bands of ``BAND_ROWS`` rows: (ceil(H / 16), W) uint8, one
    compiled pass over the image (its overall max is eq. 10's peak;
    :func:`app.vision.preprocess_kernels.frame_summary`, which also gives the background's histogram
    in the same pass)."""
    return np.asarray(frame_summary(gray, BAND_ROWS, 0, 1)[0])


def bright_boxes(gray: UInt8Array, threshold: int, bands: np.ndarray | None = None) -> list[Box]:
    """Boxes (x0, y0, x1, y1, half-open, px) that together hold every pixel ≥ ``threshold``:
    the 16×16-px tiles whose maximum reaches the threshold (from :func:`band_maxima`), grouped
    into 8-connected clusters, each cluster's box shrunk to its bright pixels — no full-frame
    threshold, median or labelling (one compiled pass over the tiles and the clusters)."""
    if bands is None:
        bands = band_maxima(gray)
    boxes = hot_tile_boxes(gray, np.ascontiguousarray(bands), BAND_ROWS, int(threshold))
    return [(int(r[0]), int(r[1]), int(r[2]), int(r[3])) for r in boxes.tolist()]


def detect_blobs(
    gray: UInt8Array,
    threshold: int,
    background: float,
    gate: BlobGate | None = None,
    median_ksize: int = 3,
    bands: np.ndarray | None = None,
    centroid: LocalCentroidConfig | None = None,
) -> tuple[list[Blob], list[RejectedBlob]]:
    """Eq. 10 binarisation, the median filter, labelling and eq. 11 centroids, done only
    inside :func:`bright_boxes` (grown by each blob's centroid margin): the same blobs as
    ``extract_blobs(gray, median_filter(binarize(gray, threshold)), ...)`` on the whole frame,
    at a fraction of the cost when the bright pixels are few.

    One compiled call (:func:`app.vision.blob_kernels.detect_in_boxes`) does it box by box:
    each grown box's edge is background for ≥ the median's reach, so neither the filter nor
    8-connectivity couples neighbouring boxes, and the box edge replicated stands for the
    median filter's border handling at the image edge (inside the image it is background
    anyway). Blobs come box by box, in raster order within a box. ``centroid`` (enabled):
    each blob with its local-support centroid measured in the same call (``refine_blobs`` of
    the eq. 11 blobs, the same blobs, built once), eq. 11 computed only where the local
    centroid is not measured (elsewhere the blob's eq. 11 ``mass`` is NaN: not computed)."""
    gate = gate or BlobGate()
    if bands is None:
        bands = band_maxima(gray)
    local_on = centroid is not None and centroid.enabled
    kept, cents, rej, count, local = detect_in_boxes(
        gray,
        np.ascontiguousarray(bands),
        BAND_ROWS,
        int(threshold),
        int(median_ksize),
        float(background),
        gate_array(gate),
        gate.max_blobs,
        MAX_REJECTED_REPORTED,
        centroid.kernel_params() if centroid is not None else _NO_PARAMS,
    )
    return _blobs((kept, cents, rej, count), gate, local if local_on else None)


def _rejected_blobs(st: np.ndarray, gate: BlobGate) -> list[RejectedBlob]:
    """The first ``MAX_REJECTED_REPORTED`` rejected (x, y, w, h, area) rows with their reasons."""
    rejected = []
    for x, y, w, h, area in st[:MAX_REJECTED_REPORTED].tolist():
        reason = _gate(area, w, h, gate) or "touches the image border"
        centre = (x + (w - 1) / 2.0, y + (h - 1) / 2.0)
        rejected.append(RejectedBlob(centroid_px=centre, area_px=area, reason=reason))
    return rejected
