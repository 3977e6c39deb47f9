"""Error of the pipeline against the renderer's ground truth versus range (0.5–5 m).

Random poses (tilt ≤ 20°), default noise; prints a Markdown table for the README, with the
paper's matcher (minimum descriptor distance only) next to ours for the lock/correct rate.

    .venv/bin/python benchmarks/accuracy_vs_range.py [--poses 50]
"""

from __future__ import annotations

import argparse

import numpy as np

from app.sim.led_ring import random_pose
from app.sim.paths import load_default_calibration
from app.sim.stereo_render import RenderSettings, render_pair
from app.vision.pipeline import NavigationPipeline, PipelineConfig


def angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def run(range_mm: float, poses: int, calib, clutter: int = 0) -> dict:
    ours = NavigationPipeline(calib, PipelineConfig())
    paper = NavigationPipeline(calib, PipelineConfig(matcher="paper"))
    rng = np.random.default_rng(int(range_mm))
    led, centre, normal, locks, paper_locks, wrong = [], [], [], 0, 0, 0
    for seed in range(poses):
        c, n = random_pose(rng, range_mm, 20.0)
        pair = render_pair(calib, c, n, RenderSettings(clutter=clutter), seed=seed)
        t = pair.truth
        res = ours.process(pair.left, pair.right)
        pres = paper.process(pair.left, pair.right)
        paper_locks += int(pres.lock)
        if not res.lock:
            continue
        locks += 1
        for item in res.leds:
            k = item.id - 1
            if np.hypot(*(np.array(item.left_px) - t.led_left_px[k])) > 0.5:
                wrong += 1
            led.append(np.linalg.norm(np.array(item.xyz_mm) - t.led_xyz_mm[k]))
        centre.append(np.linalg.norm(np.array(res.drogue.center_mm) - t.center_mm))
        normal.append(angle_deg(res.drogue.normal, t.normal))
    return {
        "range_m": range_mm / 1000.0,
        "poses": poses,
        "lock": locks / poses,
        "paper_lock": paper_locks / poses,
        "wrong": wrong,
        "led_mean": float(np.mean(led)) if led else float("nan"),
        "led_p95": float(np.percentile(led, 95)) if led else float("nan"),
        "centre_mean": float(np.mean(centre)) if centre else float("nan"),
        "normal_mean": float(np.mean(normal)) if normal else float("nan"),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=50)
    ap.add_argument("--ranges-mm", default="500,750,1000,1500,2000,2500,3500,5000")
    args = ap.parse_args()
    calib = load_default_calibration()
    fb = 0.5 * (calib.left.fx + calib.right.fx) * calib.baseline_mm
    print(
        "| range (m) | lock (ours) | lock (paper matcher) | wrong matches | LED 3-D error mean / p95 (mm) "
        "| centre error (mm) | normal error (°) | σ_Z at 0.05 px (mm) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in (float(x) for x in args.ranges_mm.split(",")):
        s = run(r, args.poses, calib)
        print(
            f"| {s['range_m']:.2f} | {100 * s['lock']:.0f} % | {100 * s['paper_lock']:.0f} % | {s['wrong']} "
            f"| {s['led_mean']:.3f} / {s['led_p95']:.3f} | {s['centre_mean']:.3f} | {s['normal_mean']:.3f} "
            f"| {r**2 * 0.05 / fb:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
