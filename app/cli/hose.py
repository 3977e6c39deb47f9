"""``aar-dock hose``: the multi-body hose's steady shape, reel tension and swing modes at a
flight condition (altitude, calibrated airspeed), with the parameters used
(:mod:`app.sim.hose`). Output frame: x aft, y right, z down (m), the reel exit first."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "hose", help="the multi-body hose's steady shape, reel tension and swing modes"
    )
    p.add_argument("--altitude-ft", type=float, default=15000.0, help="pressure altitude (ft)")
    p.add_argument("--kcas", type=float, default=230.0, help="calibrated airspeed (kt)")
    p.add_argument("--segments", type=int, default=20, help="hose segments (nodes − 1)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--plot", metavar="DIR", help="draw the shape and the first modes into DIR")
    p.set_defaults(func=run)


def _aft(nodes: Any) -> list[list[float]]:
    """Tanker frame (x forward) → the output's x aft, y right, z down."""
    return [
        [round(-float(p[0]), 6) + 0.0, round(float(p[1]), 6) + 0.0, round(float(p[2]), 6) + 0.0]
        for p in nodes
    ]


def run(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from app.sim.hose.atmosphere import flow_from_kcas
    from app.sim.hose.params import DrogueParams, HoseParams
    from app.sim.hose.steady import steady_shape, swing_modes

    parser = args.cli_parser
    for name in ("altitude_ft", "kcas"):
        if not math.isfinite(getattr(args, name)):
            parser.error(f"--{name.replace('_', '-')} must be a finite number")
    try:
        flow = flow_from_kcas(args.altitude_ft, args.kcas)
        hose = HoseParams(segments=args.segments)
    except ValueError as exc:
        parser.error(str(exc))
    drogue = DrogueParams()
    shape = steady_shape(flow, hose, drogue)
    modes = swing_modes(flow, hose, drogue, shape)
    h = asdict(hose)
    out: dict[str, Any] = {
        "altitude_ft": args.altitude_ft,
        "kcas": args.kcas,
        "frame": "x aft, y right, z down; m; reel exit first, drogue last",
        "nodes_m": _aft(shape.nodes_m),
        "reel_tension_n": round(shape.reel_tension_n, 3),
        "drogue_tension_n": round(float(shape.tensions_n[-1]), 3),
        "hose": {
            k: h[k]
            for k in ("length_m", "mass_per_m_kg", "diameter_m", "cd_normal", "cd_tangential")
        }
        | {"axial_stiffness_n": hose.axial_stiffness_n, "segments": hose.segments},
        "drogue": {"mass_kg": drogue.mass_kg, "cd": drogue.cd, "area_m2": drogue.area_m2},
        "air_density_kgm3": flow.air_density_kgm3,
        "airspeed_mps": flow.airspeed_mps,
        "swing": {
            "lateral_hz": modes.lateral.frequency_hz,
            "vertical_hz": modes.vertical.frequency_hz,
            "lateral_damping": modes.lateral.damping_ratio,
            "vertical_damping": modes.vertical.damping_ratio,
        },
    }
    if args.plot:
        try:
            out["plots"] = _plot(Path(args.plot), shape.nodes_m, modes, out)
        except OSError as exc:
            parser.error(f"--plot {args.plot}: {exc.strerror or exc}")
    if args.json:
        print(json.dumps(out))
        return 0
    d = out["nodes_m"][-1]
    s = out["swing"]
    print(
        f"{args.altitude_ft:.0f} ft, {args.kcas:.0f} KCAS: ρ {flow.air_density_kgm3:.3f} kg/m³, "
        f"TAS {flow.airspeed_mps:.1f} m/s"
    )
    print(f"drogue at {d[0]:.2f} m aft, {d[2]:.2f} m below the reel exit")
    print(f"reel tension {out['reel_tension_n']:.0f} N")
    print(
        f"swing: lateral {s['lateral_hz']:.3f} Hz (ζ {s['lateral_damping']:.3f}), "
        f"vertical {s['vertical_hz']:.3f} Hz (ζ {s['vertical_damping']:.3f})"
    )
    return 0


def _plot(folder: Path, nodes: Any, modes: Any, out: dict[str, Any]) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    aft = np.array(out["nodes_m"])
    fig, (side, top) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    scale = 0.5  # m at the largest node
    for mode, axis, colour, label in (
        (modes.vertical, side, "tab:red", "vertical"),
        (modes.lateral, top, "tab:green", "lateral"),
    ):
        shape = np.array(mode.shape_m) * np.array([-1.0, 1.0, 1.0]) * scale
        k = 2 if axis is side else 1
        for sign in (1.0, -1.0):
            axis.plot(
                aft[:, 0] + sign * shape[:, 0],
                aft[:, k] + sign * shape[:, k],
                "--",
                color=colour,
                lw=1,
                label=f"{label} mode {mode.frequency_hz:.3f} Hz, ζ {mode.damping_ratio:.3f}"
                if sign > 0
                else None,
            )
    side.plot(aft[:, 0], aft[:, 2], "o-", color="k", ms=3, label="steady shape")
    side.invert_yaxis()
    side.set_ylabel("z down (m)")
    top.plot(aft[:, 0], aft[:, 1], "o-", color="k", ms=3)
    top.set_ylabel("y right (m)")
    top.set_xlabel("x aft of the reel exit (m)")
    for a in (side, top):
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(
        f"hose at {out['altitude_ft']:.0f} ft, {out['kcas']:.0f} KCAS "
        f"(reel tension {out['reel_tension_n']:.0f} N)"
    )
    path = folder / "hose_shape_modes.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [str(path)]
