"""Monte-Carlo docking campaigns on Dask (pure: no web imports).

Each run is one :class:`~app.sim.docking.DockingSimulation` with its own seed (turbulence,
start offset, sensor noise and image noise all derive from it). Runs are mapped over a
``dask.distributed`` cluster (a ``LocalCluster`` of single-threaded worker processes by default,
or an existing scheduler); results come back as they complete.
"""

from __future__ import annotations

import csv
import json
import math
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from app.sim.docking import DockingConfig, DockingSimulation, describe_plant
from app.sim.docking.outcomes import OUTCOMES
from app.sim.imperfections import resolve

CSV_FIELDS = (
    "seed",
    "outcome",
    "reason",
    "captured",
    "miss_distance_m",
    "closure_speed_mps",
    "time_to_capture_s",
    "aborts",
    "max_control_saturation",
    "sim_time_s",
    "wall_time_s",
    "frames_dropped",
    "frames_duplicated",
    "lateral_speed_mps",
    "hose_whip_risk",
    "peak_hose_tension_n",
    "hose_whip",
    "hose_released",
    "recoveries",
    "alpha_min_deg",
    "alpha_max_deg",
    "load_factor_min_g",
    "load_factor_max_g",
    "bank_max_deg",
    "kcas_min",
    "kcas_max",
    "height_lost_m",
    "min_tanker_separation_m",
    "min_hose_separation_m",
    "traceback",
)


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a proportion (95 % by default); (0, 1) for n = 0."""
    if n <= 0:
        return (0.0, 1.0)
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def run_one(config: DockingConfig, seed: int) -> dict[str, Any]:
    """One docking run → a flat row (floats; NaN where undefined). Never raises: an
    exception makes the row's outcome ``error`` with its traceback, so that no campaign dies
    of one run."""
    t0 = time.perf_counter()
    sim: DockingSimulation | None = None
    try:
        sim = DockingSimulation(replace(config, seed=int(seed)))
        out = sim.run()
    except Exception:  # recorded, not raised: the campaign carries on
        return {
            "seed": int(seed),
            "outcome": "error",
            "reason": traceback.format_exc(limit=1).strip().splitlines()[-1],
            "traceback": traceback.format_exc(),
            "captured": False,
            "miss_distance_m": math.nan,
            "closure_speed_mps": math.nan,
            "time_to_capture_s": math.nan,
            "aborts": 0 if sim is None else sim.aborts,
            "max_control_saturation": math.nan,
            "sim_time_s": 0.0 if sim is None else sim.t,
            "wall_time_s": time.perf_counter() - t0,
            "frames_dropped": 0,
            "frames_duplicated": 0,
        }
    d = asdict(out)
    envelope = d.pop("envelope")
    row: dict[str, Any] = {"seed": int(seed), **d, **envelope, "traceback": None}
    row["sim_time_s"] = sim.t
    row["wall_time_s"] = time.perf_counter() - t0
    row["frames_dropped"] = sim.frame_channel.dropped
    row["frames_duplicated"] = sim.frame_channel.duplicated
    return row


def _finite(values: Iterable[float]) -> np.ndarray:
    arr = np.asarray([v for v in values if v is not None], float)
    return arr[np.isfinite(arr)]


def summarise(rows: list[dict[str, Any]], config: DockingConfig | None = None) -> dict[str, Any]:
    """Success rate, miss percentiles (captured runs), abort rate (runs with ≥ 1 abort)."""
    n = len(rows)
    if n == 0:
        raise ValueError("no runs to summarise")
    captured = [r for r in rows if r.get("outcome") == "captured"]

    def q(a: np.ndarray, p: float) -> float | None:
        return float(np.percentile(a, p)) if len(a) else None

    miss = _finite(r["miss_distance_m"] for r in captured)
    ttc = _finite(r["time_to_capture_s"] for r in captured)
    wall = _finite(r["wall_time_s"] for r in rows)
    sim_t = _finite(r["sim_time_s"] for r in rows)

    outcomes = {k: sum(1 for r in rows if r.get("outcome") == k) for k in OUTCOMES}
    departures = outcomes["departure"]
    lateral = _finite(float(r.get("lateral_speed_mps") or math.nan) for r in captured)
    closure = _finite(r["closure_speed_mps"] for r in captured)
    tension = _finite(float(r.get("peak_hose_tension_n") or math.nan) for r in rows)
    summary: dict[str, Any] = {
        "runs": n,
        "outcomes": outcomes,
        "capture_rate": len(captured) / n,
        "capture_rate_ci95": list(wilson_interval(len(captured), n)),
        "departure_rate": departures / n,
        "departure_rate_ci95": list(wilson_interval(departures, n)),
        "rim_strike_rate": outcomes["rim_strike"] / n,
        "lateral_speed_at_contact_p50_mps": q(lateral, 50),
        "lateral_speed_at_contact_p95_mps": q(lateral, 95),
        "closure_at_contact_min_mps": float(closure.min()) if len(closure) else None,
        "closure_at_contact_max_mps": float(closure.max()) if len(closure) else None,
        "hose_whip_risk_runs": sum(1 for r in rows if r.get("hose_whip_risk")),
        # the multi-body hose's latched contacts (N; None without one) and its whips
        "peak_tension_n": {
            "p50": q(tension, 50),
            "p95": q(tension, 95),
            "max": float(tension.max()) if len(tension) else None,
        },
        "whip_runs": sum(1 for r in rows if r.get("hose_whip")),
        "hose_released_runs": sum(1 for r in rows if r.get("hose_released")),
        "seeds": [int(min(r["seed"] for r in rows)), int(max(r["seed"] for r in rows))],
        "success_rate": len(captured) / n,
        "miss_p50_m": q(miss, 50),
        "miss_p95_m": q(miss, 95),
        "miss_max_m": float(miss.max()) if len(miss) else None,
        "abort_rate": sum(1 for r in rows if r["aborts"] > 0) / n,
        "mean_aborts": float(np.mean([r["aborts"] for r in rows])),
        "mean_time_to_capture_s": float(ttc.mean()) if len(ttc) else None,
        "max_control_saturation": float(np.nanmax([r["max_control_saturation"] for r in rows])),
        "mean_wall_time_per_run_s": float(wall.mean()) if len(wall) else None,
        "sim_seconds_per_wall_second_per_run": float(sim_t.sum() / wall.sum())
        if len(wall) and wall.sum() > 0
        else None,
    }
    if config is not None:
        summary.update(describe_plant(config))
        summary["config"] = {
            "plant": config.plant,
            "turbulence": config.turbulence,
            "vision": config.vision,
            "matcher": config.matcher,
            "camera_hz": config.camera_hz,
            "render_mode": "windows" if config.roi_tracking else config.render_mode,
            "tick_hz": config.tick_hz,
            "closure_speed_mps": config.closure_speed_mps,
            "station_keep_s": config.station_keep_s,
            "hold_gap_on_lost_lock": config.hold_gap_on_lost_lock,
            "hose_model": config.hose_model,
        }
        imp = resolve(config.imperfections)
        summary["imperfections"] = {"preset": imp.name, "values": imp.to_dict()}
    return summary


def run_campaign(
    config: DockingConfig,
    runs: int,
    first_seed: int = 0,
    client: Any = None,
    workers: int = 2,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run ``runs`` seeds on Dask; ``client`` (a ``distributed.Client``) or a new LocalCluster."""
    if runs < 1:
        raise ValueError("runs must be >= 1")
    config.validate()
    from distributed import Client, LocalCluster, as_completed

    own = client is None
    cluster = None
    if own:
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
        )
        client = Client(cluster)
    try:
        seeds = list(range(first_seed, first_seed + runs))
        futures = client.map(run_one, [config] * runs, seeds, pure=False)
        rows = []
        for fut in as_completed(futures):
            row = fut.result()
            rows.append(row)
            if on_result is not None:
                on_result(row)
        rows.sort(key=lambda r: r["seed"])
        return rows
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()


def write_outputs(
    out_dir: str | Path, rows: list[dict[str, Any]], summary: dict[str, Any]
) -> dict[str, Path]:
    """``runs.csv``, ``summary.json``, ``miss_histogram.png`` in ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "runs.csv"
    with csv_path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(CSV_FIELDS))
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k) for k in CSV_FIELDS})
    json_path = out / "summary.json"

    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        return v

    json_path.write_text(json.dumps(clean(summary), indent=2))
    png_path = out / "miss_histogram.png"
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    miss_cm = 100.0 * _finite(r["miss_distance_m"] for r in rows if r.get("outcome") == "captured")
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.hist(miss_cm, bins=20, color="tab:blue", alpha=0.8)
    ax.set_xlabel("radial miss at capture (cm)")
    ax.set_ylabel("runs")
    counts = ", ".join(f"{k} {v}" for k, v in summary.get("outcomes", {}).items() if v)
    ax.set_title(f"{summary['runs']} runs: {counts}", fontsize=9)
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return {"csv": csv_path, "json": json_path, "png": png_path}
