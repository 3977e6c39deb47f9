"""The Foxglove port under the service's access model (issue 33, item 2), against a real
``aar-dock serve --foxglove-port`` process with ``AAR_TOKEN`` set and its descriptor limit
lowered to 1 500:

* a cross-origin client without the token is refused; one from the service's own page with
  the token (in the URL, as Foxglove's *Open connection* sends it) is served;
* 2 500 raw TCP connections to the Foxglove port, held open: ``/healthz``, probed while they
  are held, answers within 1 s on at least 18 of 20 probes and reports the gate's refusals;
* the SDK's own server, on loopback, speaks only TLS with a certificate a browser does not
  know: a plain ``ws://`` client cannot open it.
"""

from __future__ import annotations

import asyncio
import base64
import json
import multiprocessing
import os
import resource
import socket
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
import websockets

from app.resources import load_default_calibration
from app.service.foxglove_gate import GatePolicy
from app.service.foxglove_output import FoxgloveOutput
from app.service.settings import Settings
from tests.support.live_server import free_port, serve

TOKEN = "fox-secret-token"
NOFILE = 1500


def _handshake(
    port: int, target: str = "/", headers: dict[str, str] | None = None
) -> tuple[int, bytes]:
    """A raw WebSocket upgrade on the Foxglove port: (status, what followed the head)."""
    key = base64.b64encode(os.urandom(16)).decode()
    lines = {
        "Host": f"127.0.0.1:{port}",
        "Upgrade": "websocket",
        "Connection": "Upgrade",
        "Sec-WebSocket-Key": key,
        "Sec-WebSocket-Version": "13",
        "Sec-WebSocket-Protocol": "foxglove.sdk.v1",
        **(headers or {}),
    }
    head = f"GET {target} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in lines.items())
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall((head + "\r\n").encode())
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
        status = int(data.split(b" ", 2)[1]) if data.startswith(b"HTTP/1.1 ") else 0
        rest = data.split(b"\r\n\r\n", 1)[1] if b"\r\n\r\n" in data else b""
        if status == 101:  # the server's first message: serverInfo
            s.settimeout(5)
            while len(rest) < 64:
                chunk = s.recv(65536)
                if not chunk:
                    break
                rest += chunk
        return status, rest


def _first_message(data: bytes) -> dict[str, Any]:
    """The first (unmasked, text) frame a server sent, as JSON."""
    n, start = data[1] & 0x7F, 2
    if n == 126:
        n, start = int.from_bytes(data[2:4], "big"), 4
    elif n == 127:
        n, start = int.from_bytes(data[2:10], "big"), 10
    assert data[0] & 0x0F == 0x1, data[:20]
    parsed: dict[str, Any] = json.loads(data[start : start + n])
    return parsed


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, int]]:
    """(HTTP port, Foxglove port) of a service with a token, at a descriptor limit of 1 500."""
    fox = free_port()
    env = {"AAR_TOKEN": TOKEN, "AAR_FOXGLOVE_PORT": str(fox), "AAR_HEADER_TIMEOUT_S": "3"}
    with serve(tmp_path_factory.mktemp("fox"), env, nofile=NOFILE) as (_proc, port, _log):
        yield port, fox


def test_cross_origin_client_without_the_token_is_refused(service: tuple[int, int]) -> None:
    port, fox = service
    evil = {"Origin": "http://evil.example.com"}
    status, body = _handshake(fox, "/", evil)
    assert status == 403, body
    assert b"evil.example.com" in body
    # with the token in the URL it is still a foreign page: refused
    assert _handshake(fox, f"/?token={TOKEN}", evil)[0] == 403
    # the service's own page, but no token (or a wrong one): refused
    own = {"Origin": f"http://127.0.0.1:{port}"}
    assert _handshake(fox, "/", own)[0] == 401
    assert _handshake(fox, "/?token=wrong", own)[0] == 401
    assert _handshake(fox, "/", {"Authorization": "Bearer wrong"})[0] == 401
    # DNS rebinding: an untrusted Host
    assert _handshake(fox, "/", {"Host": f"evil.example.com:{fox}"})[0] == 400
    # the service's own page with the token, and a script (no Origin) with the bearer token
    status, first = _handshake(fox, f"/?token={TOKEN}", own)
    assert status == 101 and _first_message(first)["op"] == "serverInfo"
    status, first = _handshake(fox, "/", {"Authorization": f"Bearer {TOKEN}"})
    assert status == 101 and _first_message(first)["op"] == "serverInfo"
    health = httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=5).json()
    fg = health["foxglove"]
    assert fg["running"] and fg["port"] == fox and fg["served"] >= 2
    assert fg["refused"]["origin"] >= 2 and fg["refused"]["token"] >= 3
    assert fg["refused"]["host"] >= 1
    assert {"name": "foxglove", "status": "ok", "reason": None} in health["components"]


def _hold(port: int, n: int, out: Any, release: Any) -> None:
    """Attacker process: ``n`` raw TCP connections to ``port`` from five loopback addresses,
    sending nothing, held until ``release`` is set (at most 60 s). Puts how many connected."""
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, n + 256), hard))
    live: list[socket.socket] = []
    for i in range(n):
        source = f"127.0.0.{2 + i % 5}"
        try:
            live.append(
                socket.create_connection(("127.0.0.1", port), timeout=2, source_address=(source, 0))
            )
        except OSError:
            pass
    out.put(len(live))
    release.wait(60)
    for s in live:
        s.close()


def _probe(port: int) -> float:
    """One ``GET /healthz`` on a new connection: seconds to a 200 (inf: none within 1 s)."""
    t0 = time.monotonic()
    try:
        r = httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=1.0)
    except httpx.HTTPError:
        return float("inf")
    dt = time.monotonic() - t0
    return dt if r.status_code == 200 and dt <= 1.0 else float("inf")


def test_2500_raw_connections_leave_healthz_answering(service: tuple[int, int]) -> None:
    port, fox = service
    ctx = multiprocessing.get_context("spawn")
    out, release = ctx.Queue(), ctx.Event()
    attacker = ctx.Process(target=_hold, args=(fox, 2500, out, release))
    attacker.start()
    try:
        connected = out.get(timeout=180)  # all 2 500 tried; the ones that connected held
        latencies = []
        for _ in range(20):
            latencies.append(_probe(port))
            time.sleep(0.25)
        try:
            health = httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=10).json()
        except httpx.HTTPError:
            health = {}
    finally:
        release.set()
        attacker.join(timeout=60)
        if attacker.is_alive():
            attacker.kill()
    answered = sum(1 for t in latencies if t <= 1.0)
    fg = health.get("foxglove") or {}
    print(
        f"2500 raw connections to the Foxglove port (fd limit {NOFILE}): {connected} connected; "
        f"healthz {answered}/20 within 1 s, max {max(latencies) * 1e3:.0f} ms; gate {fg}"
    )
    assert answered >= 18, latencies
    assert fg and fg["running"]
    assert fg["refused"].get("per_address", 0) + fg["refused"].get("total", 0) >= 2000
    # once they are gone, a client with the token is served again
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        if _handshake(fox, "/", {"Authorization": f"Bearer {TOKEN}"})[0] == 101:
            break
        time.sleep(0.5)
    else:
        raise AssertionError("the Foxglove port did not recover after the flood")


def test_the_sdk_server_itself_speaks_only_tls() -> None:
    policy = GatePolicy.from_settings(Settings(_env_file=None))  # type: ignore[call-arg]
    out = FoxgloveOutput("127.0.0.1", 0, load_default_calibration(), policy=policy)

    async def plain() -> str:
        url = f"ws://127.0.0.1:{out.live.port}"
        try:
            async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=5):
                return "opened"
        except (OSError, websockets.exceptions.WebSocketException, TimeoutError) as exc:
            return type(exc).__name__

    try:
        assert out.live.port != out.port
        assert asyncio.run(plain()) != "opened"
        status, first = _handshake(out.port)  # through the gate: served
        assert status == 101 and _first_message(first)["op"] == "serverInfo"
    finally:
        out.close()
    assert not out.gate.health().running
