"""Prometheus text exposition of the tick loop's counters and stage latencies."""

from __future__ import annotations

from app.server.tick_loop import TickLoop


def _line(name: str, value: float, labels: dict[str, str] | None = None) -> str:
    if labels:
        inner = ",".join(f'{k}="{v}"' for k, v in labels.items())
        return f"{name}{{{inner}}} {value:.6g}"
    return f"{name} {value:.6g}"


def render_metrics(
    loop: TickLoop,
    *,
    ws_clients: int = 0,
    uploads: int = 0,
    sim_worker_restarts: int | None = None,
    upload_pool_restarts: int | None = None,
) -> str:
    """Text format 0.0.4 (``text/plain; version=0.0.4``)."""
    out: list[str] = []

    def metric(name: str, kind: str, help_: str, samples: list[str]) -> None:
        out.append(f"# HELP {name} {help_}")
        out.append(f"# TYPE {name} {kind}")
        out.extend(samples)

    metric("aar_ticks_total", "counter", "Ticks published", [_line("aar_ticks_total", loop.ticks)])
    metric(
        "aar_ticks_dropped_total",
        "counter",
        "Tick deadlines skipped because a step overran",
        [_line("aar_ticks_dropped_total", loop.dropped)],
    )
    metric(
        "aar_tick_errors_total",
        "counter",
        "Simulation steps that raised",
        [_line("aar_tick_errors_total", loop.errors)],
    )
    metric(
        "aar_tick_rate_hz",
        "gauge",
        "Measured tick rate over the last 2 s",
        [_line("aar_tick_rate_hz", loop.tick_rate_hz())],
    )
    metric(
        "aar_tick_target_hz",
        "gauge",
        "Configured tick rate",
        [_line("aar_tick_target_hz", loop.config.tick_hz)],
    )
    samples: list[str] = []
    for q in (0.5, 0.99):
        for stage, value in sorted(loop.stage_quantiles(q).items()):
            samples.append(
                _line("aar_stage_latency_ms", value, {"stage": stage, "quantile": str(q)})
            )
    metric(
        "aar_stage_latency_ms",
        "summary",
        "Per-stage latency over the last 512 ticks (ms)",
        samples,
    )
    metric(
        "aar_telemetry_clients",
        "gauge",
        "Connected telemetry WebSocket clients",
        [_line("aar_telemetry_clients", ws_clients)],
    )
    metric(
        "aar_uploads_total",
        "counter",
        "Stereo pairs processed via POST /stereo",
        [_line("aar_uploads_total", uploads)],
    )
    if sim_worker_restarts is not None:
        metric(
            "aar_sim_worker_restarts_total",
            "counter",
            "Simulation worker processes lost (crash, exit, timeout) and replaced",
            [_line("aar_sim_worker_restarts_total", sim_worker_restarts)],
        )
    if upload_pool_restarts is not None:
        metric(
            "aar_upload_pool_restarts_total",
            "counter",
            "Upload worker pools replaced after a worker died",
            [_line("aar_upload_pool_restarts_total", upload_pool_restarts)],
        )
    return "\n".join(out) + "\n"
