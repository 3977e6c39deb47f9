"""Flight-scale static frames: our matcher against the paper's (the README's reproducer).

The closed-loop drogue (ring radius 305 mm, 20 mm LEDs, fast noise as in the docking
simulation) head-on at 3, 6, 9 and 13 m (centre 60 mm off the left camera's axis), one frame
per seed, each solved by a fresh pipeline with
``PipelineConfig(ring_radius_mm=305, led_diameter_mm=20, matcher=m)``: ours (epipolar,
window factor 8) and the paper's (minimum descriptor distance, window factor 80). Prints a
Markdown table: locks; wrong locks (a lock that reports an LED whose left and right pixels are
not within 0.5 px of the same LED's truth pixels); locks with the centre > 5 mm off (at 13 m
this is depth noise, not a wrong match: σ_Z ≈ 31 mm per LED at 0.05 px of disparity noise);
centre error mean / max over the locks; and the fraction of the matcher's matches that are
correct (same 0.5 px test).

``--paper-factors 48,64,80,...`` adds rows for the paper's matcher at other window factors.

    .venv/bin/python benchmarks/flight_scale_matchers.py [--seeds 10] [--paper-factors ...]
"""

from __future__ import annotations

import argparse

import numpy as np

from app.resources import load_default_calibration
from app.sim.led_ring import LedRing
from app.sim.stereo_render import RenderSettings, render_pair
from app.vision.pipeline import NavigationPipeline, PipelineConfig

RING = LedRing(radius_mm=305.0, led_diameter_mm=20.0)
TOL_PX = 0.5
WRONG_LOCK_MM = 5.0


def _led_of(px, truth_px: np.ndarray) -> int:
    d = np.hypot(*(truth_px - np.asarray(px)).T)
    d = np.where(np.isfinite(d), d, np.inf)
    k = int(np.argmin(d))
    return k if d[k] <= TOL_PX else -1


def evaluate(calib, config: PipelineConfig, frames: list) -> dict:
    locks = wrong = far = n_match = n_correct = 0
    centre: list[float] = []
    for pair in frames:
        pipe = NavigationPipeline(calib, config)
        res = pipe.process(pair.left, pair.right)
        t, tr = pair.truth, pipe.trace
        for m in tr.matches:
            kl = _led_of(tr.left.blobs[m.left_index].centroid_px, t.led_left_px)
            kr = _led_of(tr.right.blobs[m.right_index].centroid_px, t.led_right_px)
            n_correct += int(kl >= 0 and kl == kr)
        n_match += len(tr.matches)
        if res.lock:
            locks += 1
            err = float(np.linalg.norm(np.array(res.drogue.center_mm) - t.center_mm))
            far += int(err > WRONG_LOCK_MM)
            pairs = [
                (_led_of(led.left_px, t.led_left_px), _led_of(led.right_px, t.led_right_px))
                for led in res.leds
            ]
            wrong += int(any(kl < 0 or kl != kr for kl, kr in pairs))
            centre.append(err)
    return {
        "locks": locks,
        "wrong": wrong,
        "far": far,
        "centre_mean": float(np.mean(centre)) if centre else float("nan"),
        "centre_max": float(np.max(centre)) if centre else float("nan"),
        "correct": n_correct / n_match if n_match else float("nan"),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--ranges-mm", default="3000,6000,9000,13000")
    ap.add_argument("--paper-factors", default="", help="extra paper rows, e.g. 48,64,96")
    args = ap.parse_args()
    calib = load_default_calibration()
    base = {"ring_radius_mm": RING.radius_mm, "led_diameter_mm": RING.led_diameter_mm}
    rows = [
        ("ours (epipolar, 8)", PipelineConfig(**base, matcher="epipolar")),
        ("paper (80)", PipelineConfig(**base, matcher="paper")),
    ]
    for f in (float(x) for x in args.paper_factors.split(",") if x):
        rows.append((f"paper ({f:g})", PipelineConfig(**base, matcher="paper", window_factor=f)))
    print(
        f"{args.seeds} seeds per range, head-on, ring 305 mm, LEDs 20 mm, "
        "RenderSettings(fast_noise=True)"
    )
    print(
        "| range (m) | matcher (window factor) | locks | wrong locks | centre > 5 mm "
        "| centre error mean / max (mm) | correct matches |"
    )
    print("|---|---|---|---|---|---|---|")
    for z in (float(x) for x in args.ranges_mm.split(",")):
        frames = [
            render_pair(
                calib,
                [60.0, 0.0, z],
                [0.0, 0.0, -1.0],
                settings=RenderSettings(fast_noise=True),
                ring=RING,
                seed=seed,
            )
            for seed in range(args.seeds)
        ]
        for name, cfg in rows:
            s = evaluate(calib, cfg, frames)
            print(
                f"| {z / 1000:g} | {name} | {s['locks']}/{len(frames)} | {s['wrong']} | {s['far']} "
                f"| {s['centre_mean']:.2f} / {s['centre_max']:.2f} | {100 * s['correct']:.0f} % |",
                flush=True,
            )


if __name__ == "__main__":
    main()
