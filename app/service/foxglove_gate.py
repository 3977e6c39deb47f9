"""The Foxglove port's gate: the service's access model in front of foxglove-sdk's server.

foxglove-sdk's WebSocket server (0.30) checks no ``Host``, ``Origin`` or token, caps no
connections and offers no hook at its handshake (its ``ServerListener`` hears only of
subscriptions, parameters and services, after a client is in). So the SDK server listens on a
loopback port of its own, TLS only with a certificate made at start
(:mod:`app.service.loopback_tls`: a browser page cannot open it), and the public Foxglove port
is this gate, a TCP relay in its own thread (its own event loop: a flood of connections on
this port costs the web server's loop nothing). For each connection it:

1. accepts it only while the address has fewer than ``AAR_FOXGLOVE_MAX_CLIENTS_PER_ADDRESS``
   and the gate fewer than ``AAR_FOXGLOVE_MAX_CLIENTS`` (handshakes included; capped at a
   sixth of the descriptor limit minus ``AAR_FD_RESERVE``: each relayed client holds three
   descriptors), and while the process is short of its descriptor limit; a refused connection
   is closed at once, a deferred one waits in the kernel's backlog;
2. reads the HTTP upgrade request (``h11``; at most 16 kB, within ``AAR_HEADER_TIMEOUT_S``)
   and answers, then closes:

   * ``400`` for a ``Host`` that is not a trusted host (``AAR_TRUSTED_HOSTS``, DNS rebinding),
   * ``403`` for an ``Origin`` that is not one of the service's own pages (a trusted host on
     the HTTP or viser port) nor listed in ``AAR_ALLOWED_ORIGINS`` /
     ``AAR_FOXGLOVE_ALLOWED_ORIGINS``; no ``Origin``: not a browser, accepted,
   * ``401`` without the token when ``AAR_TOKEN`` is set: ``Authorization: Bearer <token>`` or
     ``?token=<token>`` in the URL (Foxglove's *Open connection* can send only the URL),
   * ``426`` for anything that is not a WebSocket upgrade;
3. relays the request and both directions, byte for byte, to the SDK server.

Counts of what it refused: :meth:`FoxgloveGate.health` (``/healthz``) and
:mod:`app.service.guard_events` (``/metrics``, ``foxglove_<reason>``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import secrets
import socket
import ssl
import threading
import time
from dataclasses import dataclass, field
from http import HTTPStatus
from urllib.parse import parse_qs, urlsplit

import h11

from app.service import guard_events
from app.service.host_rules import host_matches, split_host, token_ok
from app.service.limits import fd_limit
from app.service.settings import Settings

log = logging.getLogger(__name__)
MAX_HEAD_BYTES = 16 * 1024
RELAY_CHUNK = 64 * 1024
FDS_PER_CLIENT = 3  # the client's socket, ours to the SDK server, the SDK server's end
_DEFAULT_PORT = {"http": 80, "https": 443}
FD_SLACK = 16  # descriptors left free besides the ones open when the gate looked
FD_RECOUNT_S = 1.0


class FdBudget:
    """Whether the process has descriptors to spare for one more accepted connection (its
    open descriptors, recounted at most once a second, against its limit)."""

    def __init__(self) -> None:
        self.limit = fd_limit()
        self._open = 0
        self._counted_at = -float("inf")

    def may_accept(self) -> bool:
        if self.limit is None:
            return True
        if time.monotonic() - self._counted_at > FD_RECOUNT_S:
            try:
                self._open = len(os.listdir("/proc/self/fd")) - 1  # the listing's own one
            except OSError:  # pragma: no cover - not Linux: trust the connection caps
                self.limit = None
                return True
            self._counted_at = time.monotonic()
        return self._open + FD_SLACK < self.limit


@dataclass(frozen=True)
class GatePolicy:
    """Who may open the Foxglove port, and how many at once."""

    token: str | None
    trusted_hosts: tuple[str, ...]
    allowed_origins: frozenset[str]  # normalised scheme://host[:port]; "*": any
    origin_ports: frozenset[int]  # the service's pages that may open it (HTTP, viser)
    max_clients: int
    max_per_address: int
    handshake_timeout_s: float

    @classmethod
    def from_settings(cls, settings: Settings) -> GatePolicy:
        limit = settings.foxglove_max_clients
        nofile = fd_limit()
        if nofile is not None:
            limit = max(1, min(limit, (nofile - settings.fd_reserve) // (2 * FDS_PER_CLIENT)))
        origins = [*settings.allowed_origins, *settings.foxglove_allowed_origins]
        ports = {settings.port}
        if settings.viser_enabled:
            ports.add(settings.viser_port)
        return cls(
            token=settings.token or None,
            trusted_hosts=tuple(settings.effective_trusted_hosts),
            allowed_origins=frozenset(o.strip().lower().rstrip("/") for o in origins if o.strip()),
            origin_ports=frozenset(ports),
            max_clients=limit,
            max_per_address=min(settings.foxglove_max_clients_per_address, limit),
            handshake_timeout_s=settings.header_timeout_s,
        )

    def origin_allowed(self, origin: str) -> bool:
        o = origin.strip().lower().rstrip("/")
        if "*" in self.allowed_origins or o in self.allowed_origins:
            return True
        try:
            parts = urlsplit(o)
            port = parts.port
        except ValueError:
            return False
        if parts.scheme not in _DEFAULT_PORT or not parts.hostname:
            return False  # "null" (sandboxed frames, file://) and other schemes
        port = port or _DEFAULT_PORT[parts.scheme]
        return host_matches(parts.hostname.rstrip("."), list(self.trusted_hosts)) and (
            port in self.origin_ports
        )

    def token_given(self, authorization: str | None, target: str) -> bool:
        if self.token is None:
            return True
        if token_ok(authorization, self.token):
            return True
        given = parse_qs(urlsplit(target).query).get("token", [])
        return len(given) == 1 and secrets.compare_digest(given[0].encode(), self.token.encode())


@dataclass(frozen=True)
class Refusal:
    """The answer to a handshake that may not pass: status, counter name, detail."""

    status: int
    reason: str
    detail: str


def check_handshake(policy: GatePolicy, request: h11.Request) -> Refusal | None:
    """Host, Origin, token and upgrade of one request (module docstring, step 2)."""
    values: dict[str, list[str]] = {}
    for raw_name, raw_value in request.headers:  # h11 gives the names lower-cased
        values.setdefault(raw_name.decode("latin-1"), []).append(raw_value.decode("latin-1"))
    for name in ("host", "origin", "authorization"):
        if len(values.get(name, [])) > 1:
            return Refusal(400, "bad_request", f"more than one {name} header")

    def first(name: str) -> str | None:
        found = values.get(name)
        return found[0] if found else None

    host = split_host(first("host") or "")
    if host is None or not host_matches(host[0], list(policy.trusted_hosts)):
        return Refusal(
            400, "host", "untrusted or missing Host header (AAR_TRUSTED_HOSTS if it is yours)"
        )
    origin = first("origin")
    if origin is not None and not policy.origin_allowed(origin):
        return Refusal(
            403,
            "origin",
            f"cross-origin connection from {origin[:100]!r} refused (AAR_FOXGLOVE_ALLOWED_ORIGINS)",
        )
    target = request.target.decode("latin-1")
    if not policy.token_given(first("authorization"), target):
        return Refusal(
            401, "token", "missing or wrong token: Authorization: Bearer, or ?token= in the URL"
        )
    if "websocket" not in (first("upgrade") or "").lower():
        return Refusal(426, "not_websocket", "this port speaks Foxglove's WebSocket protocol")
    return None


@dataclass(frozen=True)
class GateHealth:
    """The gate now: listening, clients relayed, handshakes in progress, refusals by reason."""

    running: bool
    port: int
    clients: int
    handshakes: int
    served: int
    refused: dict[str, int] = field(default_factory=dict)


def _response(refusal: Refusal) -> bytes:
    body = json.dumps({"detail": refusal.detail}).encode()
    phrase = HTTPStatus(refusal.status).phrase
    extra = "www-authenticate: Bearer\r\n" if refusal.status == 401 else ""
    head = (
        f"HTTP/1.1 {refusal.status} {phrase}\r\ncontent-type: application/json\r\n"
        f"content-length: {len(body)}\r\n{extra}connection: close\r\n\r\n"
    )
    return head.encode() + body


async def _read_request(reader: asyncio.StreamReader) -> tuple[bytes, h11.Request] | None:
    """The bytes received up to and past the request's head, and the request; None: the
    client closed first. ``h11.RemoteProtocolError``: malformed or over the size limit."""
    conn = h11.Connection(h11.SERVER, max_incomplete_event_size=MAX_HEAD_BYTES)
    received = bytearray()
    while True:
        event = conn.next_event()
        if isinstance(event, h11.Request):
            return bytes(received), event
        if event is not h11.NEED_DATA:
            return None
        chunk = await reader.read(4096)
        if not chunk:
            return None
        received += chunk
        conn.receive_data(chunk)


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    with contextlib.suppress(OSError, ConnectionError):
        while data := await reader.read(RELAY_CHUNK):
            writer.write(data)
            await writer.drain()


class FoxgloveGate:
    """The public Foxglove port, relaying admitted clients to ``127.0.0.1:upstream_port``."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        upstream_port: int,
        upstream_tls: ssl.SSLContext,
        policy: GatePolicy,
    ) -> None:
        self.policy = policy
        self.upstream_port = upstream_port
        self.upstream_tls = upstream_tls
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sock = socket.create_server((host.strip("[]"), port), family=family, backlog=128)
        self._sock.setblocking(False)
        self.port = int(self._sock.getsockname()[1])
        self._budget = FdBudget()
        self._lock = threading.Lock()
        self._refused: dict[str, int] = {}
        self._per_address: dict[str, int] = {}
        self._open = 0  # admitted connections: handshakes and relayed clients
        self._clients = 0
        self._served = 0
        self._last_accept_error = 0.0
        self._loop = asyncio.new_event_loop()
        self._main = self._loop.create_task(self._accept_loop())
        self._thread = threading.Thread(target=self._run, name="foxglove-gate", daemon=True)
        self._thread.start()

    # -- health ----------------------------------------------------------------------------
    def health(self) -> GateHealth:
        with self._lock:
            refused = dict(self._refused)
        return GateHealth(
            running=self._thread.is_alive() and not self._main.done(),
            port=self.port,
            clients=self._clients,
            handshakes=self._open - self._clients,
            served=self._served,
            refused=refused,
        )

    def _count(self, reason: str) -> None:
        with self._lock:
            self._refused[reason] = self._refused.get(reason, 0) + 1
        guard_events.count(f"foxglove_{reason}")

    # -- the loop ----------------------------------------------------------------------------
    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._main)
        except asyncio.CancelledError:
            pass
        except Exception:  # pragma: no cover - a bug: healthz shows the gate down
            log.exception("the Foxglove gate stopped")
        finally:
            tasks = asyncio.all_tasks(self._loop)
            for task in tasks:
                task.cancel()
            self._loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
            self._loop.close()
            self._sock.close()

    def close(self) -> None:
        """Stop accepting, drop every client, and wait for the thread (≤ 5 s)."""
        with contextlib.suppress(RuntimeError):  # the loop already closed
            self._loop.call_soon_threadsafe(self._main.cancel)
        self._thread.join(timeout=5)

    async def _accept_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            if not self._budget.may_accept():
                await asyncio.sleep(0.05)  # the backlog waits; descriptors come back
                continue
            try:
                conn, addr = await loop.sock_accept(self._sock)
            except OSError as exc:  # EMFILE/ENFILE (another part used them), ECONNABORTED
                self._count("accept_failed")
                now = time.monotonic()
                if now - self._last_accept_error > 60:
                    self._last_accept_error = now
                    log.warning("Foxglove port: accept failed (%s); retrying", exc)
                await asyncio.sleep(0.05)
                continue
            peer = str(addr[0]) if isinstance(addr, tuple) and addr else "unix"
            why = self._admit(peer)
            if why is not None:
                conn.close()
                self._count(why)
                continue
            loop.create_task(self._serve(conn, peer))

    def _admit(self, peer: str) -> str | None:
        if self._per_address.get(peer, 0) >= self.policy.max_per_address:
            return "per_address"
        if self._open >= self.policy.max_clients:
            return "total"
        self._per_address[peer] = self._per_address.get(peer, 0) + 1
        self._open += 1
        return None

    def _release(self, peer: str) -> None:
        self._open -= 1
        n = self._per_address.get(peer, 1) - 1
        if n > 0:
            self._per_address[peer] = n
        else:
            self._per_address.pop(peer, None)

    # -- one connection ----------------------------------------------------------------------
    async def _serve(self, conn: socket.socket, peer: str) -> None:
        try:
            reader, writer = await asyncio.open_connection(sock=conn)
        except OSError:
            conn.close()
            self._release(peer)
            return
        try:
            await self._handshake_and_relay(reader, writer)
        finally:
            writer.close()
            self._release(peer)

    async def _handshake_and_relay(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        try:
            got = await asyncio.wait_for(_read_request(reader), self.policy.handshake_timeout_s)
        except TimeoutError:
            self._count("handshake_timeout")
            return
        except h11.RemoteProtocolError:
            got = None
            await self._refuse(writer, Refusal(400, "bad_request", "malformed request"))
        except (OSError, ConnectionError):
            return
        if got is None:
            return
        head, request = got
        refusal = check_handshake(self.policy, request)
        if refusal is not None:
            await self._refuse(writer, refusal)
            return
        await self._relay(reader, writer, head)

    async def _refuse(self, writer: asyncio.StreamWriter, refusal: Refusal) -> None:
        self._count(refusal.reason)
        writer.write(_response(refusal))
        with contextlib.suppress(OSError, ConnectionError, TimeoutError):
            await asyncio.wait_for(writer.drain(), 1.0)

    async def _relay(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, head: bytes
    ) -> None:
        try:
            up_reader, up_writer = await asyncio.wait_for(
                asyncio.open_connection("127.0.0.1", self.upstream_port, ssl=self.upstream_tls),
                self.policy.handshake_timeout_s,
            )
        except (OSError, TimeoutError, ssl.SSLError):
            await self._refuse(writer, Refusal(502, "upstream", "the Foxglove server is down"))
            return
        self._clients += 1
        self._served += 1
        try:
            up_writer.write(head)
            tasks = {
                asyncio.create_task(_pipe(reader, up_writer)),
                asyncio.create_task(_pipe(up_reader, writer)),
            }
            try:
                await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for task in tasks:
                    task.cancel()
                await asyncio.gather(*tasks, return_exceptions=True)
        finally:
            self._clients -= 1
            up_writer.close()
