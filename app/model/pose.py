"""The pipeline's result contract (CLI and REST return exactly this shape)."""

from __future__ import annotations

from pydantic import BaseModel, Field


class LedResult(BaseModel):
    id: int = Field(
        description="LED id 1..N (app.geometry.led_ids): clockwise from the top as seen by the "
        "cameras; the physical id at acquisition while |roll| < 180°/N, then kept by continuity"
    )
    left_px: tuple[float, float]
    right_px: tuple[float, float]
    xyz_mm: tuple[float, float, float]
    descriptor_distance: float
    epipolar_px: float
    reprojection_px: float
    sigma_px: tuple[float, float] | None = Field(
        default=None,
        description="1σ centroid noise (px) in the left and right image (local-support centroid; "
        "None: not measured, e.g. the paper's eq. 11 centroid)",
    )
    cov_mm2: list[list[float]] | None = Field(
        default=None, description="3×3 covariance of xyz_mm (mm², left camera frame) from sigma_px"
    )
    protection_level_mm: float | None = Field(
        default=None, description="radius (mm) the LED's 3-D error exceeds with probability ≤ 1e-3"
    )


class DrogueResult(BaseModel):
    center_mm: tuple[float, float, float]
    normal: tuple[float, float, float]
    radius_mm: float
    rms_mm: float
    center_cov_mm2: list[list[float]] | None = Field(
        default=None,
        description="3×3 covariance of center_mm (mm²) propagated through the circle fit",
    )
    protection_level_mm: float | None = Field(
        default=None,
        description="radius (mm) the centre's 3-D error exceeds with probability ≤ 1e-3",
    )
    fit_chi2: float | None = Field(
        default=None, description="the lock's residuals against its covariance (χ² statistic)"
    )
    fit_dof: int | None = Field(default=None, description="degrees of freedom of fit_chi2")


MAX_REJECTED_SHOWN = 64  # rejected candidates reported per image (in the blobs' order)


class StageTimings(BaseModel):
    preprocess: float = 0.0
    extract: float = 0.0
    describe: float = 0.0
    match: float = 0.0
    triangulate: float = 0.0
    pose: float = 0.0
    bound: float = 0.0  # covariances, protection levels and the residual test
    total: float = 0.0


class PoseResult(BaseModel):
    lock: bool
    reason: str | None = None
    leds: list[LedResult] = Field(default_factory=list)
    drogue: DrogueResult | None = None
    rejected_left_px: list[tuple[float, float]] = Field(
        default_factory=list,
        description="full-frame acquisition: the candidate blobs of the left image (px) that "
        "are not among the reported LEDs (gated out, unmatched or refused), at most "
        "MAX_REJECTED_SHOWN; empty on tracked frames",
    )
    rejected_right_px: list[tuple[float, float]] = Field(
        default_factory=list, description="the same for the right image (px)"
    )
    timing_ms: StageTimings = Field(default_factory=StageTimings)
