"""Tuning the paper's matcher: IHWT window factor versus lock rate and match correctness.

The paper's matcher (§4.4, eq. 14) pairs each left feature point with the right one at minimum
Euclidean distance between 64-D IHWT descriptors, with no geometric check. The descriptor
window side is ``window_factor × blob equivalent radius``; §4.3 says a larger described area
gives a more detailed description. This sweep renders the same random poses (tilt ≤ 20°,
default noise) at each range once and solves them with the paper's matcher at each factor,
with ours (epipolar gate + global assignment, factor 8) as the reference row.

Columns per range: lock rate; the fraction of the matcher's matches that are correct (left and
right centroids within 0.5 px of the same LED's truth pixels); the fraction of frames whose
five LEDs are all matched correctly; wrong locks (a lock whose centre is > 5 mm from the
truth). Prints a Markdown table.

    .venv/bin/python benchmarks/paper_window_sweep.py [--poses 30] [--factors 8,16,...]
"""

from __future__ import annotations

import argparse

import numpy as np

from app.resources import load_default_calibration
from app.sim.led_ring import random_pose
from app.sim.stereo_render import RenderSettings, render_pair
from app.vision.pipeline import NavigationPipeline, PipelineConfig

TOL_PX = 0.5
WRONG_LOCK_MM = 5.0


def render_frames(calib, range_mm: float, poses: int) -> list:
    rng = np.random.default_rng(int(range_mm))
    frames = []
    for seed in range(poses):
        c, n = random_pose(rng, range_mm, 20.0)
        frames.append(render_pair(calib, c, n, RenderSettings(), seed=seed))
    return frames


def led_of(px: tuple[float, float], truth_px: np.ndarray) -> int:
    """Index of the LED whose truth pixel is within TOL_PX of ``px``, else −1."""
    d = np.hypot(*(truth_px - np.asarray(px)).T)
    d = np.where(np.isfinite(d), d, np.inf)
    k = int(np.argmin(d))
    return k if d[k] <= TOL_PX else -1


def evaluate(calib, config: PipelineConfig, frames: list) -> dict:
    pipe = NavigationPipeline(calib, config)
    locks = wrong_locks = n_match = n_correct = all_correct = 0
    for pair in frames:
        t = pair.truth
        pipe.reset()  # independent frames: no track prior
        res = pipe.process(pair.left, pair.right)
        tr = pipe.trace
        correct = 0
        for m in tr.matches:
            kl = led_of(tr.left.blobs[m.left_index].centroid_px, t.led_left_px)
            kr = led_of(tr.right.blobs[m.right_index].centroid_px, t.led_right_px)
            correct += int(kl >= 0 and kl == kr)
        n_match += len(tr.matches)
        n_correct += correct
        all_correct += int(correct == int(np.sum(t.visible)))
        if res.lock:
            locks += 1
            err = np.linalg.norm(np.array(res.drogue.center_mm) - t.center_mm)
            wrong_locks += int(err > WRONG_LOCK_MM)
    n = len(frames)
    return {
        "lock": locks / n,
        "correct": n_correct / n_match if n_match else float("nan"),
        "all_correct": all_correct / n,
        "wrong_locks": wrong_locks,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=30)
    ap.add_argument("--ranges-mm", default="1000,2500")
    ap.add_argument("--factors", default="8,16,32,48,64,80,96,128")
    args = ap.parse_args()
    calib = load_default_calibration()
    ranges = [float(x) for x in args.ranges_mm.split(",")]
    frames = {r: render_frames(calib, r, args.poses) for r in ranges}
    rows: list[tuple[str, PipelineConfig]] = [
        (f"paper, {float(f):g}", PipelineConfig(matcher="paper", window_factor=float(f)))
        for f in args.factors.split(",")
    ]
    rows.append(("ours (epipolar), 8", PipelineConfig(matcher="epipolar", window_factor=8.0)))
    head = "| matcher, window factor |"
    sep = "|---|"
    for r in ranges:
        m = f"{r / 1000:g} m"
        head += f" lock {m} | correct matches {m} | all 5 correct {m} | wrong locks {m} |"
        sep += "---|---|---|---|"
    print(f"{args.poses} random poses per range (tilt ≤ 20°), default noise")
    print(head)
    print(sep)
    for name, cfg in rows:
        line = f"| {name} |"
        for r in ranges:
            s = evaluate(calib, cfg, frames[r])
            line += (
                f" {100 * s['lock']:.0f} % | {100 * s['correct']:.0f} % "
                f"| {100 * s['all_correct']:.0f} % | {s['wrong_locks']} |"
            )
        print(line, flush=True)


if __name__ == "__main__":
    main()
