"""``aar-dock margins``: the docking controller's stability margins at the plant input, per
loop and all loops at once, with each imperfection preset's servo lag
(:mod:`app.control.loop_margins`)."""

from __future__ import annotations

import argparse
import json
import math
import warnings
from typing import Any


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "margins", help="the controller's gain, phase, delay and disk margins per preset"
    )
    p.add_argument("--plant", default="jsbsim", choices=["jsbsim", "linear"])
    p.add_argument("--json", action="store_true", help="print the margins as JSON")
    p.set_defaults(func=run)


def _num(v: float) -> float | None:
    return round(v, 3) if math.isfinite(v) else None


def run(args: argparse.Namespace) -> int:
    from app.control.loop_margins import design_margins
    from app.sim.docking import DockingConfig
    from app.sim.docking.plant_design import design_for
    from app.sim.imperfections import PRESETS

    cfg = DockingConfig(plant=args.plant, vision=False)
    design = design_for(cfg).design
    dt = 1.0 / cfg.tick_hz
    out: dict[str, Any] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # python-control's "frd" fallback notices
        for name, preset in PRESETS.items():
            m = design_margins(design, dt, preset.actuator_lag_s)
            out[name] = {
                "servo_lag_s": preset.actuator_lag_s,
                "per_loop": {
                    s.name: {
                        "gain_margin_db": _num(s.gain_margin_db),
                        "gain_reduction_margin_db": _num(s.gain_reduction_margin_db),
                        "phase_margin_deg": _num(abs(s.phase_margin_deg)),
                        "delay_margin_s": _num(s.delay_margin_s),
                        "crossover_rad_s": _num(s.crossover_rad_s),
                    }
                    for s in m.per_loop
                },
                "disk": {
                    "gain_margin_db": _num(m.disk.gain_margin_db),
                    "phase_margin_deg": _num(m.disk.phase_margin_deg),
                    "worst_frequency_rad_s": _num(m.disk.worst_frequency_rad_s),
                },
            }
    if args.json:
        print(json.dumps({"plant": args.plant, "presets": out}))
        return 0
    print(f"plant={args.plant}: margins at the plant input (loop broken at each command)")
    for name, r in out.items():
        print(f"\n{name} (servo lag {1000 * r['servo_lag_s']:.0f} ms)")
        print(f"  {'loop':9s} {'GM up dB':>9s} {'GM down dB':>11s} {'PM deg':>7s} {'delay ms':>9s}")
        for loop, v in r["per_loop"].items():

            def f(x: float | None, scale: float = 1.0) -> str:
                return "inf" if x is None else f"{scale * x:.1f}"

            print(
                f"  {loop:9s} {f(v['gain_margin_db']):>9s} {f(v['gain_reduction_margin_db']):>11s}"
                f" {f(v['phase_margin_deg']):>7s} {f(v['delay_margin_s'], 1000):>9s}"
            )
        d = r["disk"]
        print(
            f"  all loops at once (disk): ±{d['gain_margin_db']:.1f} dB, {d['phase_margin_deg']:.1f}°"
        )
    return 0
