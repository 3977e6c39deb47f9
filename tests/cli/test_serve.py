"""``aar-dock serve``: uvicorn's own limits as it passes them, and the line it prints when it
listens beyond this machine (issue 34 item 4)."""

from __future__ import annotations

import signal
import socket
import threading
import time
from pathlib import Path

import httpx
import pytest

from app.cli.main import main
from app.cli.serve import PROXY_CONFIG, exposure_notice
from app.server.server_limits import MAX_HEADER_BYTES, connection_cap, server_limits
from app.service.settings import Settings
from tests.support.live_server import free_port, serve

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.2", "localhost", "::1", "[::1]"])
def test_loopback_binds_print_no_notice(host: str) -> None:
    assert exposure_notice(host) is None


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.0.2.10", "dock.example.org"])
def test_exposed_binds_say_behind_the_proxy(host: str) -> None:
    notice = exposure_notice(host)
    assert notice is not None and "behind the proxy" in notice and PROXY_CONFIG in notice
    assert (ROOT / PROXY_CONFIG).is_file()


def test_serve_on_0_0_0_0_says_so_at_start(capsys: pytest.CaptureFixture[str]) -> None:
    """The line comes before the ports are checked: here the port is taken, so ``serve``
    stops with exit 2 right after it, without serving."""
    with socket.socket() as held:
        held.bind(("0.0.0.0", 0))
        held.listen()
        port = held.getsockname()[1]
        code = main(["serve", "--host", "0.0.0.0", "--port", str(port), "--no-viser", "--no-sim"])
    out, err = capsys.readouterr()
    assert code == 2 and "in use" in err
    lines = [line for line in out.splitlines() if "behind the proxy" in line]
    assert len(lines) == 1 and PROXY_CONFIG in lines[0], out


def test_server_limits_from_the_settings() -> None:
    settings = Settings(keep_alive_s=7.4, push_max_mb=3.0, max_connections=100)
    limits = server_limits(settings)
    assert limits.limit_concurrency == connection_cap(settings) == 100
    assert limits.backlog == 100
    assert limits.timeout_keep_alive_s == 7
    assert limits.ws_max_size_bytes >= 3_000_000
    assert limits.h11_max_incomplete_event_size_bytes == MAX_HEADER_BYTES
    # a listener without the push route takes only the small messages (AAR_WS_MAX_MESSAGE_KB)
    small = server_limits(settings, push_listener=False).ws_max_size_bytes
    assert settings.ws_message_limit_bytes < small < 10_000


def test_the_connection_cap_leaves_descriptors_for_everything_else(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import app.server.server_limits as limits_module

    monkeypatch.setattr(limits_module, "fd_limit", lambda: 512)
    assert connection_cap(Settings(max_connections=1024, fd_reserve=128)) == 512 - 128
    assert connection_cap(Settings(max_connections=100, fd_reserve=128)) == 100


def test_uvicorns_own_cap_answers_503_beyond_it() -> None:
    """The total cap is uvicorn's own: with ``limit_concurrency`` connections open, one more
    request is a 503; with one fewer it is answered."""
    import uvicorn
    from fastapi import FastAPI

    app = FastAPI()

    @app.get("/ping")
    def ping() -> dict[str, bool]:
        return {"ok": True}

    limits = server_limits(Settings(max_connections=8))
    port = free_port()
    config = uvicorn.Config(
        app, host="127.0.0.1", port=port, log_level="warning",
        limit_concurrency=limits.limit_concurrency,
    )  # fmt: skip
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    idle: list[socket.socket] = []
    try:
        deadline = time.monotonic() + 20
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.02)
        assert server.started
        url = f"http://127.0.0.1:{port}/ping"
        for _ in range(limits.limit_concurrency - 2):
            idle.append(socket.create_connection(("127.0.0.1", port)))
        time.sleep(0.3)
        assert httpx.get(url, timeout=5).status_code == 200  # limit − 1 open with it
        idle.append(socket.create_connection(("127.0.0.1", port)))
        time.sleep(0.3)
        assert httpx.get(url, timeout=5).status_code == 503  # the limit reached
    finally:
        for s in idle:
            s.close()
        server.should_exit = True
        thread.join(15)


def test_serve_hands_uvicorn_these_limits(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``serve`` up to ``uvicorn.Server.run`` (not run: the config it got is kept)."""
    import uvicorn

    import app.sim.warmup

    seen: list[uvicorn.Config] = []

    def keep_config(self: uvicorn.Server, sockets: list[socket.socket] | None = None) -> None:
        seen.append(self.config)
        for s in sockets or []:
            s.close()

    monkeypatch.setattr(uvicorn.Server, "run", keep_config)
    monkeypatch.setattr(app.sim.warmup, "compile_kernels", lambda: None)
    for key in ("AAR_MAX_CONNECTIONS", "AAR_KEEP_ALIVE_S", "AAR_PUSH_MAX_MB"):
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("AAR_MAX_CONNECTIONS", "200")
    port = free_port()
    main(["serve", "--port", str(port), "--no-viser", "--no-sim", "--source", "push"])
    capsys.readouterr()
    assert len(seen) == 1
    config = seen[0]
    settings = Settings(max_connections=200)
    limits = server_limits(settings)
    assert config.limit_concurrency == limits.limit_concurrency == connection_cap(settings)
    assert config.backlog == limits.backlog
    assert config.timeout_keep_alive == limits.timeout_keep_alive_s
    assert config.ws_max_size == limits.ws_max_size_bytes
    assert (
        (config.ws, config.ws_max_queue) == ("websockets", limits.ws_max_queue) == ("websockets", 1)
    )
    assert config.h11_max_incomplete_event_size == MAX_HEADER_BYTES


def test_sigterm_is_a_clean_exit_after_the_graceful_shutdown(tmp_path: Path) -> None:
    """``aar-dock serve`` stopped by SIGTERM (``docker stop``, systemd) shuts down, then exits
    with status 0 through Python's exit handlers: not killed by the signal uvicorn raises
    again, which skipped them (the upload pool's semaphores were reported leaked)."""

    with serve(tmp_path) as (proc, _port, log_path):
        time.sleep(3.0)  # the upload workers started
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    log = log_path.read_text(errors="replace")
    assert "Application shutdown complete" in log
    assert "leaked" not in log
