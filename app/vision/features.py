"""Feature-point extraction (paper §4.2): one-pass connected components and eq. 11 centroids."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from app.vision.blob_kernels import (
    centroid_table,
    foreground_pixels,
    gate_mask,
    grow_and_merge_boxes,
    hot_tile_boxes,
    label_pixels,
    pack_boxes,
)
from app.vision.preprocess import U8Image
from app.vision.types import Blob, RejectedBlob

MAX_REJECTED_REPORTED = 100
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


def _label_with_stats(mask: U8Image) -> tuple[int, np.ndarray, np.ndarray]:
    """Algorithm 2 (one-pass connected components, 8-connectivity) over the foreground pixels
    only (compiled: a scan eight pixels at a time, then union–find): (n, int32 labels, (n, 5)
    int64 stats rows x, y, w, h, area) — the values of ``cv2.connectedComponentsWithStats``."""
    flat = np.ascontiguousarray(mask).reshape(-1)
    words = flat[: flat.size - flat.size % 8].view(np.uint64)
    xy = foreground_pixels(flat, words, mask.shape[1])
    labels = np.zeros(mask.shape, np.int32)
    if len(xy) == 0:
        return 1, labels, np.zeros((1, 5), dtype=np.int64)
    stats = label_pixels(xy, labels)
    return len(stats), labels, stats


def extract_blobs(
    gray: U8Image,
    mask: U8Image,
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
    margin) is labelled; without, the whole (small) mask, e.g. a tracker's mosaic.
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
    n, labels, stats = _label_with_stats(mask[y0:y1, x0:x1])
    if n <= 1:
        return [], []
    st = stats[1:].copy()
    st[:, 0] += x0
    st[:, 1] += y0
    ok, rejected = _gate_components(st, (width, height), gate)
    kept = np.flatnonzero(ok)
    if len(kept) > gate.max_blobs:
        raise TooManyBlobs(len(kept), gate.max_blobs)
    boxes = np.array([[0, 0, x1 - x0, y1 - y0, x0, y0]], np.int64)
    table = _candidate_table(kept + 1, st[kept], np.repeat(boxes, len(kept), axis=0))
    return _centroids(gray, labels, table, background), rejected


BAND_ROWS = 16  # rows per band of :func:`band_maxima` (2⁴: its tree of pair maxima)


def band_maxima(gray: U8Image) -> np.ndarray:
    """Maximum of each column over bands of ``BAND_ROWS`` rows: (ceil(H / 16), W) uint8, one
    vectorised pass over the image (its overall max is eq. 10's peak)."""
    h, w = gray.shape
    full = h - h % BAND_ROWS
    out: np.ndarray = gray[:full]
    for _ in range(4):  # 16 = 2⁴ rows: a tree of row-pair maxima (SIMD, ~1.7× numpy's max)
        out = cv2.max(out[0::2], out[1::2])
    if full < h:
        out = np.vstack([out, gray[full:].max(axis=0, keepdims=True)])
    return np.asarray(out)


def bright_boxes(gray: U8Image, threshold: int, bands: np.ndarray | None = None) -> list[Box]:
    """Boxes (x0, y0, x1, y1, half-open, px) that together hold every pixel ≥ ``threshold``:
    the 16×16-px tiles whose maximum reaches the threshold (from :func:`band_maxima`), grouped
    into 8-connected clusters, each cluster's box shrunk to its bright pixels — no full-frame
    threshold, median or labelling (one compiled pass over the tiles and the clusters)."""
    if bands is None:
        bands = band_maxima(gray)
    boxes = hot_tile_boxes(gray, np.ascontiguousarray(bands), BAND_ROWS, int(threshold))
    return [(int(r[0]), int(r[1]), int(r[2]), int(r[3])) for r in boxes.tolist()]


def _grow_and_merge(boxes: list[Box], width: int, height: int, ksize: int) -> list[Box]:
    """Each box widened by the largest centroid margin a blob inside it can need (0.5·√area,
    area ≤ the box's) plus the median filter's reach, clipped; overlapping boxes merged
    (compiled: :func:`app.vision.blob_kernels.grow_and_merge_boxes`)."""
    if not boxes:
        return []
    merged = grow_and_merge_boxes(np.array(boxes, dtype=np.int64), width, height, ksize // 2 + 2)
    return [(int(r[0]), int(r[1]), int(r[2]), int(r[3])) for r in merged.tolist()]


def detect_blobs(
    gray: U8Image,
    threshold: int,
    background: float,
    gate: BlobGate | None = None,
    median_ksize: int = 3,
    bands: np.ndarray | None = None,
) -> tuple[list[Blob], list[RejectedBlob]]:
    """Eq. 10 binarisation, the median filter, labelling and eq. 11 centroids, done only
    inside :func:`bright_boxes` (grown by each blob's centroid margin): the same blobs as
    ``extract_blobs(gray, median_filter(binarize(gray, threshold)), ...)`` on the whole frame,
    at a fraction of the cost when the bright pixels are few."""
    gate = gate or BlobGate()
    height, width = gray.shape
    boxes = _grow_and_merge(bright_boxes(gray, threshold, bands), width, height, median_ksize)
    if not boxes:
        return [], []
    # every box into one mosaic (shelves of boxes side by side): one threshold, median and
    # labelling call for all. Each box's edge is background for ≥ the median's reach, so
    # neither the filter nor 8-connectivity couples neighbouring boxes.
    # A ring of r px replicated around each box stands for the median filter's border
    # handling at the image edge (inside the image, the box's edge is background anyway).
    r = median_ksize // 2
    placed, mh, mw = _shelf_pack([(x0, y0, x1 + 2 * r, y1 + 2 * r) for x0, y0, x1, y1 in boxes])
    places = [(px + r, py + r) for px, py in placed]
    pb, bb = np.array(places, np.int64), np.array(boxes, np.int64)
    mosaic, owner = pack_boxes(gray, bb, pb, r, (mh, mw))
    _, binary = cv2.threshold(mosaic, threshold - 1, 255, cv2.THRESH_BINARY)
    mask = np.asarray(
        cv2.medianBlur(binary, median_ksize) if median_ksize > 1 else binary, dtype=np.uint8
    )
    if r:
        mask[owner < 0] = 0  # the replicated rings are not image pixels
    n, labels, st = _label_with_stats(mask)
    if n <= 1:
        return [], []
    st = st[1:, :5].astype(np.int64)
    k_of = owner[st[:, 1], st[:, 0]]  # the box holding each component (its bbox corner)
    st[:, 0] += bb[k_of, 0] - pb[k_of, 0]  # mosaic → image px
    st[:, 1] += bb[k_of, 1] - pb[k_of, 1]
    ok, rejected = _gate_components(st, (width, height), gate)
    kept = np.flatnonzero(ok)
    if len(kept) > gate.max_blobs:
        raise TooManyBlobs(len(kept), gate.max_blobs)
    # each box's region in the label mosaic and its origin in the image
    regions = np.column_stack([pb, pb + bb[:, 2:4] - bb[:, 0:2], bb[:, 0:2]])
    table = _candidate_table(kept + 1, st[kept], regions[k_of[kept]])
    return _centroids(gray, labels, table, background), rejected


def _shelf_pack(boxes: list[Box]) -> tuple[list[tuple[int, int]], int, int]:
    """Top-left mosaic position of each box (shelf packing, tallest first): (places, H, W)."""
    sizes = [(x1 - x0, y1 - y0) for x0, y0, x1, y1 in boxes]
    limit = max(1024, max(w for w, _ in sizes))
    places: list[tuple[int, int]] = [(0, 0)] * len(boxes)
    x = y = shelf_h = width = 0
    for k in sorted(range(len(boxes)), key=lambda i: -sizes[i][1]):
        w, h = sizes[k]
        if x + w > limit:  # next shelf
            y += shelf_h
            x = shelf_h = 0
        places[k] = (x, y)
        x += w
        shelf_h = max(shelf_h, h)
        width = max(width, x)
    return places, y + shelf_h, width


def _gate_components(
    st: np.ndarray, size: tuple[int, int], gate: BlobGate
) -> tuple[np.ndarray, list[RejectedBlob]]:
    """Area/aspect/fill/border gate on (x, y, w, h, area) rows (image px): (kept mask, the
    first ``MAX_REJECTED_REPORTED`` rejected components with their reasons)."""
    width, height = size
    ok = gate_mask(
        np.ascontiguousarray(st[:, :5], dtype=np.int64),
        width,
        height,
        gate.min_area_px,
        gate.max_area_px,
        float(gate.max_aspect),
        float(gate.min_fill),
    )
    rejected = []
    for x, y, w, h, area in st[~ok][:MAX_REJECTED_REPORTED].tolist():
        reason = _gate(area, w, h, gate) or "touches the image border"
        centre = (x + (w - 1) / 2.0, y + (h - 1) / 2.0)
        rejected.append(RejectedBlob(centroid_px=centre, area_px=area, reason=reason))
    return ok, rejected


def _candidate_table(labels: np.ndarray, stats: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Rows of :data:`app.vision.blob_kernels.CAND_COLUMNS`: label, (x, y, w, h, area) in
    image px, the region (lx, ly, lx1, ly1) of its box in the label image and that box's
    origin (ox, oy) in the image (``boxes`` rows)."""
    return np.column_stack([labels, stats[:, :5], boxes]).astype(np.int64)


def _centroids(
    gray: U8Image, labels: np.ndarray, table: np.ndarray, background: float
) -> list[Blob]:
    """Eq. 11 centroid of each candidate row (:func:`_candidate_table`) over its dilated
    support (px); the loop over candidates is compiled
    (:func:`app.vision.blob_kernels.centroid_table`)."""
    if len(table) == 0:
        return []
    res = centroid_table(gray, labels, np.ascontiguousarray(table), float(background)).tolist()
    return [
        Blob((cu, cv), area, (x, y, w, h), pk, m)
        for (_, x, y, w, h, area, *_rest), (cu, cv, m, pk) in zip(table.tolist(), res, strict=True)
    ]
