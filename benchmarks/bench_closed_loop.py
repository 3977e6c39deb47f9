"""Closed-loop docking speed: simulated seconds per wall second, and Dask campaign throughput.

    .venv/bin/python benchmarks/bench_closed_loop.py [--sim-seconds 6] [--seeds 3] [--campaign]
        [--plants jsbsim,linear] [--hose reduced,multibody]

Part 1 (one core: BLAS/OpenCV threads pinned to 1): the same scenarios (light turbulence, a few
seeds, the first ``--sim-seconds`` of the approach plus the same length of station keeping at
3 m) stepped with truth measurements (baseline), vision at 50 Hz rendering full frames, and
vision at 50 Hz rendering only the tracker's windows (``render_mode="windows"``); medians over
the seeds of the real-time factor (per wall second and per CPU second of the process; "vs
truth" is the CPU-time ratio), with the per-frame render and tracker times and the share of
frames the tracker tracked — for each plant (the A-4 on JSBSim, the linear design model), with
the JSBSim ÷ linear ratio of the real-time factors in the same run; with ``--hose`` for each flown
hose model (``DockingConfig.hose_model``), with the hose's own cost per tick (its free and
latched steps, timed inside the loop). Part 2 (``--campaign``): campaign throughput (runs/min) with 1 vs 2
Dask worker processes. Prints plain tables; asserts nothing.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import itertools  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import cv2  # noqa: E402

from app.sim.campaign import run_campaign  # noqa: E402
from app.sim.docking import DockingConfig, DockingSimulation  # noqa: E402
from app.sim.warmup import compile_kernels  # noqa: E402

cv2.setNumThreads(1)


def realtime_factor(
    cfg: DockingConfig, sim_seconds: float
) -> tuple[float, float, float, float, float, float]:
    """(sim s per wall s, sim s per CPU s of this process, median render ms per frame, median
    tracker ms per frame, tracked share, the hose's CPU µs per tick) over the first
    ``sim_seconds`` and ``sim_seconds`` of station keeping. On a shared machine the CPU-time
    factor is the steadier one."""
    import app.sim.camera_sensor as cs

    sim = DockingSimulation(cfg)
    hose_cpu = [0.0]

    def timed_hose(method):  # type: ignore[no-untyped-def]
        def run(*a, **k):  # type: ignore[no-untyped-def]
            c0 = time.process_time()
            method(*a, **k)
            hose_cpu[0] += time.process_time() - c0

        return run

    sim.drogue.step = timed_hose(sim.drogue.step)  # type: ignore[method-assign]
    sim.drogue.ride = timed_hose(sim.drogue.ride)  # type: ignore[method-assign]
    render_ms: list[float] = []
    orig = cs.render_pair

    def timed(*a, **k):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        out = orig(*a, **k)
        render_ms.append(1e3 * (time.perf_counter() - t0))
        return out

    cs.render_pair = timed
    track_ms: list[float] = []
    tracked = frames = 0
    n = int(round(sim_seconds / sim.dt))
    wall = cpu = hose_s = 0.0
    steps = 0
    try:
        for part in range(2):
            if part == 1:  # skip ahead to station keeping (not timed)
                while not sim.captured and not sim.done:
                    sim.step()
                if sim.done:
                    break
            hose_before = hose_cpu[0]
            t0, c0 = time.perf_counter(), time.process_time()
            for _ in range(n):
                if sim.done:
                    break
                tick = sim.step()
                steps += 1
                if tick.pose is not None:
                    frames += 1
                    tracked += tick.pose.reason == "tracked"
                    track_ms.append(tick.pose.timing_ms.total)
            wall += time.perf_counter() - t0
            cpu += time.process_time() - c0
            hose_s += hose_cpu[0] - hose_before
    finally:
        cs.render_pair = orig
    med = lambda xs: statistics.median(xs) if xs else 0.0  # noqa: E731
    sim_s = steps * sim.dt
    return (
        sim_s / wall,
        sim_s / cpu,
        med(render_ms),
        med(track_ms),
        tracked / max(frames, 1),
        1e6 * hose_s / max(steps, 1),
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sim-seconds", type=float, default=6.0)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--campaign", action="store_true", help="also measure Dask throughput")
    ap.add_argument("--runs", type=int, default=8, help="campaign runs per throughput measurement")
    ap.add_argument("--vision-runs", type=int, default=4)
    ap.add_argument("--plants", default="jsbsim,linear", help="comma-separated plants")
    ap.add_argument(
        "--hose", default="reduced", help="comma-separated flown hose models (reduced,multibody)"
    )
    args = ap.parse_args()
    print(f"(compiled loops ready in {compile_kernels():.1f} s; not timed)")

    base = DockingConfig(turbulence="light", seed=0, station_keep_s=1.0)
    cases = [
        ("truth measurements", replace(base, vision=False)),
        ("vision 50 Hz, full render", replace(base, vision=True, render_mode="full")),
        ("vision 50 Hz, windows", replace(base, vision=True, render_mode="windows")),
    ]
    print(
        f"## Simulated seconds per wall second (one core, 50 Hz tick and camera, "
        f"{args.sim_seconds:g} s approach + {args.sim_seconds:g} s station keeping, "
        f"median of {args.seeds} seeds)"
    )
    print(
        f"{'plant':7s} {'hose':9s} {'case':28s} {'real-time ×':>12s} {'per CPU s':>10s} "
        f"{'vs truth':>9s} {'render ms':>10s} {'tracker ms':>11s} {'tracked':>8s} "
        f"{'hose µs/tick':>12s}"
    )
    factors: dict[tuple[str, str], float] = {}
    for plant, hose in itertools.product(args.plants.split(","), args.hose.split(",")):
        baseline = None
        for name, cfg in cases:
            res = [
                realtime_factor(
                    replace(cfg, plant=plant, hose_model=hose, seed=s), args.sim_seconds
                )
                for s in range(args.seeds)
            ]
            rtf = statistics.median(r[0] for r in res)
            cpu_f = statistics.median(r[1] for r in res)
            if hose == "reduced" or (plant, name) not in factors:
                factors[(plant, name)] = cpu_f
            if baseline is None:
                baseline = cpu_f
            rms = statistics.median(r[2] for r in res)
            tms = statistics.median(r[3] for r in res)
            share = statistics.median(r[4] for r in res)
            hose_us = statistics.median(r[5] for r in res)
            print(
                f"{plant:7s} {hose:9s} {name:28s} {rtf:12.2f} {cpu_f:10.2f} "
                f"{cpu_f / baseline:9.3f} {rms:10.2f} {tms:11.2f} {100 * share:7.0f}% "
                f"{hose_us:12.0f}"
            )
    if ("jsbsim", cases[0][0]) in factors and ("linear", cases[0][0]) in factors:
        print("\nJSBSim ÷ linear plant (real-time factor per CPU s, same run):")
        for name, _ in cases:
            print(f"  {name:28s} {factors[('jsbsim', name)] / factors[('linear', name)]:6.3f}")
    if not args.campaign:
        return
    print("\n## Campaign throughput, Dask LocalCluster (1 thread per worker process)")
    print(
        f"{'case':28s} {'workers':>7s} {'runs':>5s} {'wall s':>8s} {'runs/min':>9s} {'speed-up':>9s}"
    )
    for name, cfg, runs in (
        ("truth measurements", replace(base, vision=False), args.runs),
        ("vision 50 Hz, windows", replace(base, render_mode="windows"), args.vision_runs),
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
