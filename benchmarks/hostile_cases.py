"""Hostile navigation cases: lock rate and wrong locks per case (the README's table).

Each case renders one frame per seed (random pose at 1.5 m, random roll) and solves it with a
fresh pipeline; a wrong lock is a centre > 5 mm off or an LED > 5 mm from every real LED
(``app.sim.hostile``). Runs the paper's matcher (at its best: IHWT window factor 80) on the
same frames with ``--paper``.

    .venv/bin/python benchmarks/hostile_cases.py [--seeds 40] [--paper] [--only TEXT]
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import replace

from app.resources import load_default_calibration
from app.sim.hostile import hostile_cases, run_case
from app.vision.pipeline import PipelineConfig


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--paper", action="store_true", help="also run the paper's matcher")
    ap.add_argument("--only", default="", help="run only cases whose name contains this")
    args = ap.parse_args()
    calib = load_default_calibration()
    head = "| case | frames | lock (ours) | wrong locks (ours) | median ms |"
    sep = "|---|---|---|---|---|"
    if args.paper:
        head += " lock (paper matcher) | wrong locks (paper) |"
        sep += "---|---|"
    print(head)
    print(sep)
    for case in hostile_cases():
        if args.only and args.only not in case.name:
            continue
        s = run_case(calib, case, range(args.seeds))
        row = (
            f"| {case.name} | {s.frames} | {100 * s.lock_rate:.0f} % | {s.wrong} "
            f"| {statistics.median(s.ms):.1f} |"
        )
        if args.paper:
            paper = replace(case, config=PipelineConfig(matcher="paper"))
            p = run_case(calib, paper, range(args.seeds))
            row += f" {100 * p.lock_rate:.0f} % | {p.wrong} |"
        print(row, flush=True)


if __name__ == "__main__":
    main()
