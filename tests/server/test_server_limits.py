"""Whether the app runs with the server limits of ``aar-dock serve`` (issue 33 item 5): said in
``/healthz`` to a real client, and in the log when it is started with plain uvicorn."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.support.inline_sim import inline_sim
from tests.support.live_server import serve


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, int, Path]]:
    with serve(tmp_path_factory.mktemp("serve")) as (proc, port, log):
        yield proc.pid, port, log


def test_serve_reports_its_server_limits(server: tuple[int, int, Path]) -> None:
    _pid, port, _log = server
    health = httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=5).json()
    assert {"name": "server_limits", "status": "ok", "reason": None} in health["components"]


def test_plain_uvicorn_start_warns_and_reports_degraded(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """``uvicorn --factory app.server.main:create_app`` as a deployer might: the app says,
    in its log and in ``/healthz``, that it runs without ``aar-dock serve``'s limits."""
    import uvicorn

    from app.server.main import create_app
    from app.server.server_limits import UNGUARDED
    from tests.support.fake_sim import FakeSim
    from tests.support.live_server import free_port
    from tests.support.service_settings import service_settings

    app = create_app(
        service_settings(tmp_path, sim_auto_restart_s=None),
        source_factory=inline_sim(lambda cfg, cal: FakeSim(cfg, cal)),
    )
    port = free_port()
    server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    caplog.set_level(logging.WARNING, logger="app.server.security")
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while not server.started and thread.is_alive() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert server.started
        health = httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=5).json()
        httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=5)
    finally:
        server.should_exit = True
        thread.join(15)
    guard = [c for c in health["components"] if c["name"] == "server_limits"]
    assert guard == [{"name": "server_limits", "status": "degraded", "reason": UNGUARDED}]
    assert health["status"] == "degraded"
    warnings = [r for r in caplog.records if "aar-dock serve" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].levelno == logging.WARNING  # once, not per request
