"""A real ``aar-dock serve`` process for the tests that need real sockets, and a raw WebSocket client."""

from __future__ import annotations

import base64
import os
import resource
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx

from tests.support.waiting import stop_process, wait_for_server

ROOT = Path(__file__).resolve().parents[2]  # the repository


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def serve(
    tmp_path: Path, env_extra: dict[str, str] | None = None, nofile: int | None = None
) -> Iterator[tuple[subprocess.Popen[bytes], int, Path]]:
    """``aar-dock serve --source push`` (no token, no viser, no simulation) as a process."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("AAR_")}
    env.update(AAR_RECORDINGS_DIR=str(tmp_path / "rec"), PYTHONPATH=str(ROOT))
    env.update(env_extra or {})
    cmd = [sys.executable, "-m", "app", "serve", "--source", "push", "--no-viser", "--no-sim"]
    log_path = tmp_path / f"serve-{port}.log"
    log = log_path.open("wb")

    def limit_fds() -> None:  # in the child, before exec
        if nofile is not None:
            resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

    proc = subprocess.Popen(
        cmd + ["--port", str(port)],
        cwd=ROOT,
        env=env,
        stdout=log,
        stderr=log,
        preexec_fn=limit_fds,
    )
    try:
        wait_for_server(
            proc,
            lambda: httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=1).is_success,
            log_path,
        )
        yield proc, port, log_path
    finally:
        stop_process(proc)
        log.close()


def ws_connect(
    port: int, path: str, source: str | None = None, timeout: float = 10.0
) -> socket.socket:
    """A raw WebSocket client after its handshake (101)."""
    s = socket.create_connection(
        ("127.0.0.1", port), timeout=timeout, source_address=(source, 0) if source else None
    )
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(
        f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
    )
    resp = b""
    while b"\r\n\r\n" not in resp:
        chunk = s.recv(4096)
        assert chunk, resp
        resp += chunk
    assert b" 101 " in resp.split(b"\r\n")[0], resp[:200]
    return s


class LatencyProbe:
    """``GET /healthz`` every ``period_s`` from its own thread; latencies (s), failures."""

    def __init__(self, port: int, period_s: float = 0.1, timeout_s: float = 1.0) -> None:
        self.port = port
        self.period_s, self.timeout_s = period_s, timeout_s
        self.latencies: list[float] = []
        self.failures: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _get(self) -> bool:
        """One ``GET /healthz`` on a new connection: 200 within the timeout."""
        try:
            s = socket.create_connection(("127.0.0.1", self.port), timeout=self.timeout_s)
        except OSError as exc:
            raise OSError(f"connect: {exc}") from None
        with s:
            s.sendall(
                b"GET /api/v1/healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
            )
            resp = b""
            while chunk := s.recv(65536):
                resp += chunk
        return resp.startswith(b"HTTP/1.1 200")

    def _run(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                if not self._get():
                    self.failures.append("status")
            except OSError as exc:
                self.failures.append(str(exc))
            self.latencies.append(time.monotonic() - t0)
            self._stop.wait(self.period_s)

    def __enter__(self) -> LatencyProbe:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def p99(self) -> float:
        lat = sorted(self.latencies)
        return lat[min(len(lat) - 1, int(0.99 * len(lat)))]
