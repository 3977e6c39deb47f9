"""A paired A/B of a guidance setting on JSBSim's A-4 with vision in the loop: the same seeds
flown with and without it, each run's outcome, break-aways (time and reason) and the closest
the nose came to the hose, then the counts per arm.

    .venv/bin/python benchmarks/guidance_ab.py --first-seed 440000 --runs 40 \\
        --turbulence moderate --imperfections harsh --setting stabilise_first

The setting is a boolean ``DockingConfig`` field (:data:`SETTINGS`) (``None``: the plant's
default), or ``pre_plane_checks`` (the high-pass and overspeed break-aways of
:mod:`app.control.abort`: off, or at their defaults); arm A flies it False, arm B True. The seeds used here are tuning seeds: quote held-out figures from
``aar-dock campaign`` on other seeds. Asserts nothing.
"""

from __future__ import annotations

import argparse
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from itertools import repeat

from app.sim.docking import DockingConfig, DockingSimulation


@dataclass(frozen=True)
class Run:
    seed: int
    outcome: str
    reason: str
    aborts: int
    first_approach_captured: bool
    min_hose_separation_m: float
    break_aways: str  # "t s: reason; …"


SETTINGS = (
    "stabilise_first",
    "swing_model_abort",
    "bow_feedforward",
    "timed_closure",
    "pre_plane_checks",
    "nav_covariance",
)


def with_setting(cfg: DockingConfig, setting: str, value: bool) -> DockingConfig:
    """``cfg`` with one of the boolean guidance settings (:data:`SETTINGS`) set."""
    if setting == "stabilise_first":
        return replace(cfg, stabilise_first=value)
    if setting == "swing_model_abort":
        return replace(cfg, swing_model_abort=value)
    if setting == "bow_feedforward":
        return replace(cfg, bow_feedforward=value)
    if setting == "timed_closure":
        return replace(cfg, timed_closure=value)
    if setting == "nav_covariance":
        return replace(cfg, nav_covariance=value)
    if setting == "pre_plane_checks":  # the high-pass and overspeed break-aways (defaults: on)
        return cfg if value else replace(cfg, high_gap_m=0.0, overspeed_gap_m=0.0)
    raise ValueError(f"unknown setting {setting!r} (one of {', '.join(SETTINGS)})")


def fly(seed: int, turbulence: str, imperfections: str, setting: str, value: bool) -> Run:
    """One run of the campaign's configuration (50 Hz camera, windowed render, 1 s kept)."""
    cfg = DockingConfig(
        plant="jsbsim",
        turbulence=turbulence,
        imperfections=imperfections,
        vision=True,
        camera_hz=50,
        render_mode="windows",
        station_keep_s=1.0,
    )
    cfg = with_setting(cfg, setting, value)
    sim = DockingSimulation(cfg)
    sim.reset(seed)
    out = sim.run()
    events = "; ".join(f"{e.t_s:.0f} s: {e.reason}" for e in sim.rta_events if e.kind == "recovery")
    return Run(
        seed,
        out.outcome,
        out.reason or "",
        out.aborts,
        out.captured and out.aborts == 0,
        out.envelope.min_hose_separation_m,
        events,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first-seed", type=int, required=True)
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--turbulence", default="moderate")
    ap.add_argument("--imperfections", default="harsh")
    ap.add_argument("--setting", default="stabilise_first", choices=SETTINGS)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    seeds = list(range(args.first_seed, args.first_seed + args.runs))
    arms: dict[bool, list[Run]] = {}
    with ProcessPoolExecutor(args.workers) as pool:
        for value in (False, True):
            arms[value] = list(
                pool.map(
                    fly,
                    seeds,
                    repeat(args.turbulence),
                    repeat(args.imperfections),
                    repeat(args.setting),
                    repeat(value),
                )
            )
    for value, runs in arms.items():
        print(f"\n{args.setting}={value}")
        for r in runs:
            print(
                f"  {r.seed} {r.outcome:10s} hose {r.min_hose_separation_m:5.2f} m | {r.break_aways}"
            )
    print(f"\n| {args.setting} | runs | outcomes | first-approach captures | min hose (m) |")
    print("|---|---|---|---|---|")
    for value, runs in arms.items():
        counts = dict(Counter(r.outcome for r in runs))
        first = sum(r.first_approach_captured for r in runs)
        hose = min(r.min_hose_separation_m for r in runs)
        print(f"| {value} | {len(runs)} | {counts} | {first} | {hose:.2f} |")


if __name__ == "__main__":
    main()
