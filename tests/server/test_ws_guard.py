"""WebSocket limits in the ASGI layer (in-process): per-route message sizes, connection caps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketDenialResponse
from starlette.websockets import WebSocketDisconnect

from app.server.main import create_app
from app.server.settings import Settings
from tests.support.service_settings import IN_PROCESS, service_settings


def _settings(tmp_path: Path, **kw: Any) -> Settings:
    return service_settings(tmp_path, **{**IN_PROCESS, **kw})


def test_telemetry_takes_only_small_messages(tmp_path: Path) -> None:
    with TestClient(create_app(_settings(tmp_path))) as c:
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


def test_websocket_connections_are_capped_per_address_and_in_total(tmp_path: Path) -> None:
    app = create_app(_settings(tmp_path, max_websockets_per_client=2))
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
    with TestClient(create_app(_settings(tmp_path, max_websockets=1))) as c:
        with c.websocket_connect("/api/v1/telemetry"):
            with pytest.raises(WebSocketDenialResponse) as denied:
                with c.websocket_connect("/api/v1/telemetry"):
                    pass
            assert denied.value.status_code == 503
            assert "AAR_MAX_WEBSOCKETS" in denied.value.json()["detail"]
