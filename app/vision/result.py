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


class DrogueResult(BaseModel):
    center_mm: tuple[float, float, float]
    normal: tuple[float, float, float]
    radius_mm: float
    rms_mm: float


class StageTimings(BaseModel):
    preprocess: float = 0.0
    extract: float = 0.0
    describe: float = 0.0
    match: float = 0.0
    triangulate: float = 0.0
    pose: float = 0.0
    total: float = 0.0


class PoseResult(BaseModel):
    lock: bool
    reason: str | None = None
    leds: list[LedResult] = Field(default_factory=list)
    drogue: DrogueResult | None = None
    timing_ms: StageTimings = Field(default_factory=StageTimings)
