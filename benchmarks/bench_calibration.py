"""Checkerboard calibration speed and accuracy against plain OpenCV, in the same run.

Plain OpenCV = classic ``findChessboardCorners`` + ``cornerSubPix`` (half-window 5) on every
image, ``calibrateCamera`` × 2 and ``stereoCalibrate`` (k1, k2 model). ``aar-dock`` =
:func:`app.calibration.stereo_calibration.calibrate_checkerboard` (detector cascade, sub-pixel
window sized to the squares, rig check, robust view dropping, held-out check, report).
Images are decoded once beforehand (not timed). Sets: Bouguet's real stereo photographs
(``tests/data/real/bouguet_stereo``, 13 pairs 640×480, published reference) and the
rendered ``sample_data/checkerboard`` (14 pairs 1280×1024, truth.json).

    .venv/bin/python benchmarks/bench_calibration.py [--repeats 5]

Prints one row per set and method: median wall time (s), ratio to plain OpenCV, and the
focal-length / |T| errors against the reference (%). A second table compares the sub-pixel
corner methods through the same calibration (aar-dock's, no view dropping): the largest
focal-length and the |T| error against the reference, the stereo RMS and the held-out check
(boards triangulated by a calibration made without them vs the true square size, mm), and on
the rendered set the corner error against the true corners.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from app.calibration.board import Board
from app.calibration.corners import detect_corners_detail
from app.calibration.detection import PairDetection, match_orientation
from app.calibration.opencv_fit import MODEL_FLAGS
from app.calibration.stereo_calibration import calibrate_checkerboard, calibrate_from_detections
from app.geometry.projection import project_camera
from app.sim.checkerboard_render import load_truth

REPO = Path(__file__).resolve().parents[1]
BOUGUET = REPO / "tests" / "data" / "real" / "bouguet_stereo"
SAMPLE = REPO / "sample_data" / "checkerboard"
# Bouguet's published stereo result (README of the data set): fc left, fc right, |T|
BOUGUET_REF = {"fx_l": 533.5, "fy_l": 533.5, "fx_r": 536.8, "fy_r": 536.5, "T": 99.81}


def plain_opencv(
    lefts: list[np.ndarray], rights: list[np.ndarray], board: Board
) -> dict[str, float]:
    """The textbook pipeline (OpenCV's stereo_calib sample with a 5 px half-window)."""
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    pl, pr = [], []
    for a, b in zip(lefts, rights, strict=True):
        found = []
        for img in (a, b):
            ok, c = cv2.findChessboardCorners(
                img,
                board.pattern_size,
                flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE,
            )
            found.append(cv2.cornerSubPix(img, c, (5, 5), (-1, -1), crit) if ok else None)
        if found[0] is not None and found[1] is not None:
            pl.append(found[0])
            pr.append(found[1])
    size = (lefts[0].shape[1], lefts[0].shape[0])
    obj = [board.object_points()] * len(pl)
    flags = MODEL_FLAGS["paper"]
    _, K1, d1, *_ = cv2.calibrateCamera(obj, pl, size, None, None, flags=flags)
    _, K2, d2, *_ = cv2.calibrateCamera(obj, pr, size, None, None, flags=flags)
    _, K1, d1, K2, d2, _R, T, _E, _F = cv2.stereoCalibrate(
        obj, pl, pr, K1, d1, K2, d2, size, flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS
    )
    return {
        "fx_l": K1[0, 0], "fy_l": K1[1, 1], "fx_r": K2[0, 0], "fy_r": K2[1, 1],
        "T": float(np.linalg.norm(T)), "views": len(pl),
    }  # fmt: skip


def ours(lefts: list[np.ndarray], rights: list[np.ndarray], board: Board) -> dict[str, float]:
    names = [f"{k:02d}" for k in range(len(lefts))]
    res = calibrate_checkerboard(names, lefts, rights, board, model="paper")
    c = res.calibration
    return {
        "fx_l": c.left.fx, "fy_l": c.left.fy, "fx_r": c.right.fx, "fy_r": c.right.fy,
        "T": c.baseline_mm, "views": res.report.views_used,
    }  # fmt: skip


def timed(fn: Callable[[], dict[str, float]], repeats: int) -> tuple[float, dict[str, float]]:
    out = fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def load_sets() -> dict[str, Any]:
    sets: dict[str, Any] = {}
    if BOUGUET.is_dir():
        lf = sorted(BOUGUET.glob("left*.jpg"))
        rf = sorted(BOUGUET.glob("right*.jpg"))
        sets["bouguet (real, 13 pairs 640x480)"] = (
            [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in lf],
            [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in rf],
            Board(9, 6, 30.0),
            BOUGUET_REF,
        )
    truth, spec, _ = load_truth(SAMPLE / "truth.json")
    ref = {
        "fx_l": truth.left.fx, "fy_l": truth.left.fy, "fx_r": truth.right.fx,
        "fy_r": truth.right.fy, "T": truth.baseline_mm,
    }  # fmt: skip
    sets["sample (rendered, 14 pairs 1280x1024)"] = (
        [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(SAMPLE.glob("left_*.png"))],
        [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(SAMPLE.glob("right_*.png"))],
        Board(spec.cols, spec.rows, spec.square_mm),
        ref,
    )
    return sets


def _plain_corners(img: np.ndarray, board: Board) -> np.ndarray | None:
    ok, c = cv2.findChessboardCorners(
        img, board.pattern_size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if not ok:
        return None
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    return cv2.cornerSubPix(img, c, (5, 5), (-1, -1), crit).reshape(-1, 2).astype(np.float64)


def _sb_accuracy(img: np.ndarray, board: Board) -> np.ndarray | None:
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY
    ok, c = cv2.findChessboardCornersSB(img, board.pattern_size, flags=flags)
    return c.reshape(-1, 2).astype(np.float64) if ok else None


def _ours(refine: str, methods: tuple[str, ...] = ("classic", "sb")) -> Callable[..., Any]:
    def fn(img: np.ndarray, board: Board) -> np.ndarray | None:
        r = detect_corners_detail(img, board.pattern_size, methods, refine=refine)
        return None if r is None else r.corners

    return fn


SUBPIX_METHODS: dict[str, Callable[..., Any]] = {
    "SB, own corners": _ours("none", ("sb",)),
    "SB + CALIB_CB_ACCURACY": _sb_accuracy,
    "classic + cornerSubPix 5 px": _plain_corners,
    "classic + cornerSubPix sized": _ours("subpix"),
    "... + saddle fit (default)": _ours("saddle"),
}


def subpixel_table(sets: dict[str, Any]) -> None:
    truth, spec, poses = load_truth(SAMPLE / "truth.json")
    print(
        f"\n{'set':<38} {'corners':<30} {'max|f| %':>8} {'|T| %':>7} {'RMS px':>7} "
        f"{'held-out mm':>11} {'vs truth px':>11}"
    )
    for name, (lefts, rights, board, ref) in sets.items():
        rendered = name.startswith("sample")
        for label, fn in SUBPIX_METHODS.items():
            dets = []
            for k, (a, b) in enumerate(zip(lefts, rights, strict=True)):
                cl, cr = fn(a, board), fn(b, board)
                if cl is not None and cr is not None:
                    cr = match_orientation(cl, cr)
                dets.append(PairDetection(f"{k:02d}", (a.shape[1], a.shape[0]), cl, cr))
            res = calibrate_from_detections(dets, board, "paper", drop_outliers=False)
            c, rep = res.calibration, res.report
            got = {"fx_l": c.left.fx, "fy_l": c.left.fy, "fx_r": c.right.fx, "fy_r": c.right.fy}
            f_err = max(abs(100 * (got[k] / ref[k] - 1)) for k in got)
            t_err = 100 * (c.baseline_mm / ref["T"] - 1)
            vs_truth = "-"
            if rendered:
                obj = spec.object_points()
                errs = []
                for d, pose in zip(res.detections, poses, strict=True):
                    xl = (pose.R @ obj.T).T + pose.t
                    xr = (truth.R @ xl.T).T + truth.T
                    for pts, tr in ((d.left, project_camera(truth.left, xl)),
                                    (d.right, project_camera(truth.right, xr))):  # fmt: skip
                        e1 = np.linalg.norm(pts - tr, axis=1)
                        e2 = np.linalg.norm(pts[::-1] - tr, axis=1)
                        errs.append(e1 if e1.max() < e2.max() else e2)
                vs_truth = f"{float(np.sqrt(np.mean(np.concatenate(errs) ** 2))):.3f}"
            held = rep.held_out.rms_mm if rep.held_out is not None else float("nan")
            print(
                f"{name:<38} {label:<30} {f_err:8.3f} {t_err:+7.3f} {rep.stereo_rms_px:7.3f} "
                f"{held:11.3f} {vs_truth:>11}"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-subpixel", action="store_true", help="only the timing table")
    args = parser.parse_args()
    sets = load_sets()
    print(
        f"{'set':<38} {'method':<14} {'median s':>9} {'ratio':>6} {'views':>5} "
        f"{'fx_l %':>7} {'fy_l %':>7} {'fx_r %':>7} {'fy_r %':>7} {'|T| %':>7}"
    )
    for name, (lefts, rights, board, ref) in sets.items():
        base = None
        for label, fn in (("plain OpenCV", plain_opencv), ("aar-dock", ours)):
            t, out = timed(lambda fn=fn, a=lefts, b=rights, s=board: fn(a, b, s), args.repeats)
            base = t if base is None else base
            errs = " ".join(f"{100 * (out[k] / ref[k] - 1):+7.3f}" for k in ref)
            print(f"{name:<38} {label:<14} {t:9.3f} {t / base:6.2f} {int(out['views']):5d} {errs}")
    if not args.no_subpixel:
        subpixel_table(sets)


if __name__ == "__main__":
    main()
