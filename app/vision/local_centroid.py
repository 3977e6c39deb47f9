"""Local-support LED centroids that survive reflections (a refinement of paper eq. 11).

Eq. 11 weights each pixel by its brightness above the frame's *global* background over the
blob dilated by a margin of ≈ ½√area px (:mod:`app.vision.blob_kernels`). On polished metal
in daylight that margin takes in the LED's own reflection on the rim, glint streaks and bright
sky, and these differ between the two views: a disparity error of a few tenths of a pixel.
Here each detected blob is measured again on its own terms:

* **local background** ``b``: the median of a one-pixel ring of pixels just outside a window
  around the blob (the blob's box grown by ``pad`` = max(3, ⌈½·max(w, h)⌉) px);
* **local peak** ``p``: the brightest pixel of the blob's box (``saturated_dn`` and above
  count as saturated: a flat top);
* **support**: the pixels ≥ ``b + support_frac·(p − b)`` 8-connected to the peak pixel inside
  the window — relative to the blob's own peak, so the same rule holds in both images whatever
  their exposure, and a reflection or glint dimmer than the level, or separated from the LED by
  a darker gap, is not part of it. A saturated blob's level is taken from the saturation level
  (its flat top and the flanks above the level);
* **centroid**: Σ wᵢ·xᵢ / Σ wᵢ with wᵢ = Iᵢ − level over the support (pixel centres, px);
* **noise** (the error bound's input, :mod:`app.geometry.uncertainty`): first-order
  propagation of independent pixel noise through the weighted mean,
  σ_u² = Σ σᵢ²·(uᵢ − ū)² / (Σ wᵢ)² with σᵢ² = σ_read² + k_shot·max(Iᵢ − b, 0) (DN²; a saturated
  pixel carries no noise), plus a floor ``floor_px`` in quadrature for what the model does not
  describe (demosaicing, blur, sub-pixel structure). With ``image_noise`` the image's own
  errors are measured too: each support pixel's difference A from the blob mirrored through
  its centroid (bilinear), σ_u² = max(model, Σ ½Aᵢ²·(uᵢ − ū)²) / (Σ wᵢ)² — an LED's image is
  point-symmetric, so A is what compression, blur, demosaicing or a saturated edge did to it.

A support that reaches the window's edge (a blob merged with something larger) or a blob with
no contrast keeps its eq. 11 centroid and gets σ = NaN: the caller treats it as unmeasured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.vision.local_centroid_kernels import (
    ATTEMPTS,
    OUT_BACKGROUND,
    OUT_COLUMNS,
    OUT_MODEL_SIGMA_U,
    OUT_MODEL_SIGMA_V,
    OUT_SIGMA_U,
    OUT_SIGMA_V,
    OUT_U,
    OUT_V,
    OUT_X0,
    OUT_X1,
    OUT_Y0,
    OUT_Y1,
    local_centroids,
)
from app.vision.types import Blob

# the columns of a :func:`local_centroids` row that a blob keeps, in this order
_MEASURED_COLUMNS = [OUT_U, OUT_V, OUT_SIGMA_U, OUT_SIGMA_V, OUT_BACKGROUND]
_MEASURED_COLUMNS += [OUT_MODEL_SIGMA_U, OUT_MODEL_SIGMA_V]


@dataclass(frozen=True)
class LocalCentroidConfig:
    """Parameters of the local-support centroid (DN, px)."""

    enabled: bool = True  # False: the paper's eq. 11 centroid as is
    support_frac: float = 0.2  # support: pixels ≥ b + frac·(peak − b)
    saturated_dn: float = 250.0  # a pixel at or above this is saturated (flat top)
    read_sigma_dn: float = 1.5  # pixel noise floor (DN, 1σ)
    shot_var_per_dn: float = 0.032  # shot-noise variance per DN of signal (DN²/DN ≈ 255/full well)
    floor_px: float = 0.03  # centroid error the noise model leaves out (px, 1σ)
    weights_from_level: bool = True  # weights I − level (True) or I − local background
    # σ also from the image itself: the blob's residuals to its own profile mirrored through
    # the centroid (compression, blur, demosaicing, saturated edges), the larger of that and
    # the sensor model's (which the blob keeps apart: rival ring hypotheses are ranked by it
    # first, app.geometry.ring.find_ring); False: the sensor model only
    image_noise: bool = True
    # colour input: each blob found on the green excess is measured on eq. 9's gray as well
    # (full resolution where JPEG and MJPG keep the chroma at half), and the measurement with
    # the smaller σ is kept (prefer_sharper); False: the green excess only
    gray_too: bool = True

    def params(self) -> NDArray[np.float64]:
        return np.array(
            [
                self.support_frac,
                self.saturated_dn,
                self.read_sigma_dn,
                self.shot_var_per_dn,
                self.floor_px,
                1.0 if self.weights_from_level else 0.0,
                1.0 if self.image_noise else 0.0,
            ],
            dtype=np.float64,
        )

    def kernel_params(self) -> NDArray[np.float64]:
        """:meth:`params` for the labelling calls (``blob_kernels.detect_in_boxes``,
        ``window_blobs``), empty when disabled (eq. 11 only)."""
        return self.params() if self.enabled else np.empty(0)


def window_pad_px(w: int, h: int) -> int:
    """Margin (px) of the local window around a blob box of w × h px."""
    return max(3, (max(w, h) + 1) // 2)


def measure_blobs(
    gray: NDArray[np.uint8], blobs: list[Blob], cfg: LocalCentroidConfig
) -> NDArray[np.float64]:
    """:func:`local_centroids` for these blobs (rows aligned with ``blobs``)."""
    if not blobs:
        return np.zeros((0, OUT_COLUMNS))
    boxes = np.array([b.bbox for b in blobs], dtype=np.int64).reshape(-1, 4)
    return np.asarray(local_centroids(gray, boxes, cfg.params()))


def read_rects(blobs: list[Blob], width: int, height: int) -> list[tuple[int, int, int, int]]:
    """Per blob (x0, y0, x1, y1), exclusive: the pixels :func:`local_centroids` may read for
    it (its box grown by its widest window, ``ATTEMPTS``' largest pad multiple, and the
    background ring), within the image. An image filled only there measures the blobs as
    the whole image does."""
    grow = int(ATTEMPTS[:, 1].max())
    out = []
    for b in blobs:
        bx, by, bw, bh = b.bbox
        m = grow * window_pad_px(bw, bh) + 2
        out.append(
            (max(0, bx - m), max(0, by - m), min(width, bx + bw + m), min(height, by + bh + m))
        )
    return out


def local_blob(
    centroid_px: tuple[float, float],
    area_px: int,
    bbox: tuple[int, int, int, int],
    peak: float,
    mass: float,
    color_bgr: tuple[float, ...] | None,
    row: list[float],
) -> Blob:
    """A blob with its local centroid, σ and local background from ``row`` (a
    :func:`local_centroids` row as a list); eq. 11's ``centroid_px`` and σ = NaN where the
    local centroid is not measured."""
    u = row[OUT_U]
    if u == u:  # not NaN: measured
        return Blob(
            (u, row[OUT_V]),
            area_px,
            bbox,
            peak,
            mass,
            color_bgr,
            (row[OUT_SIGMA_U], row[OUT_SIGMA_V]),
            row[OUT_BACKGROUND],
            (row[OUT_MODEL_SIGMA_U], row[OUT_MODEL_SIGMA_V]),
        )
    nan = float("nan")
    return Blob(centroid_px, area_px, bbox, peak, mass, color_bgr, (nan, nan), row[OUT_BACKGROUND])


def local_blobs(
    stats: list[list[int]], cents: list[list[float]], table: NDArray[np.float64]
) -> list[Blob]:
    """:func:`local_blob` of each blob of a compiled extraction — its (x, y, w, h, area) and
    (u, v, mass, peak) rows as lists, and its :func:`local_centroids` row — built in one pass
    (the same records; the per-blob call and the unused columns left out)."""
    nan = float("nan")
    return [
        Blob((u, v), area, (x, y, w, h), pk, m, None, (su, sv), bg, (mu, mv))
        if u == u  # not NaN: measured
        else Blob((cu, cv), area, (x, y, w, h), pk, m, None, (nan, nan), bg)
        for (x, y, w, h, area), (cu, cv, m, pk), (u, v, su, sv, bg, mu, mv) in zip(
            stats, cents, table[:, _MEASURED_COLUMNS].tolist(), strict=True
        )
    ]


def with_local_centroids(blobs: list[Blob], table: NDArray[np.float64]) -> list[Blob]:
    """The blobs with the local centroids, σ and local background of ``table``
    (:func:`measure_blobs`; eq. 11's centroid and σ = NaN where it is not measured)."""
    # the constructor, not dataclasses.replace (≈ 4× cheaper per blob; same fields)
    return [
        local_blob(b.centroid_px, b.area_px, b.bbox, b.peak, b.mass, b.color_bgr, row)
        for b, row in zip(blobs, table.tolist(), strict=True)
    ]


def box_table(boxes: NDArray[np.int64]) -> NDArray[np.int64]:
    """The (x, y, w, h) columns of (k, ≥ 4) int64 box rows, as :func:`local_centroids` takes
    them (C-contiguous)."""
    return np.ascontiguousarray(boxes[:, :4])


def refine_blobs(
    gray: NDArray[np.uint8], blobs: list[Blob], cfg: LocalCentroidConfig
) -> list[Blob]:
    """The blobs with their local centroids (:func:`with_local_centroids`);
    ``cfg.enabled`` False: unchanged (the paper's eq. 11)."""
    if not cfg.enabled or not blobs:
        return blobs
    return with_local_centroids(blobs, measure_blobs(gray, blobs, cfg))


def _sigma2(s: tuple[float, float] | None) -> float:
    """½(σ_u² + σ_v²) of a blob's centroid σ (px²); NaN when not measured."""
    return math.nan if s is None else 0.5 * (s[0] * s[0] + s[1] * s[1])


def prefer_sharper(
    blobs: list[Blob],
    table: NDArray[np.float64],
    inside: tuple[int, int, int, int] | list[tuple[int, int, int, int]] | None = None,
) -> list[Blob]:
    """Each blob, or its measurement in ``table`` (:func:`measure_blobs` of the same blobs on
    another image of the same frame: eq. 9's gray beside the green excess) where that one's σ
    is the smaller; the blob's own local background is kept (the appearance test compares it
    with its own peak). ``inside``: per blob (x0, y0, x1, y1), the pixels the new measurement
    may read (a tracker window); one read outside keeps the blob as it is.

    Both are unbiased estimates of the same LED centre from the same photons, so the smaller
    σ is the better one: on colour JPEG the green excess G − max(B, R) is built from chroma
    at half resolution and its blobs are lopsided (σ 2–4× gray's); in sun the gray LED can sit
    in the sky's level and its σ is the larger."""
    out = []
    for k, (b, row) in enumerate(zip(blobs, table.tolist(), strict=True)):
        alt = row[OUT_U]
        if alt != alt:  # NaN: not measured
            out.append(b)
            continue
        if inside is not None:
            x0, y0, x1, y1 = inside[k] if isinstance(inside, list) else inside
            if row[OUT_X0] < x0 or row[OUT_Y0] < y0 or row[OUT_X1] > x1 or row[OUT_Y1] > y1:
                out.append(b)
                continue
        new = local_blob(b.centroid_px, b.area_px, b.bbox, b.peak, b.mass, b.color_bgr, row)
        own = _sigma2(b.centroid_sigma_px)
        if own == own and not _sigma2(new.centroid_sigma_px) < own:
            out.append(b)
            continue
        out.append(
            Blob(
                new.centroid_px,
                b.area_px,
                b.bbox,
                b.peak,
                b.mass,
                b.color_bgr,
                new.centroid_sigma_px,
                b.local_bg,
                new.model_sigma_px,
            )
        )
    return out
