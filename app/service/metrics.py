"""Prometheus text exposition of the tick loop's counters and the bus's stage latencies, by
``prometheus_client`` (its exposition escapes label values: the ``source`` label is the
operator's free-text source string)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping

from prometheus_client.core import CollectorRegistry, Metric
from prometheus_client.exposition import generate_latest
from prometheus_client.registry import Collector

from app.service.stream_service import StreamService
from app.service.telemetry_bus import TelemetryBus
from app.service.tick_loop import TickLoop

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"

PUSH_COUNTERS = (
    ("rejected", "Pushed pairs refused (header, undecodable image)"),
    ("seq_duplicate", "Pushed pairs dropped: their seq repeated the previous one"),
    ("seq_out_of_order", "Pushed pairs dropped: their seq went back"),
    ("dropped_backpressure", "Pushed pairs replaced by a newer one before being read"),
)


class _Snapshot(Collector):
    """The metrics of one scrape, collected once (a registry of its own per scrape)."""

    def __init__(self) -> None:
        self.metrics: list[Metric] = []

    def add(
        self,
        name: str,
        kind: str,
        help_: str,
        value: float,
        labels: dict[str, str] | None = None,
    ) -> Metric:
        m = Metric(name.removesuffix("_total") if kind == "counter" else name, help_, kind)
        m.add_sample(name, labels or {}, float(value))
        self.metrics.append(m)
        return m

    def collect(self) -> Iterator[Metric]:
        yield from self.metrics


def _count(value: object) -> float:
    """A counter of the stream's status (``0`` where it has none)."""
    return float(value) if isinstance(value, int | float) else 0.0


def _stream_metrics(snap: _Snapshot, streams: StreamService) -> None:
    health = streams.health()
    if health is None:
        return
    st = streams.status()
    src = {"source": health.source}
    up = 1 if health.status == "ok" else 0
    snap.add(
        "aar_stream_up",
        "gauge",
        "1 while the active frame source delivers (0: degraded; see /healthz)",
        up,
        src,
    )
    snap.add(
        "aar_stream_rate_hz",
        "gauge",
        "Pairs a second of the active frame source over the last 2 s",
        health.rate_hz,
        src,
    )
    snap.add(
        "aar_stream_restarts_total",
        "counter",
        "Times the frame source was reopened after a failure",
        _count(st["restarts"]),
        src,
    )
    snap.add(
        "aar_stream_consecutive_failures",
        "gauge",
        "Failed pairs since the last good one",
        _count(st["consecutive_failures"]),
        src,
    )
    for key, help_ in PUSH_COUNTERS:
        snap.add(f"aar_push_{key}_total", "counter", help_, _count(st.get(key)), src)


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
    """Text format 0.0.4 (:data:`CONTENT_TYPE`)."""
    snap = _Snapshot()
    snap.add("aar_ticks_total", "counter", "Ticks published", loop.ticks)
    snap.add(
        "aar_ticks_dropped_total",
        "counter",
        "Tick deadlines skipped because a step overran",
        loop.dropped,
    )
    snap.add("aar_tick_errors_total", "counter", "Simulation steps that raised", loop.errors)
    snap.add(
        "aar_tick_rate_hz", "gauge", "Measured tick rate over the last 2 s", loop.tick_rate_hz()
    )
    snap.add("aar_tick_target_hz", "gauge", "Configured tick rate", loop.config.tick_hz)
    latency = Metric(
        "aar_stage_latency_ms", "Per-stage latency over the last 512 ticks (ms)", "summary"
    )
    for q in (0.5, 0.99):
        for stage, value in sorted(bus.stage_quantiles(q).items()):
            latency.add_sample(
                "aar_stage_latency_ms", {"stage": stage, "quantile": str(q)}, float(value)
            )
    snap.metrics.append(latency)
    snap.add("aar_telemetry_clients", "gauge", "Connected telemetry WebSocket clients", ws_clients)
    snap.add("aar_uploads_total", "counter", "Stereo pairs processed via POST /stereo", uploads)
    if sim_worker_restarts is not None:
        snap.add(
            "aar_sim_worker_restarts_total",
            "counter",
            "Simulation worker processes lost (crash, exit, timeout) and replaced",
            sim_worker_restarts,
        )
    if upload_pool_restarts is not None:
        snap.add(
            "aar_upload_pool_restarts_total",
            "counter",
            "Upload worker pools replaced after a worker died",
            upload_pool_restarts,
        )
    if streams is not None:
        _stream_metrics(snap, streams)
    if guard_counters:
        events = Metric(
            "aar_guard_events",
            "Connections and messages refused or closed by the service's guards, by reason",
            "counter",
        )
        for reason, n in sorted(guard_counters.items()):
            events.add_sample("aar_guard_events_total", {"reason": reason}, float(n))
        snap.metrics.append(events)
    registry = CollectorRegistry(auto_describe=False)
    registry.register(snap)
    return generate_latest(registry).decode("utf-8")
