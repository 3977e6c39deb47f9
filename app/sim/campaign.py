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
from collections.abc import Callable, Iterable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from app.sim.docking import DockingConfig, DockingSimulation, describe_plant
from app.sim.imperfections import resolve

CSV_FIELDS = (
    "seed",
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
)


def run_one(config: DockingConfig, seed: int) -> dict[str, Any]:
    """One docking run → a flat row (floats; NaN where undefined)."""
    t0 = time.perf_counter()
    sim = DockingSimulation(replace(config, seed=int(seed)))
    out = sim.run()
    row: dict[str, Any] = {"seed": int(seed), **asdict(out)}
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
    captured = [r for r in rows if r["captured"]]
    miss = _finite(r["miss_distance_m"] for r in captured)
    ttc = _finite(r["time_to_capture_s"] for r in captured)
    wall = _finite(r["wall_time_s"] for r in rows)
    sim_t = _finite(r["sim_time_s"] for r in rows)

    def q(a: np.ndarray, p: float) -> float | None:
        return float(np.percentile(a, p)) if len(a) else None

    summary: dict[str, Any] = {
        "runs": n,
        "success_rate": len(captured) / n,
        "miss_p50_m": q(miss, 50),
        "miss_p95_m": q(miss, 95),
        "miss_max_m": float(miss.max()) if len(miss) else None,
        "abort_rate": sum(1 for r in rows if r["aborts"] > 0) / n,
        "mean_aborts": float(np.mean([r["aborts"] for r in rows])),
        "mean_time_to_capture_s": float(ttc.mean()) if len(ttc) else None,
        "max_control_saturation": float(max(r["max_control_saturation"] for r in rows)),
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

    miss_cm = 100.0 * _finite(r["miss_distance_m"] for r in rows if r["captured"])
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.hist(miss_cm, bins=20, color="tab:blue", alpha=0.8)
    ax.set_xlabel("radial miss at capture (cm)")
    ax.set_ylabel("runs")
    ax.set_title(f"{summary['runs']} runs, success {100 * summary['success_rate']:.1f} %")
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return {"csv": csv_path, "json": json_path, "png": png_path}
