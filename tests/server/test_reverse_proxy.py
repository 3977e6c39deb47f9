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
* a real upload and a telemetry WebSocket client through the proxy work; the push route goes
  to the service's push listener (``AAR_PUSH_PORT``);
* 40 telemetry clients announcing 40 MB messages: 1009 at the frame header, neither the
  service's memory nor the proxy's grows;
* slowloris from two addresses, many times the service's descriptor limit (lowered to 512):
  the proxy holds and closes them, none reaches the service, ``/healthz`` answers.

Skipped only where ``nginx`` is not installed (``bash .ci/run`` installs Debian's).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import pwd
import re
import resource
import select
import shutil
import socket
import string
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect as ws_client

from tests.support.live_server import LatencyProbe, free_port, serve, ws_connect
from tests.support.waiting import stop_process, wait_for_server
from tests.support.ws_frames import frame_header, read_close

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
    app_pid: int  # the service's process
    app_port: int  # the service, loopback
    push_port: int  # the service's push listener (AAR_PUSH_PORT), loopback
    proxy_pid: int  # nginx's master process
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


def _port_open(port: int) -> bool:
    with socket.create_connection(("127.0.0.1", port), timeout=1):
        return True


@contextmanager
def run_stack(
    tmp: Path, env_extra: dict[str, str] | None = None, nofile: int | None = None
) -> Iterator[Stack]:
    """nginx with the shipped template in front of ``aar-dock serve`` (the compose
    environment, its push listener on a free port; ``nofile``: the service's descriptor
    limit), all on loopback."""
    push_port = free_port()
    env = {**behind_proxy_env(), "AAR_PUSH_PORT": str(push_port), **(env_extra or {})}
    with serve(tmp, env, nofile=nofile) as (app_proc, app_port, app_log):
        wait_for_server(app_proc, lambda: _port_open(push_port), app_log, timeout_s=20)
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
                "AAR_PROXY_UPSTREAM_PUSH": f"127.0.0.1:{push_port}",
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
                yield Stack(
                    app_proc.pid, app_port, push_port, proc.pid, proxy_port, nginx_log, app_log
                )
            finally:
                stop_process(proc)


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Stack]:
    with run_stack(tmp_path_factory.mktemp("proxy")) as running:
        yield running


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
    from app.service.settings import Settings

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


# ---- the attacks of issue 23, through the proxy ------------------------------------------
MB = 1_000_000


def _rss_mb(pid: int) -> float:
    """A process's resident memory (MB), plus its children's (nginx: the workers)."""
    total = 0.0
    children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    for p in [pid, *map(int, children)]:
        for line in Path(f"/proc/{p}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                total += int(line.split()[1]) / 1e3
    return total


class PeakSampler:
    """The peak of ``value()`` sampled every 20 ms from its own thread, while in the block."""

    def __init__(self, value: Callable[[], float]) -> None:
        self.value = value
        self.first = self.peak = value()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            with suppress(OSError, ValueError):
                self.peak = max(self.peak, self.value())

    def __enter__(self) -> PeakSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def test_telemetry_clients_announcing_40_mb_messages_cost_no_memory(stack: Stack) -> None:
    """40 tokenless telemetry clients through the proxy (from 40 addresses: the proxy's
    handshake rate is per address), each announcing a 40 MB message: the service refuses each
    at its frame header (1009: its HTTP port takes ``AAR_WS_MAX_MESSAGE_KB``; the push route's
    ``AAR_PUSH_MAX_MB`` is on the push listener) and the proxy passes the close on; neither the
    service's memory nor the proxy's grows by more than 100 MB."""
    closes: list[tuple[int, str] | None] = []
    sent_mb: list[float] = []
    connected = threading.Barrier(41)

    def attacker(i: int) -> None:
        s = ws_connect(stack.proxy_port, "/api/v1/telemetry", source=f"127.0.1.{i + 1}")
        connected.wait(timeout=60)  # all 40 connected before any announces its message
        sent = 0
        try:
            s.sendall(frame_header(0x2, 40 * MB))
            chunk = b"\0" * MB
            s.settimeout(2.0)
            while sent < 40 * MB:
                s.sendall(chunk)
                sent += MB
        except OSError:
            pass
        sent_mb.append(sent / MB)
        closes.append(read_close(s, 5.0))
        s.close()

    threads = [threading.Thread(target=attacker, args=(i,)) for i in range(40)]
    with PeakSampler(lambda: _rss_mb(stack.app_pid)) as app_rss:
        with PeakSampler(lambda: _rss_mb(stack.proxy_pid)) as proxy_rss:
            for t in threads:
                t.start()
            connected.wait(timeout=60)
            for t in threads:
                t.join(timeout=120)
            time.sleep(0.3)
    growth = {"service": app_rss.peak - app_rss.first, "proxy": proxy_rss.peak - proxy_rss.first}
    print(
        f"RSS service {app_rss.first:.0f} → peak {app_rss.peak:.0f} MB, proxy "
        f"{proxy_rss.first:.0f} → peak {proxy_rss.peak:.0f} MB; sent (MB) {sorted(sent_mb)}"
    )
    assert max(growth.values()) <= 100, growth
    codes = [c[0] for c in closes if c is not None]
    assert len(codes) == 40 and set(codes) == {1009}, closes
    health = httpx.get(f"http://127.0.0.1:{stack.proxy_port}/api/v1/healthz", timeout=5)
    assert health.json()["status"] == "ok"


def test_the_push_route_goes_to_the_push_listener(stack: Stack) -> None:
    """Through the proxy ``/api/v1/stream/push`` reaches the push listener, which takes
    messages of ``AAR_PUSH_MAX_MB``: a 5 kB message is read there (the stream answers a protocol
    error), where the telemetry route closes at once with 1009 (over ``AAR_WS_MAX_MESSAGE_KB``)."""
    url = f"ws://127.0.0.1:{stack.proxy_port}/api/v1"
    with ws_client(f"{url}/stream/push", open_timeout=10) as ws:
        ws.send(b"\0" * 5000)
        assert "error" in json.loads(ws.recv(timeout=10))
    with ws_client(f"{url}/telemetry", open_timeout=10) as ws:
        ws.send(b"\0" * 5000)
        with pytest.raises(ConnectionClosed) as closed:
            while True:
                ws.recv(timeout=10)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009


def _slowloris(port: int, source: str, n: int, seconds: float, out: Any) -> None:
    """Attacker process: ``n`` connections from ``source``, each sending a request's head one
    line at a time (never the blank line that ends it), every 0.5 s, for ``seconds`` after the
    last one opened. Puts (opened, still open at the end)."""
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, n + 256), hard))
    live: list[socket.socket] = []
    opened = 0
    for _ in range(n):
        with suppress(OSError):
            s = socket.create_connection(("127.0.0.1", port), timeout=2, source_address=(source, 0))
            s.sendall(b"GET /api/v1/healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            live.append(s)
            opened += 1
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        live = _trickle(live)
        time.sleep(0.5)
    still_open = 0
    for s in _trickle(live):  # the proxy closed it: EOF to read (or a refused send)
        readable, _, _ = select.select([s], [], [], 0)
        still_open += not readable
        s.close()
    out.put((opened, still_open))


def _trickle(live: list[socket.socket]) -> list[socket.socket]:
    """One more header line on each connection; the ones the peer closed are dropped."""
    kept = []
    for s in live:
        try:
            s.send(b"X-a: b\r\n")
            kept.append(s)
        except OSError:
            s.close()
    return kept


def _open_fds(pid: int) -> float:
    return float(len(os.listdir(f"/proc/{pid}/fd")))


@pytest.mark.slow
def test_slowloris_at_a_lowered_fd_limit(tmp_path: Path) -> None:
    """Slowloris from two addresses, many times the service's descriptor limit (512), through
    the proxy: the proxy holds them (one descriptor each, its ``worker_rlimit_nofile``) and
    closes every one at its ``client_header_timeout``; none reaches the service, whose open
    descriptors stay far under its limit; ``/healthz`` through the proxy from a third address
    answers within 1 s throughout; neither log grows by more than 1 MB.
    ``AAR_TEST_SLOWLORIS_N`` connections per attacker (default 2000; the issue's figure: 10 000)."""
    n = int(os.environ.get("AAR_TEST_SLOWLORIS_N", "2000"))
    nofile = 512
    header_timeout_s = seconds(config_value("client_header_timeout"))
    ctx = multiprocessing.get_context("spawn")
    out = ctx.Queue()
    with run_stack(tmp_path, {"AAR_LOG_LEVEL": "info"}, nofile=nofile) as st:
        logs = (st.app_log, st.nginx_log)
        size0 = [log.stat().st_size for log in logs]
        with LatencyProbe(st.proxy_port, period_s=0.1) as probe:
            with PeakSampler(lambda: _open_fds(st.app_pid)) as fds:
                attackers = [
                    ctx.Process(
                        target=_slowloris,
                        args=(st.proxy_port, src, n, header_timeout_s + 3, out),
                    )
                    for src in ("127.0.0.2", "127.0.0.3")
                ]
                for a in attackers:
                    a.start()
                results = [out.get(timeout=300) for _ in attackers]
                for a in attackers:
                    a.join(timeout=30)
        growth = [log.stat().st_size - s0 for log, s0 in zip(logs, size0, strict=True)]
        reached = [
            ln
            for ln in st.app_log.read_text(errors="replace").splitlines()
            if "127.0.0.2:" in ln or "127.0.0.3:" in ln
        ]
    print(
        f"slowloris 2 x {n} through the proxy (service's fd limit {nofile}): (opened, still "
        f"open) {results}; healthz p99 {probe.p99() * 1e3:.0f} ms, max "
        f"{max(probe.latencies) * 1e3:.0f} ms over {len(probe.latencies)} probes; the "
        f"service's descriptors {fds.first:.0f} → peak {fds.peak:.0f}; logs +"
        f"{growth[0] / 1e3:.1f} kB (service), +{growth[1] / 1e3:.1f} kB (proxy)"
    )
    assert not probe.failures, probe.failures
    assert max(probe.latencies) < 1.0
    assert sum(r[0] for r in results) >= 2 * nofile  # many times the service's limit
    assert [r[1] for r in results] == [0, 0]  # the proxy closed every one at its deadline
    assert not reached, reached[:3]  # none reached the service
    assert fds.peak < nofile / 4
    assert max(growth) <= MB
