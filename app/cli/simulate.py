"""``aar-dock simulate``: one closed-loop docking run (paper §6), optional Figs 14–16 style plots."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any


def add_docking_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``simulate`` and ``campaign``."""
    from app.sim.docking import HOSE_MODELS, DockingConfig
    from app.sim.plant import PLANTS

    p.add_argument(
        "--plant",
        default=DockingConfig.plant,
        choices=list(PLANTS),
        help="receiver plant: jsbsim (the A-4 on JSBSim's nonlinear FDM) or linear (the "
        "controller's own design model, an Aerosonde); default %(default)s",
    )
    p.add_argument("--turbulence", default="light", choices=["none", "light", "moderate", "severe"])
    p.add_argument(
        "--truth-measurements", action="store_true", help="no vision: true drogue centre"
    )
    p.add_argument(
        "--camera-hz", type=float, default=None, help="camera rate (default: every tick)"
    )
    p.add_argument("--matcher", default="epipolar", choices=["epipolar", "paper"])
    p.add_argument(
        "--render",
        default="windows",
        choices=["windows", "full"],
        help="windows: render only the tracker's windows while it tracks (fast, same poses); "
        "full: render whole frames",
    )
    p.add_argument("--roi", action="store_true", help=argparse.SUPPRESS)  # = --render windows
    p.add_argument(
        "--imperfections",
        default="none",
        choices=["none", "standard", "harsh"],
        help="flight imperfections preset (latency, dropped frames, plant ≠ design, "
        "calibration and INS errors, tanker wake); see docs/models.md",
    )
    p.add_argument(
        "--hose",
        default=DockingConfig.hose_model,
        choices=list(HOSE_MODELS),
        help="the flown hose: reduced (a second-order swing on a static shape, welded at "
        "contact) or multibody (the lumped-mass hose with its reel and coupling); "
        "default %(default)s",
    )
    p.add_argument(
        "--backoff-on-lost-lock",
        action="store_true",
        help="break away when the lock is lost before the last metre (default: hold the gap "
        "until the drogue is re-acquired)",
    )


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser("simulate", help="closed-loop docking simulation (one run)")
    add_docking_options(p)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--station-keep", type=float, default=12.0, help="refuelling seconds after contact"
    )
    p.add_argument("--plot", default=None, metavar="DIR", help="write PNG figures to DIR")
    p.add_argument("--json", action="store_true", help="print only the outcome as JSON")
    p.set_defaults(func=run)


def plot_run(log: Any, out_dir: Path) -> list[Path]:
    """Figures like the paper's 14 (relative position), 15 (attitude), 16 (controls)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    out_dir.mkdir(parents=True, exist_ok=True)
    t = np.asarray(log.t)
    rel = np.asarray(log.rel)
    ref = np.asarray(log.ref_rel)
    att = np.degrees(np.asarray(log.att))
    ctrl = np.asarray(log.ctrl)
    paths = []
    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    for i, name in enumerate("xyz"):
        axes[i].plot(t, rel[:, i], label="probe tip − drogue (actual)")
        axes[i].plot(t, ref[:, i], "--", label="reference − drogue")
        axes[i].set_ylabel(f"{name} (m)")
        axes[i].grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("Relative position of the probe tip to the drogue (cf. paper Fig. 14)")
    fig.tight_layout()
    paths.append(out_dir / "fig14_relative_position.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    for i, name in enumerate(("φ", "θ", "ψ")):
        axes[i].plot(t, att[:, i])
        axes[i].set_ylabel(f"{name} (deg)")
        axes[i].grid(True, alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("Receiver attitude (cf. paper Fig. 15)")
    fig.tight_layout()
    paths.append(out_dir / "fig15_attitude.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    labels = ("Δδ_t (throttle)", "Δδ_a (deg)", "Δδ_e (deg)", "Δδ_r (deg)")
    for i, lab in enumerate(labels):
        y = ctrl[:, i] if i == 0 else np.degrees(ctrl[:, i])
        axes[i].plot(t, y)
        axes[i].set_ylabel(lab)
        axes[i].grid(True, alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("Control deflections relative to trim (cf. paper Fig. 16)")
    fig.tight_layout()
    paths.append(out_dir / "fig16_controls.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    return paths


def run(args: argparse.Namespace) -> int:
    from app.sim.docking import DockingConfig, DockingSimulation, TickLog

    try:
        cfg = DockingConfig(
            plant=args.plant,
            turbulence=args.turbulence,
            seed=args.seed,
            vision=not args.truth_measurements,
            camera_hz=args.camera_hz,
            matcher=args.matcher,
            render_mode="windows" if args.roi else args.render,
            station_keep_s=args.station_keep,
            imperfections=args.imperfections,
            hold_gap_on_lost_lock=not args.backoff_on_lost_lock,
            hose_model=args.hose,
        )
        cfg.validate()
        if args.station_keep < 0:
            raise ValueError("--station-keep must be >= 0")
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if cfg.vision:  # compile the navigation loops first (once per install): not timed
        from app.sim.warmup import compile_kernels

        compile_kernels()
    sim = DockingSimulation(cfg)
    log = TickLog()
    t0 = time.perf_counter()
    while not sim.done:
        log.add(sim.step())
    wall_s = time.perf_counter() - t0
    sim_s = sim.k * sim.dt
    out = sim.outcome()
    speed = {
        "sim_time_s": round(sim_s, 3),
        "wall_time_s": round(wall_s, 3),
        "real_time_factor": round(sim_s / wall_s, 2) if wall_s > 0 else None,
    }
    if args.plot:
        paths = plot_run(log, Path(args.plot))
        if not args.json:
            for p in paths:
                print(f"wrote {p}", file=sys.stderr)
    d = rounded(out.to_dict())
    plant = {"plant": cfg.plant, "airframe": sim.airframe, "trim": rounded(sim.trim.to_dict())}
    if args.json:
        print(json.dumps({**d, **speed, **plant}))
        return 0

    def show(v: float | None, unit: str, scale: float = 1.0, digits: int = 2) -> str:
        return "n/a" if v is None else f"{scale * v:.{digits}f} {unit}"

    t = sim.trim
    print(
        f"plant={cfg.plant} ({sim.airframe}, {t.altitude_ft:.0f} ft, {t.kcas:.0f} KCAS, "
        f"α {t.alpha_deg:.2f}°, throttle {t.throttle:.3f}, {t.weight_lbs:.0f} lb)"
    )
    print(f"outcome={d['outcome']}" + (f" ({d['reason']})" if d["reason"] else ""))
    print(
        f"captured={d['captured']} miss={show(d['miss_distance_m'], 'cm', 100.0, 1)} "
        f"closure={show(d['closure_speed_mps'], 'm/s')} "
        f"time_to_capture={show(d['time_to_capture_s'], 's')} "
        f"aborts={d['aborts']} max_saturation={d['max_control_saturation']:.2f} "
        f"peak_hose_tension={show(d['peak_hose_tension_n'], 'N', digits=0)} "
        f"hose_whip={d['hose_whip']} "
        f"sim={speed['sim_time_s']:.1f} s wall={speed['wall_time_s']:.1f} s "
        f"({speed['real_time_factor']}× real time)"
    )
    return 0


#: decimals kept per output key (units: m, m/s, s, fractions); the rest 4 significant digits
ROUNDING = {
    "miss_distance_m": 4,  # 0.1 mm
    "closure_speed_mps": 3,
    "time_to_capture_s": 2,
    "max_control_saturation": 3,
    "peak_hose_tension_n": 0,
}


def rounded(d: dict[str, Any]) -> dict[str, Any]:
    """Floats rounded to what they mean (``ROUNDING``; others to 4 significant digits)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out[k] = rounded(v)
        elif isinstance(v, float) and not isinstance(v, bool):
            out[k] = round(v, ROUNDING[k]) if k in ROUNDING else float(f"{v:.4g}")
        else:
            out[k] = v
    return out
