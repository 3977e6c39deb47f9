"""Navigation on the physically based optics set: lock rates, wrong locks, accuracy, bounds.

Runs every case of a set (``tests/data/optics/dev``, ``holdout`` or ``blind``, rendered with Mitsuba 3 by
``benchmarks/optics/render_optics_set.py``) for a few sensor-noise seeds through

* ``ours``: the pipeline as shipped (local-support centroids, colour gate, error bound);
* ``eq11``: the same with the paper's eq. 11 centroid (``centroid.enabled=False``);

and, on the same frames, the plain local-centroid + OpenCV baseline with oracle association
(:mod:`app.sim.optics_eval`). Prints one Markdown table per configuration (by condition) and
the acceptance figures.

    .venv/bin/python benchmarks/bench_optics.py [--set dev|holdout|blind|both|all] [--seeds 3]
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

from app.resources import load_default_calibration
from app.sim.optics_eval import OpticsOutcome, evaluate, summarise
from app.sim.optics_set import load_optics_set
from app.vision.local_centroid import LocalCentroidConfig
from app.vision.pipeline import PipelineConfig

SETS = Path(__file__).resolve().parents[1] / "tests" / "data" / "optics"


def table(outcomes: list[OpticsOutcome]) -> str:
    conds = sorted({o.condition for o in outcomes})
    lines = [
        "| condition | runs | lock % | wrong | loose | LED err ≤2.5 m mean / median (mm) | "
        "baseline, same frames (mm) | bound held |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in [*conds, "all"]:
        group = [o for o in outcomes if c == "all" or o.condition == c]
        s = summarise(group, max_range_mm=2500.0)
        bound = f"{s.bound_held}/{s.bound_checked}" if s.bound_checked else "–"
        lines.append(
            f"| {c} | {s.runs} | {100 * s.lock_rate:.0f} | {s.wrong} | {s.loose} | "
            f"{s.led_error_mean_mm:.3f} / {s.led_error_median_mm:.3f} | "
            f"{s.baseline_error_mean_mm:.3f} / {s.baseline_error_median_mm:.3f} | {bound} |"
        )
    return "\n".join(lines)


def refusals(outcomes: list[OpticsOutcome], top: int = 6) -> str:
    reasons = Counter((o.reason or "")[:70] for o in outcomes if not o.lock)
    return "\n".join(f"  {n:3d} × {r}" for r, n in reasons.most_common(top))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--set", default="dev", choices=["dev", "holdout", "blind", "both", "all"])
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    calib = load_default_calibration()
    names = {"both": ["dev", "holdout"], "all": ["dev", "holdout", "blind"]}.get(
        args.set, [args.set]
    )
    ours = PipelineConfig()
    configs = {
        "ours": ours,
        "eq11": replace(ours, centroid=LocalCentroidConfig(enabled=False)),
    }
    for name in names:
        cases = load_optics_set(SETS / name)
        for label, cfg in configs.items():
            t0 = time.perf_counter()
            out = evaluate(calib, cases, range(args.seeds), cfg)
            dt = time.perf_counter() - t0
            print(
                f"\n### {name} set — {label} ({len(cases)} cases × {args.seeds} seeds, {dt:.0f} s)\n"
            )
            print(table(out))
            worst = sorted((o for o in out if o.lock), key=lambda o: -o.worst_mm / o.range_mm)[:3]
            for o in worst:
                print(
                    f"  worst: {o.case} seed {o.seed} ({o.condition}, {o.range_mm / 1000:.1f} m): "
                    f"{o.worst_mm:.2f} mm"
                )
            print("  refusals:\n" + refusals(out))


if __name__ == "__main__":
    main()
