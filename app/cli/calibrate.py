"""``aar-dock calibrate``: stereo calibration from checkerboard pictures (paper §3.2).

Example::

    aar-dock calibrate --left 'sample_data/checkerboard/left_*.png' \\
        --right 'sample_data/checkerboard/right_*.png' --board 9x6 --square-mm 25 \\
        --out calibration.json --report calib_report

Pairs are formed from the two sorted file lists. Exit code 0 on success, 2 with a one-line
message on a bad set (no files, unreadable image, sizes differ, board not found, < 6 views).
"""

from __future__ import annotations

import argparse
import glob
import json
import sys
from pathlib import Path
from typing import Any

from app.types import UInt8Array

PROG = "aar-dock calibrate"


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="calibrate the stereo rig from checkerboard image pairs",
        description="Stereo calibration from checkerboard image pairs (Zhang's method, OpenCV). "
        "Writes the calibration JSON and, with --report, report.json + report.png.",
    )
    p.add_argument(
        "--left", required=True, help="glob of the left images (quote it), e.g. 'dir/left*.png'"
    )
    p.add_argument("--right", required=True, help="glob of the right images (quote it)")
    p.add_argument(
        "--board", default="9x6", help="inner corners per row x per column (default 9x6)"
    )
    p.add_argument("--square-mm", type=float, default=25.0, help="square side in mm (default 25)")
    p.add_argument("--out", default="calibration.json", help="output calibration JSON")
    p.add_argument("--report", default=None, help="folder for report.json and report.png")
    p.add_argument(
        "--model",
        choices=("paper", "full"),
        default="paper",
        help="distortion model: paper = k1, k2 only (eq. 7); full = k1, k2, p1, p2, k3",
    )
    p.add_argument(
        "--skew",
        action="store_true",
        help="also estimate the skew γ of eq. 2 (joint least-squares refinement after OpenCV, "
        "which has no skew term and otherwise writes γ = 0)",
    )
    p.add_argument(
        "--max-rms",
        type=float,
        default=0.5,
        help="warn when the stereo reprojection RMS exceeds this (px, default 0.5)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="detection processes (default: a pool of all CPUs when the set is large enough "
        "to pay for it; 1 = none)",
    )
    p.add_argument(
        "--keep-outliers",
        action="store_true",
        help="do not drop reprojection-outlier views (robust z-score rule, see docs/calibration.md)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=run)


def _fail(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:

    from app.calibration.board import Board, CheckerboardError, pair_name, parse_board
    from app.calibration.corners import to_gray
    from app.calibration.report_plot import write_report_png
    from app.calibration.stereo_calibration import calibrate_checkerboard
    from app.geometry.calibration import CalibrationError
    from app.vision.io import read_image
    from app.vision.preprocess import ImageError

    left_files = sorted(Path(p) for p in glob.glob(args.left))
    right_files = sorted(Path(p) for p in glob.glob(args.right))
    if not left_files:
        return _fail(f"no files match --left {args.left!r}")
    if not right_files:
        return _fail(f"no files match --right {args.right!r}")
    if len(left_files) != len(right_files):
        return _fail(
            f"{len(left_files)} left images but {len(right_files)} right images: "
            "pairs are formed from the two sorted lists, they must have the same length"
        )
    try:
        cols, rows = parse_board(args.board)
        board = Board(cols, rows, float(args.square_mm))
        names = [
            pair_name(lf.name, rf.name) for lf, rf in zip(left_files, right_files, strict=True)
        ]
        lefts: list[UInt8Array] = []
        rights: list[UInt8Array] = []
        for lf, rf in zip(left_files, right_files, strict=True):
            for f, dest in ((lf, lefts), (rf, rights)):
                try:
                    dest.append(to_gray(read_image(f)))
                except ImageError as exc:
                    raise CheckerboardError(f"cannot read image {f} ({exc})") from None
        result = calibrate_checkerboard(
            names,
            lefts,
            rights,
            board,
            model=args.model,
            max_stereo_rms_px=args.max_rms,
            progress=not args.no_progress,
            estimate_skew=args.skew,
            workers=args.workers,
            drop_outliers=not args.keep_outliers,
        )
        out = Path(args.out)
        if out.parent and not out.parent.exists():
            out.parent.mkdir(parents=True, exist_ok=True)
        result.save(out)
    except (CheckerboardError, CalibrationError) as exc:
        return _fail(str(exc))
    except OSError as exc:
        return _fail(f"cannot write output ({exc})")

    rep = result.report
    if args.report:
        rdir = Path(args.report)
        rdir.mkdir(parents=True, exist_ok=True)
        payload = {"calibration": result.calibration.to_dict(), "report": rep.to_dict()}
        (rdir / "report.json").write_text(json.dumps(payload, indent=2) + "\n")
        k = result.used[0]
        write_report_png(result, rdir / "report.png", lefts[k], rights[k])
    for w in rep.warnings:
        print(f"warning: {w}", file=sys.stderr)
    il, ir = rep.intrinsics["left"], rep.intrinsics["right"]
    print(
        f"views used      {rep.views_used} of {rep.pairs_given} ({len(rep.rejected)} rejected"
        + (f", {len(rep.dropped)} dropped as outliers)" if rep.dropped else ")")
    )
    print(
        f"RMS (px)        left {rep.left_rms_px:.3f}  right {rep.right_rms_px:.3f}  stereo {rep.stereo_rms_px:.3f}"
    )
    for side, i in (("left", il), ("right", ir)):
        print(
            f"{side:<6}          fx {i['fx']:.2f} fy {i['fy']:.2f} u0 {i['u0']:.2f} v0 {i['v0']:.2f} "
            f"k1 {i['k1']:.4f} k2 {i['k2']:.4f} "
            + (f"skew {i['skew']:.2f}" if args.skew else "(skew not estimated: 0)")
        )
    print(f"baseline        {rep.baseline_mm:.2f} mm, convergence {rep.convergence_deg:.3f} deg")
    if rep.held_out is not None:
        print(
            f"held-out check  square size RMS {rep.held_out.rms_mm:.3f} mm, "
            f"max {rep.held_out.max_mm:.3f} mm ({rep.held_out.folds}-fold, boards triangulated "
            "by a calibration made without them)"
        )
    print(
        f"wrote           {args.out}"
        + (f", {args.report}/report.json, {args.report}/report.png" if args.report else "")
    )
    return 0
