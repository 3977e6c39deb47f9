"""Stereo LED renderer speed: median time per 1280×1024 stereo pair.

Compares the default renderer (fresh full-frame Gaussian noise per image), the ``fast_noise``
renderer (noise window cut from a cached field at a random offset, blobs touched in patches)
and a baseline that only makes two full-frame noisy backgrounds the plain way
(``np.random`` Generator ``normal``, float64, clip, uint8), with no LEDs at all.

    .venv/bin/python benchmarks/bench_render.py [--repeats 50]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from app.resources import load_default_calibration
from app.sim.stereo_render import RenderSettings, render_pair


def median_ms(fn: Callable[[int], object], repeats: int) -> float:
    fn(0)  # warm-up (fills the noise-field cache for fast_noise)
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        fn(i + 1)
        times.append(time.perf_counter() - t0)
    return 1000.0 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()

    calib = load_default_calibration()
    w, h = calib.image_size
    center, normal = np.array([20.0, 0.0, 1000.0]), np.array([0.0, 0.0, -1.0])

    def baseline(seed: int) -> object:
        rng = np.random.default_rng(seed)
        out = []
        for _ in range(2):
            img = 12.0 + rng.normal(0.0, 2.0, size=(h, w))
            out.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
        return out

    def renderer(settings: RenderSettings) -> Callable[[int], object]:
        return lambda seed: render_pair(calib, center, normal, settings, seed=seed)

    cases: list[tuple[str, Callable[[int], object]]] = [
        ("baseline: np.random normal full-frame ×2, no LEDs", baseline),
        ("render_pair default (grey)", renderer(RenderSettings())),
        ("render_pair fast_noise (grey)", renderer(RenderSettings(fast_noise=True))),
        ("render_pair default, 12 clutter", renderer(RenderSettings(clutter=12))),
        (
            "render_pair fast_noise, 12 clutter",
            renderer(RenderSettings(clutter=12, fast_noise=True)),
        ),
        ("render_pair default (BGR colour)", renderer(RenderSettings(color=True))),
        (
            "render_pair fast_noise (BGR colour)",
            renderer(RenderSettings(color=True, fast_noise=True)),
        ),
    ]
    results = [(name, median_ms(fn, args.repeats)) for name, fn in cases]
    base = results[0][1]
    default = results[1][1]
    print(f"Stereo pair {w}×{h}, ring at 1 m, median of {args.repeats} runs")
    print(f"{'case':58s} {'ms/pair':>9s} {'vs baseline':>12s} {'vs default':>11s}")
    for name, ms in results:
        print(f"{name:58s} {ms:9.2f} {ms / base:11.2f}x {ms / default:10.2f}x")


if __name__ == "__main__":
    main()
