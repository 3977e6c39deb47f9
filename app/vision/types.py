"""Typed records that flow through the navigation pipeline (paper §4–5)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.types import FloatArray


@dataclass(frozen=True)
class Blob:
    """One bright connected component (a candidate LED image), eq. 11 centroid in px."""

    centroid_px: tuple[float, float]  # (u, v), intensity-weighted, distorted image coords
    area_px: int
    bbox: tuple[int, int, int, int]  # x, y, w, h (px)
    peak: float  # max gray level in the component
    # sum of background-subtracted gray (eq. 11 denominator); NaN where a local-support
    # centroid replaced eq. 11 in the acquisition (eq. 11 not computed)
    mass: float
    color_bgr: tuple[float, ...] | None = None  # mean (B, G, R) DN over the blob, colour input
    # 1σ centroid noise (u, v) px of the local-support centroid (app.vision.local_centroid);
    # None: eq. 11's centroid, not measured; NaN: the local centroid could not be measured
    centroid_sigma_px: tuple[float, float] | None = None
    local_bg: float | None = None  # local background level (DN) around the blob
    # the sensor model's share of ``centroid_sigma_px`` (px): shot and read noise only, without
    # what the image itself shows (LocalCentroidConfig.image_noise); None: not measured
    model_sigma_px: tuple[float, float] | None = None


@dataclass(frozen=True)
class RejectedBlob:
    """A component dropped by area/shape gating, with the reason."""

    centroid_px: tuple[float, float]
    area_px: int
    reason: str


@dataclass(frozen=True)
class FeatureSet:
    """Blobs of one image and their 64-D IHWT descriptors (rows aligned with ``blobs``)."""

    blobs: list[Blob]
    descriptors: FloatArray  # (N, 64)
    rejected: list[RejectedBlob] = field(default_factory=list)

    @property
    def points_px(self) -> FloatArray:
        if not self.blobs:
            return np.zeros((0, 2))
        return np.array([b.centroid_px for b in self.blobs], dtype=np.float64)


@dataclass(frozen=True)
class Match:
    """A left/right correspondence (paper §4.4) with its quality measures."""

    left_index: int
    right_index: int
    descriptor_distance: float  # eq. 14
    epipolar_px: float  # symmetric distance to the epipolar lines, undistorted px
