"""The documented exposed deployment (issue 34 item 4): Debian's nginx with the repository's
configuration (``deploy/nginx/nginx.conf.template``) in front of ``aar-dock serve`` on a
loopback port, run with the environment ``docker-compose.yml`` gives the service behind it.
The attacks go through the proxy:

* slowloris (request heads trickled a line at a time, never finished): the proxy closes every
  one within its ``client_header_timeout``, none reaches the service, ``/healthz`` answers;
* too many connections from one address (slow uploads held open): refused by ``limit_conn``
  (429) while the held ones stay open, ``/healthz`` answers from another address;
* a WebSocket handshake flood from one address: refused by ``limit_req`` (429);
* oversized bodies: 413 from the proxy on the declared length, per route;
* a real upload and a telemetry WebSocket client through the proxy work.

Skipped only where ``nginx`` is not installed (``bash .ci/run`` installs Debian's).
"""

from __future__ import annotations

import os
import pwd
import re
import select
import shutil
import socket
import string
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
import yaml
from websockets.sync.client import connect as ws_client

from tests.support.live_server import LatencyProbe, free_port, serve
from tests.support.waiting import stop_process, wait_for_server

ROOT = Path(__file__).resolve().parents[2]
TEMPLATE = ROOT / "deploy" / "nginx" / "nginx.conf.template"
NGINX = shutil.which("nginx") or next(
    (p for p in ("/usr/sbin/nginx", "/usr/local/sbin/nginx") if os.access(p, os.X_OK)), None
)
pytestmark = pytest.mark.skipif(
    NGINX is None, reason="nginx is not installed (bash .ci/run installs Debian's nginx-light)"
)


@dataclass(frozen=True)
class Stack:
    app_port: int  # the service, loopback
    proxy_port: int  # the proxy's HTTP port, where the attacks go
    nginx_log: Path  # nginx's error log (stderr)
    app_log: Path  # the service's log (uvicorn's access lines)


def config_value(directive: str) -> str:
    """The value of an http-level directive in the shipped template (e.g. ``10s``)."""
    m = re.search(rf"^\s*{directive}\s+([^;]+);", TEMPLATE.read_text(), re.MULTILINE)
    assert m, directive
    return m.group(1).strip()


def seconds(value: str) -> float:
    m = re.fullmatch(r"(\d+)(ms|s|m)?", value)
    assert m, value
    return int(m.group(1)) * {"ms": 1e-3, "s": 1.0, "m": 60.0, None: 1.0}[m.group(2)]


def behind_proxy_env() -> dict[str, str]:
    """The service's environment in ``docker-compose.yml`` (its literal values: those the
    deployer does not fill in), so that the test runs the documented deployment."""
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    env = compose["services"]["dashboard"]["environment"]
    assert "ports" not in compose["services"]["dashboard"]  # reachable through the proxy only
    return {k: str(v) for k, v in env.items() if "${" not in str(v) and k != "AAR_FOXGLOVE_HOST"}


def render(prefix: Path, values: dict[str, str]) -> Path:
    text = string.Template(TEMPLATE.read_text()).safe_substitute(values)
    live = [ln for ln in text.splitlines() if not ln.lstrip().startswith("#")]
    assert not [ln for ln in live if "${" in ln], "a placeholder was left"
    conf = prefix / "nginx.conf"
    conf.write_text(text)
    return conf


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Stack]:
    tmp = tmp_path_factory.mktemp("proxy")
    with serve(tmp, behind_proxy_env()) as (_proc, app_port, app_log):
        prefix = tmp / "nginx"
        prefix.mkdir()
        proxy_port = free_port()
        conf = render(
            prefix,
            {
                "AAR_PROXY_USER": pwd.getpwuid(os.geteuid()).pw_name,
                "AAR_PROXY_HTTP_LISTEN": f"127.0.0.1:{proxy_port}",
                "AAR_PROXY_VISER_LISTEN": f"127.0.0.1:{free_port()}",
                "AAR_PROXY_FOXGLOVE_LISTEN": f"127.0.0.1:{free_port()}",
                "AAR_PROXY_UPSTREAM_HTTP": f"127.0.0.1:{app_port}",
                "AAR_PROXY_UPSTREAM_VISER": f"127.0.0.1:{free_port()}",
                "AAR_PROXY_UPSTREAM_FOXGLOVE": f"127.0.0.1:{free_port()}",
            },
        )
        nginx_log = prefix / "error.log"
        with nginx_log.open("wb") as log:
            assert NGINX is not None
            proc = subprocess.Popen(
                [NGINX, "-p", f"{prefix}/", "-c", str(conf), "-g", "daemon off;"],
                stdout=log,
                stderr=log,
            )
            try:
                wait_for_server(
                    proc,
                    lambda: (
                        httpx.get(
                            f"http://127.0.0.1:{proxy_port}/api/v1/healthz", timeout=1
                        ).is_success
                    ),
                    nginx_log,
                    timeout_s=20,
                )
                yield Stack(app_port, proxy_port, nginx_log, app_log)
            finally:
                stop_process(proc)


def guard_events(port: int) -> dict[str, float]:
    """The service's own guard counters (``/metrics``), by reason."""
    text = httpx.get(f"http://127.0.0.1:{port}/api/v1/metrics", timeout=5).text
    found = re.findall(r'^aar_guard_events_total\{reason="([^"]+)"\} (\S+)$', text, re.MULTILINE)
    return {reason: float(v) for reason, v in found}


def status_of(resp: bytes) -> int:
    m = re.match(rb"HTTP/1\.[01] (\d{3})", resp)
    assert m, resp[:200]
    return int(m.group(1))


def read_head(s: socket.socket, timeout: float = 10.0) -> bytes:
    """The response's head and whatever of its body came with it (b"" if just closed)."""
    s.settimeout(timeout)
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = s.recv(65536)
        if not chunk:
            break
        data += chunk
    return data


def test_slowloris_is_closed_by_the_proxy_and_healthz_answers(stack: Stack) -> None:
    n = 300  # more than the service's own per-address cap (128): none may reach it
    timeout_s = seconds(config_value("client_header_timeout"))
    before = guard_events(stack.app_port)
    opened: dict[socket.socket, float] = {}
    closed_after: list[float] = []
    with LatencyProbe(stack.proxy_port, period_s=0.1) as probe:
        for _ in range(n):
            s = socket.create_connection(
                ("127.0.0.1", stack.proxy_port), timeout=2, source_address=("127.0.0.2", 0)
            )
            s.sendall(b"GET /api/v1/healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            opened[s] = time.monotonic()
        live = dict(opened)
        deadline = time.monotonic() + timeout_s + 5
        next_trickle = 0.0
        while live and time.monotonic() < deadline:
            now = time.monotonic()
            if now >= next_trickle:  # one more header line on each, every 0.5 s
                for s in list(live):
                    try:
                        s.send(b"X-a: b\r\n")
                    except OSError:
                        closed_after.append(now - live.pop(s))
                next_trickle = now + 0.5
            readable, _, _ = select.select(list(live), [], [], 0.1)
            for s in readable:  # the proxy closed it (EOF, maybe after a 408)
                closed_after.append(time.monotonic() - live.pop(s))
        still_open = len(live)
    for s in opened:
        s.close()
    after = guard_events(stack.app_port)
    print(
        f"slowloris {n} connections through the proxy: closed after {min(closed_after):.1f}–"
        f"{max(closed_after):.1f} s (client_header_timeout {timeout_s:g} s), {still_open} "
        f"still open; healthz p99 {probe.p99() * 1e3:.0f} ms, max "
        f"{max(probe.latencies) * 1e3:.0f} ms over {len(probe.latencies)} probes"
    )
    assert still_open == 0 and len(closed_after) == n
    assert max(closed_after) <= timeout_s + 2.0  # trickling does not extend the deadline
    assert min(closed_after) >= timeout_s - 1.0  # the proxy's timeout, not a refusal
    assert not probe.failures, probe.failures
    assert max(probe.latencies) < 1.0
    # none reached the service: its own header timeout and caps never fired
    for reason in ("header_timeout", "connection_refused_per_client"):
        assert after.get(reason, 0.0) == before.get(reason, 0.0), (reason, before, after)


def test_too_many_connections_from_one_address_refused_by_limit_conn(stack: Stack) -> None:
    cap = int(config_value("limit_conn").split()[1])  # limit_conn ZONE N
    head = (
        b"POST /api/v1/stereo HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: multipart/form-data; boundary=x\r\nContent-Length: 1000000\r\n\r\n"
    )
    held: list[socket.socket] = []
    log0 = stack.nginx_log.stat().st_size
    try:
        with LatencyProbe(stack.proxy_port, period_s=0.1) as probe:
            for _ in range(cap):  # slow uploads: each request stays in progress
                s = socket.create_connection(
                    ("127.0.0.1", stack.proxy_port), timeout=5, source_address=("127.0.0.3", 0)
                )
                s.sendall(head + b"-" * 100)
                held.append(s)
            time.sleep(0.5)
            extra = socket.create_connection(
                ("127.0.0.1", stack.proxy_port), timeout=5, source_address=("127.0.0.3", 0)
            )
            with extra:
                extra.sendall(head)
                refused = read_head(extra)
            for s in held:  # the held ones are still open: a byte more each
                s.sendall(b"-")
            last_byte = time.monotonic()
            readable, _, _ = select.select(held, [], [], 0.2)
            # then silence: the proxy ends each slow body within client_body_timeout
            body_timeout_s = seconds(config_value("client_body_timeout"))
            pending = list(held)
            while pending and time.monotonic() < last_byte + body_timeout_s + 3:
                done, _, _ = select.select(pending, [], [], 0.2)
                pending = [s for s in pending if s not in done]
            ended_after = time.monotonic() - last_byte
    finally:
        for s in held:
            s.close()
    log = stack.nginx_log.read_bytes()[log0:].decode(errors="replace")
    print(f"{cap} held from one address; one more: {refused[:40]!r}; healthz max "
          f"{max(probe.latencies) * 1e3:.0f} ms over {len(probe.latencies)} probes; the slow "
          f"bodies ended {ended_after:.1f} s after their last byte")  # fmt: skip
    assert status_of(refused) == 429
    assert "limiting connections by zone" in log and '"aar_conn_per_addr"' in log
    assert not readable  # none of the held ones was answered or closed
    assert not pending and body_timeout_s - 1 <= ended_after <= body_timeout_s + 3, ended_after
    assert not probe.failures, probe.failures
    assert max(probe.latencies) < 1.0


def test_websocket_handshake_flood_refused_by_limit_req(stack: Stack) -> None:
    statuses = []
    for _ in range(40):
        with socket.create_connection(
            ("127.0.0.1", stack.proxy_port), timeout=5, source_address=("127.0.0.4", 0)
        ) as s:
            s.sendall(
                b"GET /api/v1/telemetry HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                b"Sec-WebSocket-Version: 13\r\n\r\n"
            )
            statuses.append(status_of(read_head(s)))
    print(f"40 handshakes at once from one address: {statuses}")
    assert statuses[0] == 101
    assert 429 in statuses and statuses.count(101) <= 22  # burst 20 (+ refill)


def test_oversized_bodies_are_413_at_the_proxy(stack: Stack) -> None:
    """One byte over the service's own limit of each route (its defaults): 413 from the proxy
    on the declared length, before a body byte is sent; the limit itself passes on (the body
    is then awaited: the proxy's own 413 is on the length alone)."""
    from app.server.settings import Settings

    defaults = Settings()
    cases = [
        ("POST", "/api/v1/stereo", defaults.stereo_request_limit_bytes),
        ("POST", "/api/v1/calibration/checkerboard", defaults.checkerboard_limit_bytes),
        ("PUT", "/api/v1/sim/config", defaults.json_limit_bytes),
        ("PUT", "/api/v1/calibration", defaults.json_limit_bytes),
    ]
    for method, path, limit in cases:
        for length, refused in ((limit + 1, True), (limit, False)):
            t0 = time.monotonic()
            with socket.create_connection(("127.0.0.1", stack.proxy_port), timeout=5) as s:
                s.sendall(
                    f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
                    f"application/json\r\nContent-Length: {length}\r\n\r\n".encode()
                )
                if refused:
                    resp = read_head(s)
                    head = resp.split(b"\r\n\r\n")[0].lower()
                    assert status_of(resp) == 413, (path, length, resp[:200])
                    assert b"application/json" not in head  # nginx's page, not the service's
                    assert time.monotonic() - t0 < 2.0
                else:
                    readable, _, _ = select.select([s], [], [], 0.5)
                    assert not readable, (path, length, s.recv(200))  # waiting for the body


def test_upload_and_telemetry_websocket_through_the_proxy(stack: Stack) -> None:
    pair = ROOT / "sample_data" / "pair_1000mm"
    url = f"ws://127.0.0.1:{stack.proxy_port}/api/v1/telemetry"
    with ws_client(url, open_timeout=10) as ws:
        files = {
            "left": ("left.png", (pair / "left.png").read_bytes(), "image/png"),
            "right": ("right.png", (pair / "right.png").read_bytes(), "image/png"),
        }
        r = httpx.post(
            f"http://127.0.0.1:{stack.proxy_port}/api/v1/stereo", files=files, timeout=60
        )
        assert r.status_code == 200, r.text
        assert len(r.json()["leds"]) == 5
        record = ws.recv(timeout=30)
    assert isinstance(record, str) and '"source":"upload"' in record.replace(" ", "")


def test_oversized_request_head_is_refused_at_the_proxy(stack: Stack) -> None:
    with socket.create_connection(("127.0.0.1", stack.proxy_port), timeout=5) as s:
        s.sendall(
            b"GET /api/v1/healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: "
            + b"a" * 20_000
            + b"\r\n\r\n"
        )
        resp = read_head(s)
    assert status_of(resp) == 400 and b"Too Large" in resp, resp[:300]


def test_the_service_sees_the_clients_address_and_checks_its_host(stack: Stack) -> None:
    """The proxy passes the Host the client sent (the service's DNS-rebinding check still
    answers) and the client's address (X-Forwarded-For, trusted from the proxy)."""
    url = f"http://127.0.0.1:{stack.proxy_port}/api/v1/healthz"
    bad = httpx.get(url, headers={"Host": "rebound.example.org"}, timeout=5)
    assert bad.status_code == 400 and "untrusted Host" in bad.json()["detail"]
    transport = httpx.HTTPTransport(local_address="127.0.0.6")
    with httpx.Client(transport=transport, timeout=5) as client:
        assert client.get(url).status_code == 200
    time.sleep(0.3)
    access = [ln for ln in stack.app_log.read_text().splitlines() if "/api/v1/healthz" in ln]
    assert any("127.0.0.6:" in ln for ln in access), access[-3:]
