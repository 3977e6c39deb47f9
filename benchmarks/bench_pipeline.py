"""Navigation pipeline speed: per-stage medians, and our implementations against OpenCV
baselines in the same run (ratios; the machines are noisy, so compare ratios, quote medians).

* describe: our IHWT (integral image + 64-D Haar) vs OpenCV SIFT ``compute`` on the same
  keypoints (128-D gradient histograms) — the stock descriptor one would reach for.
* triangulate: our eq. 15–16 least squares (+ the reprojection refinement) vs
  ``cv2.triangulatePoints`` (DLT) on the same undistorted points.
* whole frame: the pipeline's total vs the time of OpenCV's ``connectedComponentsWithStats``
  alone on the same binary images (the floor any blob pipeline pays).

    .venv/bin/python benchmarks/bench_pipeline.py [--repeats 30]
"""

from __future__ import annotations

import argparse
import statistics
import time

import cv2
import numpy as np

from app.geometry.projection import undistort_pixels
from app.geometry.triangulation import refine_reprojection, triangulate_linear
from app.sim.led_ring import random_pose
from app.sim.paths import load_default_calibration
from app.sim.stereo_render import RenderSettings, render_pair
from app.vision.ihwt import describe, integral_image
from app.vision.pipeline import NavigationPipeline, PipelineConfig
from app.vision.preprocess import binarize, choose_threshold


def timed(fn, repeats: int) -> float:
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--clutter", type=int, default=0)
    args = ap.parse_args()
    calib = load_default_calibration()
    rng = np.random.default_rng(0)
    centre, normal = random_pose(rng, 1000.0, 20.0)
    pair = render_pair(calib, centre, normal, RenderSettings(clutter=args.clutter), seed=1)
    pipe = NavigationPipeline(calib, PipelineConfig())
    stage_runs = []
    for _ in range(args.repeats):
        stage_runs.append(pipe.process(pair.left, pair.right).timing_ms.model_dump())
    print(
        f"Pipeline on one 1280×1024 stereo pair at 1 m, {args.clutter} clutter blobs, "
        f"median of {args.repeats} runs (ms):"
    )
    print(f"{'stage':<12}{'median ms':>10}")
    for k in stage_runs[0]:
        print(f"{k:<12}{statistics.median(r[k] for r in stage_runs):>10.2f}")

    blobs = pipe.trace.left.blobs
    gray = pair.left
    kps = [cv2.KeyPoint(b.centroid_px[0], b.centroid_px[1], 16.0) for b in blobs]
    sift = cv2.SIFT_create()
    t_ihwt = timed(lambda: describe(gray, blobs, ii=integral_image(gray)), args.repeats)
    t_sift = timed(lambda: sift.compute(gray, kps), args.repeats)

    xl = undistort_pixels(calib.left, np.array([b.centroid_px for b in pipe.trace.left.blobs]))
    xr = undistort_pixels(
        calib.right,
        np.array([pipe.trace.right.blobs[m.right_index].centroid_px for m in pipe.trace.matches]),
    )
    xl = xl[[m.left_index for m in pipe.trace.matches]]
    t_lin = timed(
        lambda: triangulate_linear(calib.P_left, calib.P_right, xl, xr), args.repeats * 10
    )
    t_ref = timed(
        lambda: refine_reprojection(
            calib.P_left,
            calib.P_right,
            xl,
            xr,
            triangulate_linear(calib.P_left, calib.P_right, xl, xr),
        ),
        args.repeats * 10,
    )
    t_cv = timed(
        lambda: cv2.triangulatePoints(calib.P_left, calib.P_right, xl.T.copy(), xr.T.copy()),
        args.repeats * 10,
    )

    masks = [binarize(img, choose_threshold(img)) for img in (pair.left, pair.right)]
    t_cc = timed(
        lambda: [cv2.connectedComponentsWithStats(m, connectivity=8) for m in masks], args.repeats
    )
    t_total = statistics.median(r["total"] for r in stage_runs)

    print("\nOurs vs OpenCV baseline in the same run (median ms, ratio = ours / baseline):")
    print(f"{'operation':<44}{'ours':>9}{'baseline':>10}{'ratio':>8}")
    rows = [
        (f"describe {len(blobs)} FPs: IHWT vs SIFT.compute", t_ihwt, t_sift),
        (f"triangulate {len(xl)}: eq.15-16 vs triangulatePoints", t_lin, t_cv),
        (f"triangulate {len(xl)}: eq.15-16+refine vs triangulatePoints", t_ref, t_cv),
        ("whole pair vs connectedComponents alone", t_total, t_cc),
    ]
    for name, a, b in rows:
        print(f"{name:<44}{a:>9.3f}{b:>10.3f}{a / b:>8.2f}")
    print(f"\nframe rate of the whole pipeline: {1000.0 / t_total:.0f} stereo pairs/s on one core")


if __name__ == "__main__":
    main()
