"""Integrity on degraded images: lock rate, wrong locks, LED error and bound coverage per set.

Sets (docs/integrity.md, "Degraded images"):

* ``degraded``: bloom, Gaussian and motion blur, a sky gradient, JPEG and all of them at once,
  1 m, rendered and degraded with OpenCV only (``tests/support/degraded_frames.py``), one fresh
  pipeline per pair;
* ``mjpg``: a moving ring from 2.5 m to 1 m written as MJPG ``.avi`` at OpenCV's default
  quality and read back, through the tracker as ``aar-dock track`` runs it;
* ``hostile``: the hostile set (:mod:`app.sim.hostile`), scored the same way;
* ``optics``: the physically based dev / held-back sets (:mod:`app.sim.optics_eval`).

A wrong lock: centre or an LED more than 5 mm off (10 mm / 1 % of range on the optics set);
coverage: the true errors of a lock all inside its reported 99.9 % protection levels.

    .venv/bin/python benchmarks/bench_degraded.py [--sets degraded,mjpg,hostile,optics]
        [--seeds 6] [--frames 45] [--hostile-seeds 12] [--optics dev] [--eq11]
        [--noise default|sensor|image] [--hostile-colour grey|whitish|green] [--no-second-pass]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.resources import load_default_calibration  # noqa: E402
from app.sim.hostile import hostile_cases  # noqa: E402
from app.sim.led_ring import random_pose  # noqa: E402
from app.sim.optics_eval import evaluate, summarise  # noqa: E402
from app.sim.optics_set import load_optics_set  # noqa: E402
from app.sim.stereo_render import RenderSettings, render_pair  # noqa: E402
from app.vision.local_centroid import LocalCentroidConfig  # noqa: E402
from app.vision.pipeline import NavigationPipeline, PipelineConfig  # noqa: E402
from app.vision.tracking import StereoTracker  # noqa: E402
from tests.support.degraded_frames import (  # noqa: E402
    CASES,
    Scored,
    SetSummary,
    calibration,
    degraded_pair,
    mjpg_clip,
    score,
)

OPTICS = Path(__file__).resolve().parents[1] / "tests" / "data" / "optics"


def row(name: str, scored: list[Scored]) -> str:
    s = SetSummary.of(scored)
    cov = f"{s.bound_held}/{s.bound_checked}" if s.bound_checked else "–"
    reasons = Counter((x.reason or "")[:48] for x in scored if not x.lock)
    why = "; ".join(f"{n}× {r}" for r, n in reasons.most_common(2))
    return (
        f"| {name} | {s.runs} | {100 * s.locks / max(s.runs, 1):.0f} % | {s.wrong} | "
        f"{s.led_mean_mm:.3f} | {cov} | {why} |"
    )


HEAD = "| set | runs | lock | wrong | LED mean (mm) | bound held | refusals |\n|---|---:|---:|---:|---:|---:|---|"


def degraded(cfg: PipelineConfig, seeds: int) -> None:
    calib = calibration(load_default_calibration())
    everything = []
    for case in CASES:
        scored = []
        for seed in range(seeds):
            p = degraded_pair(calib, case, seed)
            res = NavigationPipeline(calib, cfg).process(p.left, p.right)
            scored.append(score(res, p.led_xyz_mm, p.center_mm))
        everything += scored
        print(row(f"{case} 1 m", scored), flush=True)
    print(row("all degraded", everything), flush=True)


def mjpg(cfg: PipelineConfig, frames: int, colour: bool) -> None:
    calib = calibration(load_default_calibration())
    clip = mjpg_clip(calib, frames, colour=colour)
    tracker = StereoTracker(calib, cfg)
    scored = []
    for left, right, leds, centre in zip(
        clip.lefts, clip.rights, clip.led_xyz_mm, clip.centers_mm, strict=True
    ):
        scored.append(score(tracker.update(left, right), leds, centre))
    kind = "colour" if colour else "grey"
    print(row(f"MJPG {kind} 2.5→1 m, tracker", scored), flush=True)


def hostile(cfg: PipelineConfig, seeds: int, only: str, colour: str = "grey") -> None:
    """The hostile set; ``colour``: ``grey`` as defined, ``whitish`` / ``green``: every case
    rendered as colour frames with whitish / LED-green glints (the second pass on gray runs
    only on colour frames)."""
    calib = load_default_calibration()
    everything = []
    for case in hostile_cases():
        if only and only not in case.name:
            continue
        if colour != "grey":
            case = replace(case, settings=_coloured(case.settings, colour == "green"))
        scored = []
        for seed in range(seeds):
            rng = np.random.default_rng([seed, 7])
            centre, normal = random_pose(
                rng, case.range_mm, case.max_tilt_deg, calib=calib, ring=case.ring
            )
            roll = float(rng.uniform(-np.pi, np.pi))
            pair = render_pair(
                calib, centre, normal, case.settings(seed), ring=case.ring, seed=seed, roll_rad=roll
            )
            res = NavigationPipeline(calib, replace(cfg)).process(pair.left, pair.right)
            s = score(res, pair.truth.led_xyz_mm, pair.truth.center_mm)
            if s.lock and not case.leds_present:
                s = replace(s, wrong=True)
            scored.append(s)
        everything += scored
        print(row(case.name, scored), flush=True)
    print(row("all hostile", everything), flush=True)


def _coloured(
    settings: Callable[[int], RenderSettings], led_green: bool
) -> Callable[[int], RenderSettings]:
    return lambda seed: replace(settings(seed), color=True, glint_led_color=led_green)


def optics(cfg: PipelineConfig, which: str, seeds: int) -> None:
    calib = load_default_calibration()
    for name in {"both": ["dev", "holdout"], "all": ["dev", "holdout", "blind"]}.get(
        which, [which]
    ):
        out = evaluate(calib, load_optics_set(OPTICS / name), range(seeds), cfg)
        for cond in [*sorted({o.condition for o in out}), "all"]:
            g = [o for o in out if cond == "all" or o.condition == cond]
            s = summarise(g, max_range_mm=2500.0)
            cov = f"{s.bound_held}/{s.bound_checked}" if s.bound_checked else "–"
            reasons = Counter((o.reason or "")[:48] for o in g if not o.lock)
            why = "; ".join(f"{n}× {r}" for r, n in reasons.most_common(2))
            print(
                f"| optics {name}: {cond} | {s.runs} | {100 * s.lock_rate:.0f} % | {s.wrong} | "
                f"{s.led_error_mean_mm:.3f} | {cov} | {why} |",
                flush=True,
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", default="degraded,mjpg,hostile,optics")
    ap.add_argument("--seeds", type=int, default=6, help="poses per degraded case")
    ap.add_argument("--frames", type=int, default=45, help="frames of the MJPG clip")
    ap.add_argument("--hostile-seeds", type=int, default=12)
    ap.add_argument("--only", default="", help="hostile cases whose name contains this")
    ap.add_argument(
        "--hostile-colour",
        default="grey",
        choices=["grey", "whitish", "green"],
        help="render every hostile case as colour frames, glints whitish or LED-green",
    )
    ap.add_argument(
        "--no-second-pass",
        action="store_true",
        help="without the second pass on refused frames (small blobs, gray): the baseline",
    )
    ap.add_argument("--optics", default="dev", choices=["dev", "holdout", "blind", "both", "all"])
    ap.add_argument("--optics-seeds", type=int, default=2)
    ap.add_argument("--eq11", action="store_true", help="the paper's eq. 11 centroid instead")
    ap.add_argument(
        "--noise",
        default="default",
        choices=["default", "sensor", "image"],
        help="centroid σ: the sensor model only, or also the image's own (default: the config's)",
    )
    args = ap.parse_args()
    cfg = PipelineConfig()
    if args.eq11:
        cfg = replace(cfg, centroid=LocalCentroidConfig(enabled=False))
    if args.noise != "default":
        cfg = replace(cfg, centroid=replace(cfg.centroid, image_noise=args.noise == "image"))
    if args.no_second_pass:
        cfg = replace(cfg, retry_min_area_px=None, retry_gray=False)
    sets = args.sets.split(",")
    t0 = time.perf_counter()
    print(HEAD)
    if "degraded" in sets:
        degraded(cfg, args.seeds)
    if "mjpg" in sets:
        mjpg(cfg, args.frames, colour=True)
        mjpg(cfg, args.frames, colour=False)
    if "hostile" in sets:
        hostile(cfg, args.hostile_seeds, args.only, args.hostile_colour)
    if "optics" in sets:
        optics(cfg, args.optics, args.optics_seeds)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
