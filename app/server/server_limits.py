"""The limits ``aar-dock serve`` hands uvicorn (its own, documented settings), and whether the
app runs under them.

uvicorn enforces: connections and in-flight tasks at once (``limit_concurrency``: a request
beyond them is answered ``503``), pending connections (``backlog``), idle keep-alive
(``timeout_keep_alive``), a request head's size (``h11_max_incomplete_event_size``) and a
WebSocket message's size at its frame header (``ws_max_size``), and reads a WebSocket's next
message only once the app took the previous ones (``ws="websockets"``, ``ws_max_queue``: below).
What no Python server offers
(a deadline for a request's head against slowloris, connection caps and request rates per
client address) is the reverse proxy's: ``deploy/nginx/nginx.conf.template``, docs/service.md
"Behind the proxy".

``aar-dock serve`` records on the app that it runs with these limits (:func:`mark_guarded`).
Served without them (plain ``uvicorn --factory``), the app logs :data:`UNGUARDED` at the first
request from a real client, and ``/healthz`` says ``degraded`` (component
``server_limits``) to every real client.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol

from app.service.limits import fd_limit

if TYPE_CHECKING:
    from app.service.settings import Settings

MAX_HEADER_BYTES = 16 * 1024  # a request's head (h11_max_incomplete_event_size)
WS_FRAME_OVERHEAD_BYTES = 4096  # above a route's largest message, for the frame

# uvicorn's WebSocket implementation with backpressure through the closing handshake (measured:
# tests/server/test_ws_guard.py, the flood of tiny messages). With "websockets" (the websockets
# library's protocol) a connection's frames are parsed only while fewer than ``ws_max_queue``
# messages wait for the app; once the app stopped receiving (it closed the connection: 1008,
# 1009) nothing more is parsed and the kernel's buffers push back on the sender until the close
# timeout ends it. The default "websockets-sansio" (and "wsproto") resume reading when the app
# sends its close and parse, then drop, whatever the peer sends for 10 s: 20 clients flooding
# one-byte messages held the event loop ≈ 1 s at a time (healthz p99 1.03 s; with this one
# 42 ms). uvicorn 0.55 marks "websockets" deprecated (it is to point at "websockets-sansio" in a
# later release; websockets keeps its legacy protocol until ≈ 2030): the pins in pyproject.toml
# and the flood test guard the choice (docs/development.md, "Moving the pins").
WsImplementation = Literal["websockets", "websockets-sansio", "wsproto"]
WS_IMPLEMENTATION: WsImplementation = "websockets"
WS_MAX_QUEUE = 1  # messages read ahead of the app, per connection (uvicorn's default: 32)


def connection_cap(settings: Settings) -> int:
    """``AAR_MAX_CONNECTIONS``, at most the descriptor limit minus ``AAR_FD_RESERVE``."""
    cap = settings.max_connections
    nofile = fd_limit()
    if nofile is not None:
        cap = max(8, min(cap, nofile - settings.fd_reserve))
    return cap


@dataclass(frozen=True)
class ServerLimits:
    """uvicorn's own limits, as ``aar-dock serve`` passes them (``uvicorn.Config``)."""

    limit_concurrency: int  # connections or in-flight tasks; a request beyond them gets 503
    backlog: int  # connections the kernel queues before uvicorn accepts them
    timeout_keep_alive_s: int  # idle keep-alive (AAR_KEEP_ALIVE_S)
    ws_max_size_bytes: int  # the largest WebSocket message of the routes this listener serves
    h11_max_incomplete_event_size_bytes: int  # a request's head
    ws_implementation: (
        WsImplementation  # uvicorn's ``ws``: the one with backpressure (WS_IMPLEMENTATION)
    )
    ws_max_queue: int  # WebSocket messages read ahead of the app (WS_MAX_QUEUE)


def server_limits(settings: Settings, *, push_listener: bool = True) -> ServerLimits:
    """The limits of one listener; ``push_listener``: it serves the push route (its messages
    are stereo pairs, ``AAR_PUSH_MAX_MB``), else only WebSockets of ``AAR_WS_MAX_MESSAGE_KB``."""
    cap = connection_cap(settings)
    ws_bytes = settings.push_limit_bytes if push_listener else settings.ws_message_limit_bytes
    return ServerLimits(
        limit_concurrency=cap,
        backlog=min(2048, cap),
        timeout_keep_alive_s=max(1, round(settings.keep_alive_s)),
        ws_max_size_bytes=ws_bytes + WS_FRAME_OVERHEAD_BYTES,
        h11_max_incomplete_event_size_bytes=MAX_HEADER_BYTES,
        ws_implementation=WS_IMPLEMENTATION,
        ws_max_queue=WS_MAX_QUEUE,
    )


# ---- whether the app runs under them -------------------------------------------------------
UNGUARDED = (
    "this service was started without the server limits of `aar-dock serve` (plain uvicorn "
    "or another ASGI server?): no connection cap, no per-listener WebSocket message limit. "
    "Run it with `aar-dock serve`, behind the proxy where it is exposed (docs/service.md)"
)


class _GuardState(Protocol):
    server_limits: ServerLimits | None


class GuardedApp(Protocol):
    """An application with a ``state`` namespace (Starlette's and FastAPI's ``app.state``)."""

    @property
    def state(self) -> _GuardState: ...


def mark_guarded(app: GuardedApp, limits: ServerLimits) -> None:
    """Record on the app (``app.state.server_limits``) the limits its server runs with."""
    app.state.server_limits = limits


def is_guarded(app: object) -> bool:
    """True if :func:`mark_guarded` was called on ``app`` (``aar-dock serve`` does)."""
    state = getattr(app, "state", None)
    return getattr(state, "server_limits", None) is not None
