"""WebSocket limits in the ASGI layer: per-route message sizes, connection caps (in-process), and
message rates (a real ``aar-dock serve`` under a flood of tiny messages: each flooding client is
closed, 1008, after its burst; ``/healthz`` keeps answering fast)."""

from __future__ import annotations

import multiprocessing
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketDenialResponse
from starlette.websockets import WebSocketDisconnect

from app.service.settings import Settings
from tests.support.live_server import LatencyProbe, serve, ws_connect
from tests.support.service_app import service_app
from tests.support.service_settings import SIM_IDLE, service_settings
from tests.support.ws_frames import frame_header, read_close


def _settings(tmp_path: Path, **kw: Any) -> Settings:
    return service_settings(tmp_path, **{**SIM_IDLE, **kw})


def test_telemetry_takes_only_small_messages(tmp_path: Path) -> None:
    # no penalty: the same (in-process) address opens the push route after its 1009
    with TestClient(service_app(_settings(tmp_path, ws_abuse_penalty_s=0.0))) as c:
        with c.websocket_connect("/api/v1/telemetry") as ws:
            ws.send_text("x" * 100)  # small: read and ignored
            ws.send_bytes(b"\0" * 5000)  # over AAR_WS_MAX_MESSAGE_KB (4 kB)
            with pytest.raises(WebSocketDisconnect) as exc:
                ws.receive_text()
        assert exc.value.code == 1009 and "AAR_WS_MAX_MESSAGE_KB" in exc.value.reason
        # the push route keeps its own, larger limit (AAR_PUSH_MAX_MB)
        with c.websocket_connect("/api/v1/stream/push") as ws:
            ws.send_bytes(b"\0" * 5000)
            assert "error" in ws.receive_json()  # a protocol error, not a closed connection


def test_an_address_closed_for_a_limit_is_refused_for_the_penalty(tmp_path: Path) -> None:
    with TestClient(service_app(_settings(tmp_path, ws_abuse_penalty_s=60.0))) as c:
        with c.websocket_connect("/api/v1/telemetry") as ws:
            for _ in range(25):  # over the burst of 20 (AAR_WS_MESSAGE_BURST)
                ws.send_text("x")
            with pytest.raises(WebSocketDisconnect) as exc:
                ws.receive_text()
        assert exc.value.code == 1008 and "AAR_WS_MAX_MESSAGES_PER_S" in exc.value.reason
        with pytest.raises(WebSocketDenialResponse) as denied:
            with c.websocket_connect("/api/v1/telemetry"):
                pass
        assert denied.value.status_code == 429
        assert "AAR_WS_ABUSE_PENALTY_S" in denied.value.json()["detail"]
        metrics = c.get("/api/v1/metrics").text
    assert 'reason="ws_message_rate"' in metrics and 'reason="ws_refused_penalty"' in metrics


def test_websocket_connections_are_capped_per_address_and_in_total(tmp_path: Path) -> None:
    app = service_app(_settings(tmp_path, max_websockets_per_client=2))
    with TestClient(app) as c:
        with c.websocket_connect("/api/v1/telemetry"), c.websocket_connect("/api/v1/telemetry"):
            with pytest.raises(WebSocketDenialResponse) as denied:
                with c.websocket_connect("/api/v1/telemetry"):
                    pass
            assert denied.value.status_code == 429
            assert "AAR_MAX_WEBSOCKETS_PER_CLIENT" in denied.value.json()["detail"]
        # the slots are given back when the connections close
        with c.websocket_connect("/api/v1/telemetry"), c.websocket_connect("/api/v1/telemetry"):
            pass
        assert 'reason="ws_refused_per_client"' in c.get("/api/v1/metrics").text
    with TestClient(service_app(_settings(tmp_path, max_websockets=1))) as c:
        with c.websocket_connect("/api/v1/telemetry"):
            with pytest.raises(WebSocketDenialResponse) as denied:
                with c.websocket_connect("/api/v1/telemetry"):
                    pass
            assert denied.value.status_code == 503
            assert "AAR_MAX_WEBSOCKETS" in denied.value.json()["detail"]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, int, Path]]:
    with serve(tmp_path_factory.mktemp("serve")) as (proc, port, log):
        yield proc.pid, port, log


def _flood(port: int, seconds: float, clients: int, out: Any) -> None:
    """Attacker process: ``clients`` threads, each connecting to the telemetry WebSocket and
    sending one-byte text messages as fast as it can, reconnecting when closed."""
    stop = threading.Event()
    closes: list[int] = []
    tiny = (frame_header(0x1, 1) + b"x") * 40_000  # 280 kB of one-byte text messages

    def flooder() -> None:
        while not stop.is_set():
            try:
                s = ws_connect(port, "/api/v1/telemetry", source="127.0.0.2")
            except (OSError, AssertionError):
                time.sleep(0.05)
                continue
            try:
                s.settimeout(2.0)
                while not stop.is_set():
                    s.sendall(tiny)
            except OSError:
                pass
            close = read_close(s, 1.0)
            closes.append(0 if close is None else close[0])
            s.close()

    threads = [threading.Thread(target=flooder) for _ in range(clients)]
    for t in threads:
        t.start()
    time.sleep(seconds)
    stop.set()
    for t in threads:
        t.join(timeout=10)
    out.put(closes)


def test_floods_of_tiny_messages_are_cut_and_healthz_stays_fast(
    server: tuple[int, int, Path],
) -> None:
    _, port, _ = server
    ctx = multiprocessing.get_context("spawn")
    out = ctx.Queue()
    with LatencyProbe(port, period_s=0.05) as idle:
        time.sleep(1.0)
    with LatencyProbe(port, period_s=0.05) as probe:
        time.sleep(0.5)
        proc = ctx.Process(target=_flood, args=(port, 5.0, 20, out))
        proc.start()
        closes = out.get(timeout=60)
        proc.join(timeout=10)
    print(f"healthz idle: p99 {idle.p99() * 1e3:.0f} ms")
    print(
        f"healthz under flood: p99 {probe.p99() * 1e3:.0f} ms, max "
        f"{max(probe.latencies) * 1e3:.0f} ms, {len(probe.latencies)} probes, "
        f"{len(closes)} flooding connections closed"
    )
    assert not probe.failures, probe.failures
    assert probe.p99() < 0.5
    assert 1008 in closes, closes[:5]
    metrics = httpx.get(f"http://127.0.0.1:{port}/api/v1/metrics").text
    assert 'aar_guard_events_total{reason="ws_message_rate"}' in metrics
