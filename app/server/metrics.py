"""Prometheus text exposition of the tick loop's counters and the bus's stage latencies."""

from __future__ import annotations

from collections.abc import Mapping

from app.server.stream_service import StreamService
from app.server.telemetry_bus import TelemetryBus
from app.server.tick_loop import TickLoop


def _line(name: str, value: float, labels: dict[str, str] | None = None) -> str:
    if labels:
        inner = ",".join(f'{k}="{v}"' for k, v in labels.items())
        return f"{name}{{{inner}}} {value:.6g}"
    return f"{name} {value:.6g}"


def render_metrics(
    loop: TickLoop,
    bus: TelemetryBus,
    *,
    ws_clients: int = 0,
    uploads: int = 0,
    sim_worker_restarts: int | None = None,
    upload_pool_restarts: int | None = None,
    streams: StreamService | None = None,
    guard_counters: Mapping[str, int] | None = None,
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
        for stage, value in sorted(bus.stage_quantiles(q).items()):
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
    health = streams.health() if streams is not None else None
    if streams is not None and health is not None:
        st = streams.status()
        src = {"source": health.source}
        metric(
            "aar_stream_up",
            "gauge",
            "1 while the active frame source delivers (0: degraded; see /healthz)",
            [_line("aar_stream_up", 1 if health.status == "ok" else 0, src)],
        )
        metric(
            "aar_stream_rate_hz",
            "gauge",
            "Pairs a second of the active frame source over the last 2 s",
            [_line("aar_stream_rate_hz", health.rate_hz, src)],
        )
        metric(
            "aar_stream_restarts_total",
            "counter",
            "Times the frame source was reopened after a failure",
            [_line("aar_stream_restarts_total", st["restarts"], src)],
        )
        metric(
            "aar_stream_consecutive_failures",
            "gauge",
            "Failed pairs since the last good one",
            [_line("aar_stream_consecutive_failures", st["consecutive_failures"], src)],
        )
        for key, help_ in (
            ("rejected", "Pushed pairs refused (header, undecodable image)"),
            ("seq_duplicate", "Pushed pairs dropped: their seq repeated the previous one"),
            ("seq_out_of_order", "Pushed pairs dropped: their seq went back"),
            ("dropped_backpressure", "Pushed pairs replaced by a newer one before being read"),
        ):
            name = f"aar_push_{key}_total"
            metric(name, "counter", help_, [_line(name, st.get(key) or 0, src)])
    if guard_counters:
        metric(
            "aar_guard_events_total",
            "counter",
            "Connections and messages refused or closed by the connection guard, by reason",
            [
                _line("aar_guard_events_total", n, {"reason": reason})
                for reason, n in sorted(guard_counters.items())
            ],
        )
    return "\n".join(out) + "\n"
