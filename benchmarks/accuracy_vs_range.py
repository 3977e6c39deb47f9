"""Error of the pipeline against the renderer's ground truth versus range (0.5–5 m).

Random poses (tilt ≤ 20°), default noise; each pose is rendered once and solved by both
matchers — ours (epipolar gate + global assignment, IHWT window factor 8) and the paper's
(minimum descriptor distance only, eq. 14, at its default window factor 80) — with a fresh
track per frame (independent frames). Prints a Markdown table for the README with the same
columns for both, side by side:

* lock rate;
* wrong locks: locks whose drogue centre is > 5 mm from the truth;
* wrong LEDs: reported LEDs whose left pixel is > 0.5 px from the truth pixel of that id;
* LED 3-D error mean / p95, centre error mean, normal error mean (over locked frames).

    .venv/bin/python benchmarks/accuracy_vs_range.py [--poses 50] [--ranges-mm 500,1000,...]
"""

from __future__ import annotations

import argparse

import numpy as np

from app.resources import load_default_calibration
from app.sim.led_ring import random_pose
from app.sim.stereo_render import RenderSettings, render_pair
from app.vision.pipeline import NavigationPipeline, PipelineConfig

WRONG_LOCK_MM = 5.0
MATCHERS = ("epipolar", "paper")


def angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


class _Stats:
    def __init__(self) -> None:
        self.locks = self.wrong_locks = self.wrong_leds = 0
        self.led: list[float] = []
        self.centre: list[float] = []
        self.normal: list[float] = []

    def add(self, res, t) -> None:
        if not res.lock:
            return
        self.locks += 1
        for item in res.leds:
            k = item.id - 1
            if np.hypot(*(np.array(item.left_px) - t.led_left_px[k])) > 0.5:
                self.wrong_leds += 1
            self.led.append(float(np.linalg.norm(np.array(item.xyz_mm) - t.led_xyz_mm[k])))
        err = float(np.linalg.norm(np.array(res.drogue.center_mm) - t.center_mm))
        self.wrong_locks += int(err > WRONG_LOCK_MM)
        self.centre.append(err)
        self.normal.append(angle_deg(res.drogue.normal, t.normal))

    def summary(self, poses: int) -> dict:
        def stat(v, f):
            return float(f(v)) if v else float("nan")

        return {
            "lock": self.locks / poses,
            "wrong_locks": self.wrong_locks,
            "wrong_leds": self.wrong_leds,
            "led_mean": stat(self.led, np.mean),
            "led_p95": stat(self.led, lambda v: np.percentile(v, 95)),
            "centre_mean": stat(self.centre, np.mean),
            "normal_mean": stat(self.normal, np.mean),
        }


def run(range_mm: float, poses: int, calib, clutter: int = 0) -> dict[str, dict]:
    pipes = {m: NavigationPipeline(calib, PipelineConfig(matcher=m)) for m in MATCHERS}
    stats = {m: _Stats() for m in MATCHERS}
    rng = np.random.default_rng(int(range_mm))
    for seed in range(poses):
        c, n = random_pose(rng, range_mm, 20.0)
        pair = render_pair(calib, c, n, RenderSettings(clutter=clutter), seed=seed)
        for m, pipe in pipes.items():
            pipe.reset()
            stats[m].add(pipe.process(pair.left, pair.right), pair.truth)
    return {m: s.summary(poses) for m, s in stats.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=50)
    ap.add_argument("--ranges-mm", default="500,750,1000,1500,2000,2500,3500,5000")
    args = ap.parse_args()
    calib = load_default_calibration()
    fb = 0.5 * (calib.left.fx + calib.right.fx) * calib.baseline_mm
    print(
        "| range (m) | lock (ours / paper) | wrong locks (ours / paper) "
        "| wrong LEDs (ours / paper) | LED 3-D error mean / p95, ours (mm) "
        "| LED 3-D error mean / p95, paper (mm) | centre error, ours / paper (mm) "
        "| normal error, ours / paper (°) | σ_Z at 0.05 px (mm) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in (float(x) for x in args.ranges_mm.split(",")):
        s = run(r, args.poses, calib)
        o, p = s["epipolar"], s["paper"]
        print(
            f"| {r / 1000:.2f} | {100 * o['lock']:.0f} % / {100 * p['lock']:.0f} % "
            f"| {o['wrong_locks']} / {p['wrong_locks']} | {o['wrong_leds']} / {p['wrong_leds']} "
            f"| {o['led_mean']:.3f} / {o['led_p95']:.3f} | {p['led_mean']:.3f} / {p['led_p95']:.3f} "
            f"| {o['centre_mean']:.3f} / {p['centre_mean']:.3f} "
            f"| {o['normal_mean']:.3f} / {p['normal_mean']:.3f} | {r**2 * 0.05 / fb:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
