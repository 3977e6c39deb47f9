"""The report of a checkerboard calibration: per-view errors, rejected and dropped views with
their reasons, the image coverage map and the held-out check.

The data classes here are filled by :mod:`app.calibration.stereo_calibration`; everything is
JSON-serialisable through :meth:`CalibrationReport.to_dict`. Pure numpy; the report picture
is :mod:`app.calibration.report_plot`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.types import FloatArray

COVERAGE_GRID = (4, 4)  # rows x cols of image cells counted by the coverage map
SKEW_NOTE = (
    "OpenCV's camera model has no skew term: γ is not estimated and is written as 0 "
    "(the paper's Table 1 lists γ = -4.5 / -0.49 px)."
)
SKEW_REFINED_NOTE = (
    "Skew γ estimated: OpenCV's skew-free result was refined jointly with γ (both cameras, "
    "rig and board poses) by sparse least squares."
)


@dataclass
class ViewReport:
    """Per-view reprojection RMS (px) after the joint stereo refinement, and the held-out
    residual of that view's board (mm, see :class:`HeldOutCheck`; None if not computed)."""

    name: str
    left_rms_px: float
    right_rms_px: float
    held_out_mm: float | None = None


@dataclass
class RejectedView:
    """A pair not used: board missing in an image, or left/right grids not the same corners."""

    name: str
    reason: str


@dataclass
class DroppedView:
    """A pair dropped as a reprojection outlier (robust z-score rule of
    :mod:`app.calibration.robust`)."""

    name: str
    reason: str
    rms_px: float
    robust_z: float


@dataclass
class HeldOutCheck:
    """Each view's board triangulated with a calibration made *without* it (``folds``-fold
    cross-validation; leave-one-out when folds = views). Residual = distance between
    neighbouring triangulated corners − the square size (mm)."""

    folds: int
    rms_mm: float
    max_mm: float
    per_view_rms_mm: dict[str, float]


@dataclass
class Coverage:
    """Corner counts of the used views per image cell (``COVERAGE_GRID``), per camera, and
    the image corners (cells) left empty."""

    grid: tuple[int, int]
    left: list[list[int]]
    right: list[list[int]]
    empty_corners: dict[str, list[str]]
    covered_fraction: dict[str, float]


@dataclass
class CalibrationReport:
    """Everything a user needs to judge a calibration (serialisable with :meth:`to_dict`)."""

    board: str  # "9x6" inner corners
    square_mm: float
    model: str
    image_size: tuple[int, int]
    pairs_given: int
    views_used: int
    views: list[ViewReport]
    rejected: list[RejectedView]
    left_rms_px: float  # single-camera calibration RMS (with skew: of the joint refinement)
    right_rms_px: float
    stereo_rms_px: float  # joint refinement RMS over both cameras
    max_stereo_rms_px: float
    baseline_mm: float
    convergence_deg: float
    T_mm: list[float]
    rotation_deg: float  # angle of R
    intrinsics: dict[str, dict[str, float]]
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    dropped: list[DroppedView] = field(default_factory=list)
    coverage: Coverage | None = None
    held_out: HeldOutCheck | None = None
    detectors: dict[str, int] = field(default_factory=dict)  # images found per detector

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["image_size"] = list(self.image_size)
        if self.coverage is not None:
            d["coverage"]["grid"] = list(self.coverage.grid)
        return d


def intrinsics_summary(K: FloatArray, dist: FloatArray) -> dict[str, float]:
    """fx, fy, skew, u0, v0 (px) and k1, k2, p1, p2, k3 of one camera."""
    d = np.zeros(5)
    d[: min(5, dist.size)] = dist.ravel()[:5]
    return {
        "fx": float(K[0, 0]),
        "fy": float(K[1, 1]),
        "skew": float(K[0, 1]),
        "u0": float(K[0, 2]),
        "v0": float(K[1, 2]),
        "k1": float(d[0]),
        "k2": float(d[1]),
        "p1": float(d[2]),
        "p2": float(d[3]),
        "k3": float(d[4]),
    }


def _cell_counts(points: Sequence[FloatArray], size: tuple[int, int]) -> NDArray[np.int64]:
    rows, cols = COVERAGE_GRID
    w, h = size
    counts = np.zeros((rows, cols), dtype=np.int64)
    if points:
        p = np.concatenate([np.asarray(x, dtype=np.float64).reshape(-1, 2) for x in points])
        c = np.clip((p[:, 0] / w * cols).astype(int), 0, cols - 1)
        r = np.clip((p[:, 1] / h * rows).astype(int), 0, rows - 1)
        np.add.at(counts, (r, c), 1)
    return counts


def coverage_map(
    left: Sequence[FloatArray], right: Sequence[FloatArray], size: tuple[int, int]
) -> Coverage:
    """Coverage of the image by the corners of the used views (``size`` = (w, h) px)."""
    rows, cols = COVERAGE_GRID
    named = {
        "top-left": (0, 0),
        "top-right": (0, cols - 1),
        "bottom-left": (rows - 1, 0),
        "bottom-right": (rows - 1, cols - 1),
    }
    out: dict[str, NDArray[np.int64]] = {
        "left": _cell_counts(left, size),
        "right": _cell_counts(right, size),
    }
    return Coverage(
        grid=(rows, cols),
        left=out["left"].tolist(),
        right=out["right"].tolist(),
        empty_corners={
            side: [n for n, rc in named.items() if counts[rc] == 0] for side, counts in out.items()
        },
        covered_fraction={side: float(np.mean(c > 0)) for side, c in out.items()},
    )


def coverage_warnings(cov: Coverage) -> list[str]:
    """A warning per camera whose image corners are empty (distortion poorly constrained)."""
    out = []
    for side in ("left", "right"):
        empty = cov.empty_corners[side]
        if empty:
            out.append(
                f"poor coverage in the {side} image: no corners in the {', '.join(empty)} "
                f"corner cell(s) of a {cov.grid[0]}x{cov.grid[1]} grid "
                f"({100 * cov.covered_fraction[side]:.0f} % of cells covered); distortion is "
                "extrapolated there: add views with the board near the image corners"
            )
    return out
