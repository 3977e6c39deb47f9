"""Connection limits in uvicorn's protocol layer: what the ASGI app never sees.

uvicorn (``aar-dock serve``) gets the two protocol classes :func:`protocol_classes` builds:

* HTTP (h11): every connection is registered on ``connection_made``. Above
  ``AAR_MAX_CONNECTIONS`` (capped at the file-descriptor limit minus ``AAR_FD_RESERVE``), the
  *oldest connection still waiting for request headers* is closed to make room; if there is
  none, the new connection is closed at once. A connection from an address that already has
  ``AAR_MAX_CONNECTIONS_PER_CLIENT`` is closed in ``accept`` (:class:`GuardedListener`), before
  any transport or protocol is made for it. A connection that has not sent a request's
  headers ``AAR_HEADER_TIMEOUT_S`` after it opened (or after its previous response) is closed
  (slowloris). So the service never runs out of file descriptors (``accept()`` keeps working)
  and a client that sends its request promptly is answered.
* WebSocket: the largest message is set per route *before* any frame is read
  (``/api/v1/stream/push``: ``AAR_PUSH_MAX_MB``; every other route: ``AAR_WS_MAX_MESSAGE_KB``):
  a frame header announcing more is answered with close 1009 without buffering its payload.
  A client that sends more than ``AAR_WS_MESSAGE_BURST`` messages, refilled at
  ``AAR_WS_MAX_MESSAGES_PER_S`` (push route: ``AAR_PUSH_MAX_MESSAGES_PER_S``), is closed with
  1008 at once: input is parsed 1 kB at a time (but on the push route) and the rest of a
  flood is dropped unparsed. An address closed for its rate or a message size gets ``429`` on
  its WebSocket handshakes for ``AAR_WS_ABUSE_PENALTY_S`` (reconnecting floods cost an HTTP
  parse each, not a handshake and a burst).

The listening socket (:class:`GuardedListener`) stops accepting while the process is a few
descriptors short of its limit (the connections refused above close within a loop iteration
or two, freeing theirs): asyncio's accept loop, which retried ``accept()`` up to the backlog
(2048) times per wake-up at EMFILE and logged each failure with a traceback, never meets it.

Counts of what was refused: :mod:`app.server.guard_events` (``/metrics``).

The guards live in the server, not in the ASGI app: ``aar-dock serve`` records them on the
app (:func:`mark_guarded`). Served without them (plain ``uvicorn --factory``), the app logs
:data:`UNGUARDED` at the first request from a real client, and ``/healthz`` says
``degraded`` (component ``connection_guard``) to every real client.
"""

from __future__ import annotations

import asyncio
import logging
import os
import resource
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

from app.server import guard_events
from app.server.settings import Settings

log = logging.getLogger(__name__)
SLICE_BYTES = 1024  # WebSocket input (but the push route's) parsed this much at a time


def fd_limit() -> int | None:
    """The soft ``RLIMIT_NOFILE`` of this process (None: unlimited or unknown)."""
    try:
        soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    except (OSError, ValueError):  # pragma: no cover - not on Linux/macOS
        return None
    return None if soft == resource.RLIM_INFINITY else int(soft)


@dataclass(frozen=True)
class TokenBucketPolicy:
    rate_per_s: float
    burst: int


class TokenBucket:
    """``burst`` messages at once, refilled at ``rate_per_s``."""

    def __init__(self, policy: TokenBucketPolicy) -> None:
        self.policy = policy
        self.tokens = float(policy.burst)
        self.t = time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        p = self.policy
        self.tokens = min(float(p.burst), self.tokens + (now - self.t) * p.rate_per_s)
        self.t = now
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


@dataclass(frozen=True)
class ConnectionPolicy:
    max_connections: int
    max_per_client: int
    header_timeout_s: float
    push_path: str
    push_max_bytes: int
    ws_max_bytes: int
    push_rate: TokenBucketPolicy
    ws_rate: TokenBucketPolicy
    abuse_penalty_s: float

    @classmethod
    def from_settings(cls, settings: Settings, push_path: str) -> ConnectionPolicy:
        limit = settings.max_connections
        nofile = fd_limit()
        if nofile is not None:
            limit = max(8, min(limit, nofile - settings.fd_reserve))
        return cls(
            max_connections=limit,
            max_per_client=min(settings.max_connections_per_client, limit),
            header_timeout_s=settings.header_timeout_s,
            push_path=push_path,
            push_max_bytes=settings.push_limit_bytes,
            ws_max_bytes=settings.ws_message_limit_bytes,
            push_rate=TokenBucketPolicy(
                settings.push_max_messages_per_s,
                max(settings.ws_message_burst, int(settings.push_max_messages_per_s / 5)),
            ),
            ws_rate=TokenBucketPolicy(settings.ws_max_messages_per_s, settings.ws_message_burst),
            abuse_penalty_s=settings.ws_abuse_penalty_s,
        )

    def max_message_bytes(self, path: str) -> int:
        return self.push_max_bytes if path.rstrip("/") == self.push_path else self.ws_max_bytes

    def message_rate(self, path: str) -> TokenBucketPolicy:
        return self.push_rate if path.rstrip("/") == self.push_path else self.ws_rate


@dataclass(eq=False)
class _Entry:
    client: str
    protocol: Any  # the H11 or WebSocket protocol that owns the transport now
    path: str = ""


@dataclass
class ConnectionRegistry:
    """The open connections; the ones waiting for request headers, oldest first."""

    policy: ConnectionPolicy
    entries: dict[Any, _Entry] = field(default_factory=dict)
    per_client: dict[str, int] = field(default_factory=dict)
    waiting: dict[Any, _Entry] = field(default_factory=dict)  # insertion order = age
    waiting_by_client: dict[str, dict[Any, _Entry]] = field(default_factory=dict)
    penalized: dict[str, float] = field(default_factory=dict)  # address → until (monotonic)

    def penalize(self, client: str) -> None:
        """``client`` broke a WebSocket limit: refuse its handshakes for a while."""
        if self.policy.abuse_penalty_s > 0:
            if len(self.penalized) > 10_000:  # bounded: forget the expired ones
                now = time.monotonic()
                self.penalized = {k: v for k, v in self.penalized.items() if v > now}
            self.penalized[client] = time.monotonic() + self.policy.abuse_penalty_s

    def is_penalized(self, client: str) -> bool:
        until = self.penalized.get(client)
        if until is None:
            return False
        if time.monotonic() < until:
            return True
        del self.penalized[client]
        return False

    def admit(self, transport: Any, client: str, protocol: Any) -> bool:
        """Register a new connection, evicting a waiting one if a cap is reached; False: refuse."""
        p = self.policy
        if self.per_client.get(client, 0) >= p.max_per_client:
            if not self._evict_oldest(self.waiting_by_client.get(client, {}), "per_client"):
                guard_events.count("connection_refused_per_client")
                return False
        if len(self.entries) >= p.max_connections:
            if not self._evict_oldest(self.waiting, "total"):
                guard_events.count("connection_refused_total")
                return False
        entry = _Entry(client, protocol)
        self.entries[transport] = entry
        self.per_client[client] = self.per_client.get(client, 0) + 1
        self.set_waiting(transport, True)
        return True

    def _evict_oldest(self, pool: dict[Any, _Entry], why: str) -> bool:
        if not pool:
            return False
        transport = next(iter(pool))
        entry = self.entries.get(transport)
        self.remove(transport)
        guard_events.count(f"connection_evicted_{why}")
        if entry is not None:
            entry.protocol.evict()
        return True

    def set_waiting(self, transport: Any, waiting: bool) -> None:
        entry = self.entries.get(transport)
        if entry is None:
            return
        mine = self.waiting_by_client.setdefault(entry.client, {})
        self.waiting.pop(transport, None)
        mine.pop(transport, None)
        if waiting:
            self.waiting[transport] = entry
            mine[transport] = entry
        elif not mine:
            self.waiting_by_client.pop(entry.client, None)

    def handover(self, transport: Any, protocol: Any) -> str:
        """The connection became a WebSocket owned by ``protocol``; its request path."""
        entry = self.entries.get(transport)
        if entry is None:
            return ""
        self.set_waiting(transport, False)
        entry.protocol = protocol
        return entry.path

    def remove(self, transport: Any) -> None:
        entry = self.entries.pop(transport, None)
        if entry is None:
            return
        self.set_waiting(transport, False)
        self.waiting.pop(transport, None)
        n = self.per_client.get(entry.client, 1) - 1
        if n > 0:
            self.per_client[entry.client] = n
        else:
            self.per_client.pop(entry.client, None)
        bucket = self.waiting_by_client.get(entry.client)
        if bucket is not None:
            bucket.pop(transport, None)
            if not bucket:
                self.waiting_by_client.pop(entry.client, None)


def _peer(transport: Any) -> str:
    peer = transport.get_extra_info("peername")
    if isinstance(peer, tuple | list) and peer:
        return str(peer[0])
    return str(peer or "unix")


def new_registry(settings: Settings, push_path: str) -> ConnectionRegistry:
    """One per server: shared by :func:`protocol_classes` and :func:`guarded_listener`."""
    return ConnectionRegistry(ConnectionPolicy.from_settings(settings, push_path))


def protocol_classes(registry: ConnectionRegistry) -> tuple[type[Any], type[Any]]:
    """The HTTP and WebSocket protocol classes for ``uvicorn.Config(http=..., ws=...)``."""

    class GuardedH11Protocol(H11Protocol):
        guard = registry

        def connection_made(self, transport: asyncio.BaseTransport) -> None:  # type: ignore[override]
            self._refused = False
            self._header_timer: asyncio.TimerHandle | None = None
            if not registry.admit(transport, _peer(transport), self):
                self._refused = True
                transport.abort()  # type: ignore[attr-defined]
                return
            super().connection_made(transport)  # type: ignore[arg-type]
            self._arm_header_timer()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm_header_timer()
            if self._refused:
                return
            registry.remove(self.transport)
            super().connection_lost(exc)

        def evict(self) -> None:
            self._disarm_header_timer()
            if self.transport is not None and not self.transport.is_closing():
                self.transport.abort()

        def _arm_header_timer(self) -> None:
            self._disarm_header_timer()
            self._header_timer = self.loop.call_later(
                registry.policy.header_timeout_s, self._header_timeout
            )

        def _disarm_header_timer(self) -> None:
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _header_timeout(self) -> None:
            self._header_timer = None
            if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
                guard_events.count("header_timeout")
                registry.remove(self.transport)
                self.transport.abort()

        def handle_events(self) -> None:
            super().handle_events()
            if self.transport is None or self.transport.get_protocol() is not self:
                return  # upgraded to a WebSocket: that protocol owns the registry entry now
            if self.conn.their_state is not h11.IDLE:  # a request's headers arrived
                self._disarm_header_timer()
                registry.set_waiting(self.transport, False)

        def handle_websocket_upgrade(self, event: h11.Request) -> None:
            self._disarm_header_timer()
            entry = registry.entries.get(self.transport)
            if entry is not None:
                if registry.is_penalized(entry.client):
                    guard_events.count("ws_refused_penalty")
                    self._refuse_upgrade()
                    return
                entry.path = self.scope["path"]
            super().handle_websocket_upgrade(event)

        def _refuse_upgrade(self) -> None:
            body = (
                b'{"detail": "WebSocket refused: this address broke a message limit '
                b'(AAR_WS_ABUSE_PENALTY_S)"}'
            )
            headers = [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"retry-after", str(max(1, round(registry.policy.abuse_penalty_s))).encode()),
                (b"connection", b"close"),
            ]
            out = self.conn.send(h11.Response(status_code=429, headers=headers))
            out += self.conn.send(h11.Data(data=body)) or b""
            out += self.conn.send(h11.EndOfMessage()) or b""
            self.transport.write(out or b"")
            self.transport.close()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing() and self.conn.their_state is h11.IDLE:
                registry.set_waiting(self.transport, True)  # idle keep-alive: evictable
                self._arm_header_timer()

    class GuardedWebSocketProtocol(WebSocketsSansIOProtocol):
        guard = registry

        def connection_made(self, transport: asyncio.BaseTransport) -> None:
            super().connection_made(transport)
            path = registry.handover(transport, self)
            self._over_rate = False
            self._slice = 0 if path.rstrip("/") == registry.policy.push_path else SLICE_BYTES
            self._peer = _peer(transport)
            self._bucket = TokenBucket(registry.policy.message_rate(path))
            # before the first frame is parsed (it may be in the same packet as the request)
            self.conn.max_message_size = registry.policy.max_message_bytes(path)

        def connection_lost(self, exc: Exception | None) -> None:
            registry.remove(self.transport)
            super().connection_lost(exc)

        def data_received(self, data: bytes) -> None:
            # in slices: a chunk of tiny frames is parsed a slice at a time, and the rest is
            # dropped once the client is over its message rate (or closed)
            if not self._slice:
                super().data_received(data)
                return
            for i in range(0, len(data), self._slice):
                if self._over_rate or self.transport.is_closing():
                    return
                super().data_received(data[i : i + self._slice])

        def evict(self) -> None:  # pragma: no cover - WebSockets are never waiting
            self.transport.abort()

        def handle_parser_exception(self) -> None:
            close = self.conn.close_sent
            if close is not None and close.code == 1009:
                guard_events.count("ws_message_too_big")
                registry.penalize(self._peer)
            super().handle_parser_exception()

        def send_receive_event_to_app(self) -> None:
            if self._over_rate:
                self.frames = []
                return
            if not self._bucket.take():
                self._over_rate = True
                self.frames = []
                guard_events.count("ws_message_rate")
                registry.penalize(self._peer)
                reason = (
                    f"more than {self._bucket.policy.burst} messages at "
                    f"{self._bucket.policy.rate_per_s:g}/s (AAR_WS_MAX_MESSAGES_PER_S)"
                )
                self.conn.fail(1008, reason)
                self.queue.put_nowait({"type": "websocket.disconnect", "code": 1008})
                self.transport.write(b"".join(self.conn.data_to_send()))
                self.close_sent = True
                self.transport.close()
                return
            super().send_receive_event_to_app()

    return GuardedH11Protocol, GuardedWebSocketProtocol


# ---- whether the app runs behind them ------------------------------------------------------
UNGUARDED = (
    "this service was started without the connection guards of `aar-dock serve` (plain "
    "uvicorn or another ASGI server?): no connection caps, no header timeout (slowloris), no "
    "per-route WebSocket message limits. Run it with `aar-dock serve` (docs/service.md)"
)


def mark_guarded(app: Any, registry: ConnectionRegistry) -> None:
    """Record on the app (``app.state.connection_guard``) that its server runs the guards."""
    app.state.connection_guard = registry


def is_guarded(app: Any) -> bool:
    """True if :func:`mark_guarded` was called on ``app`` (``aar-dock serve`` does)."""
    state = getattr(app, "state", None)
    return getattr(state, "connection_guard", None) is not None


# ---- the listening socket ------------------------------------------------------------------
FD_SLACK = 16  # descriptors the listener leaves free besides the ones open when it looked
FD_RECOUNT_S = 1.0


class FdBudget:
    """Accepted sockets still open, against what the process's descriptor limit leaves."""

    def __init__(self) -> None:
        self.open = 0
        self._lock = threading.Lock()
        self._others = 0  # descriptors that are not accepted sockets (files, pipes, viser)
        self._counted_at = -float("inf")
        self.limit = fd_limit()

    def _recount(self) -> None:
        try:
            total = len(os.listdir("/proc/self/fd")) - 1  # the listing's own descriptor
        except OSError:  # pragma: no cover - not Linux: trust the connection caps
            self.limit = None
            return
        self._others = max(0, total - self.open)
        self._counted_at = time.monotonic()

    def may_accept(self) -> bool:
        if self.limit is None:
            return True
        if time.monotonic() - self._counted_at > FD_RECOUNT_S:
            self._recount()
        return self.open + self._others + FD_SLACK < self.limit

    def opened(self) -> None:
        with self._lock:
            self.open += 1

    def closed(self) -> None:
        with self._lock:
            self.open -= 1


class CountedSocket(socket.socket):
    """An accepted connection; its ``close`` gives its descriptor back to the budget."""

    def __init__(self, *args: Any, budget: FdBudget | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)  # (``dup()`` makes one without a budget)
        self._budget = budget
        if budget is not None:
            budget.opened()

    def close(self) -> None:
        budget, self._budget = self._budget, None
        if budget is not None:
            budget.closed()
        super().close()


MAX_REFUSALS_PER_ACCEPT = 256  # then the event loop gets its turn


class GuardedListener(socket.socket):
    """The server's listening socket. ``accept`` closes at once (no transport, no protocol:
    microseconds) a connection from an address already at ``AAR_MAX_CONNECTIONS_PER_CLIENT``,
    and says "nothing pending" (``BlockingIOError``: asyncio tries again on the next loop
    iteration) while the descriptor budget is spent."""

    def __init__(
        self,
        *args: Any,
        budget: FdBudget | None = None,
        registry: ConnectionRegistry | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(*args, **kwargs)
        self.budget = budget or FdBudget()
        self.registry = registry

    def accept(self) -> tuple[socket.socket, Any]:
        if self.registry is None:  # a dup(): a plain listening socket
            return super().accept()
        cap = self.registry.policy.max_per_client
        for _ in range(MAX_REFUSALS_PER_ACCEPT):
            if not self.budget.may_accept():
                guard_events.count("accept_deferred_fd_limit")
                raise BlockingIOError("the process is at its file-descriptor budget")
            conn, addr = super().accept()
            client = str(addr[0]) if isinstance(addr, tuple) and addr else "unix"
            if self.registry.per_client.get(client, 0) >= cap:
                conn.close()
                guard_events.count("connection_refused_per_client")
                continue
            counted = CountedSocket(
                conn.family, conn.type, conn.proto, fileno=conn.detach(), budget=self.budget
            )
            return counted, addr
        raise BlockingIOError("refused connections: the event loop's turn")


def guarded_listener(sock: socket.socket, registry: ConnectionRegistry) -> GuardedListener:
    """``sock`` (bound, e.g. by ``uvicorn.Config.bind_socket``) as a :class:`GuardedListener`."""
    return GuardedListener(
        sock.family, sock.type, sock.proto, fileno=sock.detach(), registry=registry
    )
