"""Feature-point extraction (paper §4.2): one-pass connected components and eq. 11 centroids."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from app.vision.preprocess import U8Image
from app.vision.types import Blob, RejectedBlob

MAX_REJECTED_REPORTED = 100
ROI_MARGIN_PX = 48  # > the largest centroid margin (0.5·sqrt(max_area_px) + dilation)


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
    """OpenCV one-pass labelling (Algorithm 2) and the (x, y, w, h, area) stats of each label,
    computed from the foreground pixels only (same values as ``connectedComponentsWithStats``,
    whose stats pass costs a full-image scan per call)."""
    n, labels = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    stats = np.zeros((n, 5), dtype=np.int64)
    if n <= 1:
        return n, labels, stats
    nz = cv2.findNonZero(mask).reshape(-1, 2)  # (x, y), row-major: ~10× faster than np.nonzero
    xs, ys = nz[:, 0].astype(np.int64), nz[:, 1].astype(np.int64)
    lab = labels[ys, xs]
    order = np.argsort(lab, kind="stable")
    lab, xs, ys = lab[order], xs[order], ys[order]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    ids = lab[starts]
    x0 = np.minimum.reduceat(xs, starts)
    y0 = np.minimum.reduceat(ys, starts)
    stats[ids, 0] = x0
    stats[ids, 1] = y0
    stats[ids, 2] = np.maximum.reduceat(xs, starts) - x0 + 1
    stats[ids, 3] = np.maximum.reduceat(ys, starts) - y0 + 1
    stats[ids, 4] = np.diff(np.r_[starts, len(lab)])
    return n, labels, stats


def extract_blobs(
    gray: U8Image,
    mask: U8Image,
    background: float,
    gate: BlobGate | None = None,
) -> tuple[list[Blob], list[RejectedBlob]]:
    """Label ``mask`` in one pass (Algorithm 2, via OpenCV's ``connectedComponentsWithStats``)
    and compute each component's intensity-weighted centroid on ``gray`` (eq. 11).

    The centroid weights are ``P_i = gray − background`` over the component dilated by a
    margin (so the blurred fringe of the LED below the threshold is counted symmetrically),
    which gives sub-pixel accuracy; coordinates are pixel centres (u right, v down), px.
    """
    gate = gate or BlobGate()
    # Label only the bounding box of the foreground (the LEDs cover < 0.1 % of the frame),
    # widened by the largest centroid margin so that no blob's fringe is cut.
    height, width = gray.shape
    bx, by, bw, bh = cv2.boundingRect(mask)
    if bw == 0 or bh == 0:
        return [], []
    m = ROI_MARGIN_PX
    ox, oy = max(0, bx - m), max(0, by - m)
    ex, ey = min(width, bx + bw + m), min(height, by + bh + m)
    gray_roi = gray[oy:ey, ox:ex]
    n, labels, stats = _label_with_stats(mask[oy:ey, ox:ex])
    stats[:, 0] += ox
    stats[:, 1] += oy
    blobs: list[Blob] = []
    rejected: list[RejectedBlob] = []
    st = stats[1:].astype(np.int64)
    xs, ys, ws, hs, areas = st[:, 0], st[:, 1], st[:, 2], st[:, 3], st[:, 4]
    aspect = np.maximum(ws, hs) / np.maximum(1, np.minimum(ws, hs))
    fill = areas / np.maximum(1, ws * hs)
    border = (xs == 0) | (ys == 0) | (xs + ws >= width) | (ys + hs >= height)
    ok = (
        (areas >= gate.min_area_px)
        & (areas <= gate.max_area_px)
        & (aspect <= gate.max_aspect)
        & (fill >= gate.min_fill)
        & ~border
    )
    candidates = [int(i) + 1 for i in np.flatnonzero(ok)]
    for j in np.flatnonzero(~ok)[:MAX_REJECTED_REPORTED]:
        x, y, w, h, area = (int(v) for v in st[j])
        reason = _gate(area, w, h, gate) or "touches the image border"
        centre = (x + (w - 1) / 2.0, y + (h - 1) / 2.0)
        rejected.append(RejectedBlob(centroid_px=centre, area_px=area, reason=reason))
    if len(candidates) > gate.max_blobs:
        raise TooManyBlobs(len(candidates), gate.max_blobs)
    kernels: dict[int, np.ndarray] = {}
    integer_bg = float(background).is_integer() and 0 <= background <= 255
    bg_u8 = float(background) if integer_bg else 0.0
    stat_rows = stats.tolist()
    for i in candidates:
        x, y, w, h, area = stat_rows[i]
        pad = max(2, int(round(0.5 * math.sqrt(area))))
        # window in ROI coordinates
        x0, y0 = max(0, x - ox - pad), max(0, y - oy - pad)
        x1, y1 = min(ex - ox, x - ox + w + pad), min(ey - oy, y - oy + h + pad)
        lab = labels[y0:y1, x0:x1]
        comp = (lab == i).view(np.uint8)
        kernel = kernels.get(pad)
        if kernel is None:
            kernel = kernels[pad] = np.ones((2 * pad + 1, 2 * pad + 1), np.uint8)
        # Dilated support (0/1), but never a neighbouring component's pixels.
        support = cv2.dilate(comp, kernel)
        if np.count_nonzero(lab) != area:
            support[(lab != 0) & (comp == 0)] = 0
        window = gray_roi[y0:y1, x0:x1]
        if integer_bg:  # P_i = max(gray − background, 0) on the support, exact in uint8
            weights = cv2.multiply(cv2.subtract(window, bg_u8), support)  # type: ignore[call-overload]
            mom = cv2.moments(weights)
            mass, m10, m01 = mom["m00"], mom["m10"], mom["m01"]
        else:
            wf = window.astype(np.float64) - background
            wf[support == 0] = 0.0
            np.clip(wf, 0.0, None, out=wf)
            mass = float(wf.sum())
            m10 = float(wf.sum(axis=0) @ np.arange(wf.shape[1], dtype=np.float64))
            m01 = float(wf.sum(axis=1) @ np.arange(wf.shape[0], dtype=np.float64))
        if mass <= 0:
            cu, cv = x + (w - 1) / 2.0, y + (h - 1) / 2.0
        else:
            cu = m10 / mass + x0 + ox
            cv = m01 / mass + y0 + oy
        peak = float(cv2.minMaxLoc(window, comp)[1])
        blobs.append(
            Blob(centroid_px=(cu, cv), area_px=area, bbox=(x, y, w, h), peak=peak, mass=mass)
        )
    return blobs, rejected
