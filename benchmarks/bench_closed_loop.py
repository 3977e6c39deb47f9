"""Closed-loop docking speed: simulated seconds per wall second, and Dask campaign throughput.

    .venv/bin/python benchmarks/bench_closed_loop.py [--sim-seconds 3] [--repeats 3] [--runs 8]

Part 1 (one core: BLAS/OpenCV threads pinned to 1): the same scenario stepped with truth
measurements (baseline), vision in the loop at the full tick rate (50 Hz camera), and vision at a
25 Hz camera with the drogue filter predicting in between; medians over repeats, with the per-frame
render and pipeline times. Part 2: campaign throughput (runs/min) with 1 vs 2 Dask worker
processes, truth measurements and vision (25 Hz camera). Prints plain tables; asserts nothing.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import cv2  # noqa: E402

from app.sim.campaign import run_campaign  # noqa: E402
from app.sim.docking import DockingConfig, DockingSimulation  # noqa: E402

cv2.setNumThreads(1)


def realtime_factor(cfg: DockingConfig, sim_seconds: float) -> tuple[float, float, float]:
    """(sim s per wall s, mean render ms per frame, mean pipeline ms per frame)."""
    import app.sim.stereo_render as sr

    sim = DockingSimulation(cfg)
    render_ms: list[float] = []
    orig = sr.render_pair

    def timed(*a, **k):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        out = orig(*a, **k)
        render_ms.append(1e3 * (time.perf_counter() - t0))
        return out

    sr.render_pair = timed
    pipe_ms: list[float] = []
    try:
        n = int(round(sim_seconds / sim.dt))
        t0 = time.perf_counter()
        for _ in range(n):
            tick = sim.step()
            if tick.pose is not None:
                pipe_ms.append(tick.pose.timing_ms.total)
        wall = time.perf_counter() - t0
    finally:
        sr.render_pair = orig
    mean = lambda xs: statistics.fmean(xs) if xs else 0.0  # noqa: E731
    return n * sim.dt / wall, mean(render_ms), mean(pipe_ms)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sim-seconds", type=float, default=3.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--runs", type=int, default=8, help="campaign runs per throughput measurement")
    ap.add_argument("--vision-runs", type=int, default=4)
    args = ap.parse_args()

    base = DockingConfig(turbulence="light", seed=0, station_keep_s=1.0)
    cases = [
        ("truth measurements", replace(base, vision=False)),
        ("vision, 50 Hz camera", replace(base, vision=True)),
        ("vision, 25 Hz camera", replace(base, vision=True, camera_hz=25.0)),
        ("vision, 50 Hz, ROI window", replace(base, vision=True, roi_tracking=True)),
        (
            "vision, 10 Hz, ROI window",
            replace(base, vision=True, camera_hz=10.0, roi_tracking=True),
        ),
    ]
    print(f"## Simulated seconds per wall second (one core, 50 Hz tick, median of {args.repeats})")
    print(
        f"{'case':28s} {'sim s / wall s':>15s} {'vs truth':>9s} {'render ms':>10s} {'pipeline ms':>12s}"
    )
    baseline = None
    for name, cfg in cases:
        res = [realtime_factor(cfg, args.sim_seconds) for _ in range(args.repeats)]
        rtf = statistics.median(r[0] for r in res)
        if baseline is None:
            baseline = rtf
        rms = statistics.median(r[1] for r in res)
        pms = statistics.median(r[2] for r in res)
        print(f"{name:28s} {rtf:15.2f} {rtf / baseline:9.3f} {rms:10.1f} {pms:12.1f}")

    print("\n## Campaign throughput, Dask LocalCluster (1 thread per worker process)")
    print(
        f"{'case':28s} {'workers':>7s} {'runs':>5s} {'wall s':>8s} {'runs/min':>9s} {'speed-up':>9s}"
    )
    for name, cfg, runs in (
        ("truth measurements", replace(base, vision=False), args.runs),
        ("vision, 25 Hz camera", replace(base, vision=True, camera_hz=25.0), args.vision_runs),
    ):
        ref = None
        for workers in (1, 2):
            t0 = time.perf_counter()
            run_campaign(cfg, runs, first_seed=100, workers=workers)
            wall = time.perf_counter() - t0
            rate = 60.0 * runs / wall
            ref = ref or rate
            print(f"{name:28s} {workers:7d} {runs:5d} {wall:8.1f} {rate:9.2f} {rate / ref:9.2f}")
    print(f"\n(cpu count: {os.cpu_count()}; wall times include cluster start-up)")


if __name__ == "__main__":
    main()
