"""The picture of a checkerboard calibration's report (matplotlib, Agg canvas): an example
pair with its detected corners, the corner coverage of all used views, the per-view
reprojection RMS of both cameras and a summary (:func:`write_report_png`). matplotlib is
imported when a picture is drawn, not with this module."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.calibration.corners import to_gray
from app.calibration.report import SKEW_REFINED_NOTE
from app.calibration.stereo_calibration import CheckerboardCalibration


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
