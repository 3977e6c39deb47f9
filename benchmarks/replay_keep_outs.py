"""Replay the held-out runs that ended in a hose keep-out, with the recovery law's descent as
it is and as it was (the baseline, in the same run): JSBSim's A-4, vision in the loop, the
campaign's settings (camera 50 Hz, windowed rendering).

    .venv/bin/python benchmarks/replay_keep_outs.py [--seeds 390166:moderate:harsh ...]
        [--workers 2]

The six default seeds are the hose keep-outs of the held-out campaigns on 064b94b
(docs/control.md, "Held-out campaigns"): each a break-away after the probe crossed the
drogue's plane 0.35–0.5 m above its centre; the receiver carried on 2.5–3 m past the plane
before the drop-back took hold, and the nose (0.6 m behind the tip, 0.5 m to its left and
0.3 m below it) came within 0.5 m of the hose that rises forward from the drogue.
These seeds are no longer held out: they serve as a regression, not as a rate.

Prints a Markdown table: per seed and descent (sink rate, k_z), the outcome, the nose's
minimum distance to the hose and to the tanker (m), α's and the load factor's range over the
run (JSBSim's own properties). Asserts nothing.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from typing import Any

from app.control.recovery import RecoveryGains
from app.sim.campaign import run_one
from app.sim.docking import DockingConfig

KEEP_OUTS = (
    "170028:moderate:standard",
    "170173:moderate:standard",
    "390082:moderate:harsh",
    "390166:moderate:harsh",
    "390212:moderate:harsh",
    "390310:moderate:harsh",
)
#: (label, sink rate m/s, k_z): the descent before this round, and now
DESCENTS = (("3 m/s, k_z 2 (before)", 3.0, 2.0), ("defaults", None, None))


def replay(spec: str, sink_mps: float | None, sink_gain: float | None) -> dict[str, Any]:
    """One run of ``spec`` ("seed:turbulence:imperfections") to its end, as the campaign runs
    it (:func:`app.sim.campaign.run_one`: its row, an exception recorded as ``error``)."""
    seed, turbulence, imperfections = spec.split(":")
    gains = RecoveryGains()
    if sink_mps is not None and sink_gain is not None:
        gains = replace(gains, sink_mps=sink_mps, sink_gain=sink_gain)
    cfg = DockingConfig(
        plant="jsbsim",
        turbulence=turbulence,
        imperfections=imperfections,
        vision=True,
        camera_hz=50,
        render_mode="windows",
        recovery=gains,
    )
    return run_one(cfg, int(seed))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", nargs="+", default=list(KEEP_OUTS))
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    jobs = [(spec, label, s, k) for spec in args.seeds for label, s, k in DESCENTS]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [pool.submit(replay, spec, s, k) for spec, _, s, k in jobs]
        rows = [f.result() for f in futures]
    print("| seed | descent | outcome | nose–hose min (m) | nose–tanker min (m) | α (°) | n (g) |")
    print("|---|---|---|---|---|---|---|")
    for (spec, label, _, _), r in zip(jobs, rows, strict=True):
        print(
            f"| {spec} | {label} | {r['outcome']} | {r['min_hose_separation_m']:.2f} "
            f"| {r['min_tanker_separation_m']:.2f} "
            f"| {r['alpha_min_deg']:.1f} … {r['alpha_max_deg']:.1f} "
            f"| {r['load_factor_min_g']:.2f} … {r['load_factor_max_g']:.2f} |"
        )


if __name__ == "__main__":
    main()
