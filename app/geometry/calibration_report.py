"""The report of a checkerboard calibration: per-view errors, rejected and dropped views with
their reasons, the image coverage map, the held-out check, and the report picture.

The data classes here are filled by :mod:`app.geometry.stereo_calibrate`; everything is
JSON-serialisable through :meth:`CalibrationReport.to_dict`. Pure numpy, except the picture
(matplotlib, Agg canvas, imported inside :func:`report_png_bytes`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from app.geometry.board_detect import to_gray
from app.geometry.calibration import FloatArray

if TYPE_CHECKING:
    from app.geometry.stereo_calibrate import CheckerboardCalibration

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
    """A pair dropped as a reprojection outlier (robust z-score rule, stereo_calibrate)."""

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


def write_report_png(
    result: CheckerboardCalibration,
    path: str | Path,
    example_left: NDArray[Any] | None = None,
    example_right: NDArray[Any] | None = None,
) -> Path:
    """PNG: an example pair with its detected corners, corner coverage of all used views,
    and the per-view reprojection RMS of both cameras (matplotlib, Agg canvas)."""
    out = Path(path)
    out.write_bytes(report_png_bytes(result, example_left, example_right))
    return out


def report_png_bytes(
    result: CheckerboardCalibration,
    example_left: NDArray[Any] | None = None,
    example_right: NDArray[Any] | None = None,
) -> bytes:
    """The report picture of :func:`write_report_png` as PNG bytes."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    rep = result.report
    w, h = rep.image_size
    fig = Figure(figsize=(14, 9), dpi=90)
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2)
    ex = result.detections[result.used[0]] if result.used else None
    for ax, img, side in ((axes[0, 0], example_left, "left"), (axes[0, 1], example_right, "right")):
        if img is not None:
            ax.imshow(to_gray(img), cmap="gray", vmin=0, vmax=255)
        else:
            ax.set_xlim(0, w)
            ax.set_ylim(h, 0)
        if ex is not None:
            pts = ex.left if side == "left" else ex.right
            if pts is not None:
                ax.plot(pts[:, 0], pts[:, 1], "-", color="tab:orange", lw=0.8)
                ax.plot(pts[:, 0], pts[:, 1], "+", color="tab:red", ms=6)
                ax.plot(pts[0, 0], pts[0, 1], "o", mfc="none", color="tab:cyan", ms=10)
        # corner coverage of every used view
        for k in result.used:
            d = result.detections[k]
            p = d.left if side == "left" else d.right
            if p is not None:
                ax.plot(p[:, 0], p[:, 1], ".", ms=3, alpha=0.6)
        if rep.coverage is not None:  # the coverage grid; empty cells shaded red
            rows, cols = rep.coverage.grid
            counts = np.asarray(rep.coverage.left if side == "left" else rep.coverage.right)
            for i in range(rows):
                for j in range(cols):
                    empty = bool(counts[i, j] == 0)
                    ax.add_patch(
                        Rectangle(
                            (j * w / cols, i * h / rows),
                            w / cols,
                            h / rows,
                            fill=empty,
                            facecolor="tab:red",
                            edgecolor="yellow",
                            alpha=0.25 if empty else 0.5,
                            lw=0.6,
                        )
                    )
        ax.set_title(
            f"{side}: view {ex.name if ex else '-'} (+), all views (dots), empty cells red",
            fontsize=9,
        )
        ax.set_aspect("equal")
    names = [v.name for v in rep.views]
    x = np.arange(len(names))
    ax = axes[1, 0]
    ax.bar(x - 0.2, [v.left_rms_px for v in rep.views], 0.4, label="left")
    ax.bar(x + 0.2, [v.right_rms_px for v in rep.views], 0.4, label="right")
    ax.axhline(
        rep.stereo_rms_px, color="k", ls="--", lw=1, label=f"stereo RMS {rep.stereo_rms_px:.3f} px"
    )
    ax.set_xticks(x, names, rotation=60, fontsize=7)
    ax.set_ylabel("reprojection RMS (px)")
    ax.set_title("per-view reprojection error")
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    ax.axis("off")
    il, ir = rep.intrinsics["left"], rep.intrinsics["right"]
    lines = [
        f"board {rep.board} inner corners, {rep.square_mm:g} mm squares, model '{rep.model}'",
        f"views used {rep.views_used} of {rep.pairs_given}, image {w}x{h} px",
        f"RMS left {rep.left_rms_px:.3f} px, right {rep.right_rms_px:.3f} px, stereo {rep.stereo_rms_px:.3f} px",
        f"baseline {rep.baseline_mm:.2f} mm, convergence {rep.convergence_deg:.3f} deg",
        f"T = ({rep.T_mm[0]:.2f}, {rep.T_mm[1]:.2f}, {rep.T_mm[2]:.2f}) mm",
        f"left  fx {il['fx']:.1f} fy {il['fy']:.1f} u0 {il['u0']:.1f} v0 {il['v0']:.1f} k1 {il['k1']:.4f} k2 {il['k2']:.4f}",
        f"right fx {ir['fx']:.1f} fy {ir['fy']:.1f} u0 {ir['u0']:.1f} v0 {ir['v0']:.1f} k1 {ir['k1']:.4f} k2 {ir['k2']:.4f}",
        (
            f"skew estimated: left {il['skew']:.2f} px, right {ir['skew']:.2f} px"
            if rep.notes and rep.notes[0] == SKEW_REFINED_NOTE
            else "skew: not estimated by OpenCV (0 in the output)"
        ),
    ]
    if rep.held_out is not None:
        lines.append(
            f"held-out square size ({rep.held_out.folds} folds): RMS {rep.held_out.rms_mm:.3f} mm,"
            f" max {rep.held_out.max_mm:.3f} mm"
        )
    for r in rep.rejected[:6]:
        lines.append(f"rejected {r.name}: {r.reason[:80]}")
    for dv in rep.dropped[:4]:
        lines.append(f"dropped {dv.name}: {dv.reason[:80]}")
    for wmsg in rep.warnings[:4]:
        if not wmsg.startswith(("pair ", "poor coverage")):
            lines.append(f"WARNING: {wmsg[:90]}")
    ax.text(0, 1, "\n".join(lines), va="top", family="monospace", fontsize=8.5)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()
