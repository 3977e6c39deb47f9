"""How long one break-away costs: forced at 1 m on JSBSim's A-4 (truth measurements), timed
from the order to the safe standoff (≥ 10 m aft and ≥ 3 m below the drogue, from the flown
drogue and probe), to the hand-back to the LQR, and to the next approach (the rejoin's end);
with the farthest aft and below the receiver went, and α's range from JSBSim's own property.

    .venv/bin/python benchmarks/bench_break_away.py [--seeds 3 5 7 8]

Prints a table (one row per seed and condition). Asserts nothing: the floors (standoff in
≤ 6 s, inside the envelope) are tests (tests/sim/test_run_time_assurance.py).
"""

from __future__ import annotations

import argparse

from app.sim.docking import DockingConfig, DockingSimulation

CONDITIONS = (("light", "standard"), ("moderate", "standard"), ("moderate", "harsh"))


def one(seed: int, turbulence: str, imperfections: str) -> dict[str, float]:
    """One forced break-away; the times (s from the order) and extremes (m, °)."""
    sim = DockingSimulation(
        DockingConfig(turbulence=turbulence, imperfections=imperfections, seed=seed, vision=False)
    )
    while float(sim.drogue.position_m[0] - sim.probe_tip()[0]) > 1.0:
        sim.step()
    t0 = sim.t
    sim.break_away("forced by the benchmark")
    fdm = sim.plant.fdm
    row = {"standoff_s": float("nan"), "aft_max_m": 0.0, "below_max_m": 0.0}
    alphas = []
    while sim.t < t0 + 90.0 and not (sim.rta_reason is None and sim.guidance.phase != "rejoin"):
        tick = sim.step()
        aft = float(tick.drogue_truth_m[0] - tick.probe_tip_m[0])
        below = float(tick.probe_tip_m[2] - tick.drogue_truth_m[2])
        alphas.append(float(fdm["aero/alpha-deg"]))
        row["aft_max_m"] = max(row["aft_max_m"], aft)
        row["below_max_m"] = max(row["below_max_m"], below)
        if row["standoff_s"] != row["standoff_s"] and aft >= 10.0 and below >= 3.0:
            row["standoff_s"] = sim.t - t0
    backs = [e.t_s - t0 for e in sim.rta_events if e.kind == "hand_back" and e.t_s > t0]
    row["hand_back_s"] = backs[0] if backs else float("nan")
    row["next_approach_s"] = sim.t - t0
    row["alpha_min_deg"], row["alpha_max_deg"] = min(alphas), max(alphas)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[3, 5, 7, 8])
    args = ap.parse_args()
    print(
        "| seed | turbulence · imperfections | standoff (s) | hand-back (s) | next approach (s) "
        "| aft max (m) | below max (m) | α (°) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        for turbulence, imperfections in CONDITIONS:
            r = one(seed, turbulence, imperfections)
            print(
                f"| {seed} | {turbulence} · {imperfections} | {r['standoff_s']:.1f} "
                f"| {r['hand_back_s']:.1f} | {r['next_approach_s']:.1f} | {r['aft_max_m']:.1f} "
                f"| {r['below_max_m']:.1f} | {r['alpha_min_deg']:.1f}…{r['alpha_max_deg']:.1f} |"
            )


if __name__ == "__main__":
    main()
