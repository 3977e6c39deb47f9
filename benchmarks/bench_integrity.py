"""Integrity cost and benefit: this pipeline against the pipeline before the integrity work.

The baseline is the same repository at ``--baseline-rev`` (default 8fc3348, the commit
before issue 8), checked out into a temporary git worktree and run in a child process on
exactly the same frames (saved to a temporary .npz). Rounds alternate (ours, baseline, ours,
…) and the median per frame set is quoted, so the ratio is robust to a noisy machine.

Prints two tables: speed (clean frames: ours / baseline; hostile frames: ours / our clean),
and wrong locks / locks on the hostile frames for both.

    .venv/bin/python benchmarks/bench_integrity.py [--frames 20] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

from app.resources import REPO_ROOT, load_default_calibration
from app.sim.hostile import WRONG_MM
from app.sim.led_ring import random_pose
from app.sim.stereo_render import RenderSettings, render_pair
from app.vision.pipeline import NavigationPipeline

CHILD = r"""
import json, sys, time
import numpy as np
from app.resources import load_default_calibration
from app.vision.pipeline import NavigationPipeline
data = np.load(sys.argv[1])
calib = load_default_calibration()
out = {}
for key in sorted({k.rsplit("_", 2)[0] for k in data.files}):
    n = len([k for k in data.files if k.startswith(key + "_L_")])
    times, results = [], []
    pipe = NavigationPipeline(calib)
    for i in range(n):
        left, right = data[f"{key}_L_{i}"], data[f"{key}_R_{i}"]
        pipe.process(left, right)
        t0 = time.perf_counter()
        res = pipe.process(left, right)
        times.append((time.perf_counter() - t0) * 1e3)
        results.append({
            "lock": res.lock,
            "center": None if res.drogue is None else list(res.drogue.center_mm),
            "leds": [list(led.xyz_mm) for led in res.leds],
        })
    out[key] = {"ms": times, "results": results}
json.dump(out, sys.stdout)
"""

SETS = {
    "clean_1000mm": (1000.0, RenderSettings()),
    "clean_1500mm": (1500.0, RenderSettings()),
    "glints30": (1500.0, RenderSettings(glints=30)),
    "glints50": (1500.0, RenderSettings(glints=50)),
    "glints80": (1500.0, RenderSettings(glints=80)),
    "glints30_noleds": (1500.0, RenderSettings(glints=30, occluded=(1, 2, 3, 4, 5))),
    "rim10_2occluded": (1500.0, RenderSettings(rim_reflections=((2, 10.0),), occluded=(1, 3))),
}


def make_frames(n: int):
    calib = load_default_calibration()
    frames, truth = {}, {}
    for key, (rng_mm, settings) in SETS.items():
        rng = np.random.default_rng(zlib.crc32(key.encode()))
        for i in range(n):
            c, nn = random_pose(rng, rng_mm, 20.0)
            pair = render_pair(calib, c, nn, settings, seed=i)
            frames[f"{key}_L_{i}"] = pair.left
            frames[f"{key}_R_{i}"] = pair.right
            truth.setdefault(key, []).append(pair.truth)
    return frames, truth


def run_ours(frames: dict, n: int) -> dict:
    calib = load_default_calibration()
    out = {}
    for key in SETS:
        pipe = NavigationPipeline(calib)
        times, results = [], []
        for i in range(n):
            left, right = frames[f"{key}_L_{i}"], frames[f"{key}_R_{i}"]
            pipe.reset()
            pipe.process(left, right)
            pipe.reset()
            t0 = time.perf_counter()
            res = pipe.process(left, right)
            times.append((time.perf_counter() - t0) * 1e3)
            results.append(
                {
                    "lock": res.lock,
                    "center": None if res.drogue is None else list(res.drogue.center_mm),
                    "leds": [list(led.xyz_mm) for led in res.leds],
                }
            )
        out[key] = {"ms": times, "results": results}
    return out


def run_baseline(worktree: Path, npz: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(worktree))
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(npz)],
        cwd=worktree,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(proc.stdout)


def wrong(result: dict, truth, leds_present: bool) -> bool:
    if not result["lock"]:
        return False
    if not leds_present:
        return True
    if np.linalg.norm(np.array(result["center"]) - truth.center_mm) > WRONG_MM:
        return True
    return any(
        np.min(np.linalg.norm(truth.led_xyz_mm - np.array(x), axis=1)) > WRONG_MM
        for x in result["leds"]
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--baseline-rev", default="8fc3348")
    args = ap.parse_args()
    frames, truth = make_frames(args.frames)
    with tempfile.TemporaryDirectory() as tmp:
        npz = Path(tmp) / "frames.npz"
        np.savez(npz, **frames)
        worktree = Path(tmp) / "baseline"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(worktree), args.baseline_rev],
            cwd=REPO_ROOT,
            check=True,
            capture_output=True,
        )
        try:
            ours_runs, base_runs = [], []
            for _ in range(args.rounds):
                ours_runs.append(run_ours(frames, args.frames))
                base_runs.append(run_baseline(worktree, npz))
        finally:
            subprocess.run(
                ["git", "worktree", "remove", "--force", str(worktree)], cwd=REPO_ROOT, check=False
            )

    def med(runs: list[dict], key: str) -> float:
        return statistics.median(statistics.median(r[key]["ms"]) for r in runs)

    rev = args.baseline_rev
    print(f"Speed, median ms per stereo pair ({args.frames} frames × {args.rounds} rounds):")
    print(f"| frames | ours | before ({rev}) | ours / before | ours / our clean 1.5 m |")
    print("|---|---|---|---|---|")
    clean = med(ours_runs, "clean_1500mm")
    for key in SETS:
        o, b = med(ours_runs, key), med(base_runs, key)
        print(f"| {key} | {o:.2f} | {b:.2f} | {o / b:.2f} | {o / clean:.2f} |")
    print("\nLocks and wrong locks (centre > 5 mm off or an LED > 5 mm from every real LED):")
    print(f"| frames | ours: locks | ours: wrong | before ({rev}): locks | before: wrong |")
    print("|---|---|---|---|---|")
    for key in SETS:
        present = "noleds" not in key
        row = []
        for runs in (ours_runs, base_runs):
            res = runs[0][key]["results"]
            row.append(sum(r["lock"] for r in res))
            row.append(sum(wrong(r, t, present) for r, t in zip(res, truth[key], strict=True)))
        n = args.frames
        print(f"| {key} | {row[0]}/{n} | {row[1]} | {row[2]}/{n} | {row[3]} |")


if __name__ == "__main__":
    main()
