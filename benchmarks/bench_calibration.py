"""Checkerboard calibration speed and accuracy against plain OpenCV, in the same run.

Plain OpenCV = classic ``findChessboardCorners`` + ``cornerSubPix`` (half-window 5) on every
image, ``calibrateCamera`` × 2 and ``stereoCalibrate`` (k1, k2 model). ``aar-dock`` =
:func:`app.geometry.stereo_calibrate.calibrate_checkerboard` (detector cascade, sub-pixel
window sized to the squares, rig check, robust view dropping, held-out check, report).
Images are decoded once beforehand (not timed). Sets: Bouguet's real stereo photographs
(``../shared/data/real/bouguet_stereo``, 13 pairs 640×480, published reference) and the
rendered ``sample_data/checkerboard`` (14 pairs 1280×1024, truth.json).

    .venv/bin/python benchmarks/bench_calibration.py [--repeats 5]

Prints one row per set and method: median wall time (s), ratio to plain OpenCV, and the
focal-length / |T| errors against the reference (%).
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

from app.geometry.board_detect import Board, pair_name
from app.geometry.stereo_calibrate import MODEL_FLAGS, calibrate_checkerboard
from app.sim.checkerboard_render import load_truth

REPO = Path(__file__).resolve().parents[1]
BOUGUET = REPO.parent / "shared" / "data" / "real" / "bouguet_stereo"
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
        assert [pair_name(a.name, b.name) for a, b in zip(lf, rf, strict=True)]
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(
        f"{'set':<38} {'method':<14} {'median s':>9} {'ratio':>6} {'views':>5} "
        f"{'fx_l %':>7} {'fy_l %':>7} {'fx_r %':>7} {'fy_r %':>7} {'|T| %':>7}"
    )
    for name, (lefts, rights, board, ref) in load_sets().items():
        base = None
        for label, fn in (("plain OpenCV", plain_opencv), ("aar-dock", ours)):
            t, out = timed(lambda fn=fn, a=lefts, b=rights, s=board: fn(a, b, s), args.repeats)
            base = t if base is None else base
            errs = " ".join(f"{100 * (out[k] / ref[k] - 1):+7.3f}" for k in ref)
            print(f"{name:<38} {label:<14} {t:9.3f} {t / base:6.2f} {int(out['views']):5d} {errs}")


if __name__ == "__main__":
    main()
