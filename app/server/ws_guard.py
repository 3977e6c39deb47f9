"""WebSocket limits in the ASGI layer: connections at once, message sizes and rates per route.

A pure-ASGI middleware, so the app carries it however it is served (``aar-dock serve``, plain
uvicorn, in-process test clients). uvicorn's own ``ws_max_size`` (``aar-dock serve`` sets it
per listener, :mod:`app.server.server_limits`) refuses an oversized message at its frame
header, before its payload is buffered; this guard adds, per route:

* at most ``AAR_MAX_WEBSOCKETS`` WebSockets at once (else the handshake is answered ``503``)
  and ``AAR_MAX_WEBSOCKETS_PER_CLIENT`` from one client address (else ``429``);
* a message above the route's limit (push: ``AAR_PUSH_MAX_MB``; every other WebSocket:
  ``AAR_WS_MAX_MESSAGE_KB``) closes the connection with 1009 and its reason;
* more than ``AAR_WS_MESSAGE_BURST`` messages, refilled at ``AAR_WS_MAX_MESSAGES_PER_S`` (push:
  ``AAR_PUSH_MAX_MESSAGES_PER_S``, burst a fifth of it), closes it with 1008;
* after either, that address's handshakes are refused (``429``) for ``AAR_WS_ABUSE_PENALTY_S``.

The client address is the one uvicorn puts in the scope: behind the proxy, the client's own
(``X-Forwarded-For`` from the addresses in ``FORWARDED_ALLOW_IPS``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.server.security import deny_websocket
from app.service import guard_events
from app.service.settings import Settings


@dataclass(frozen=True)
class RoutePolicy:
    """One route's WebSocket limits."""

    max_bytes: int
    size_setting: str
    rate_per_s: float
    burst: int


class TokenBucket:
    """``burst`` messages at once, refilled at ``rate_per_s``."""

    def __init__(self, rate_per_s: float, burst: int) -> None:
        self.rate_per_s, self.burst = rate_per_s, burst
        self.tokens = float(burst)
        self.t = time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        self.tokens = min(float(self.burst), self.tokens + (now - self.t) * self.rate_per_s)
        self.t = now
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


class WebSocketGuard:
    def __init__(self, app: ASGIApp, *, settings: Settings, push_path: str) -> None:
        self.app = app
        self.settings = settings
        self.push_path = push_path
        self.open = 0
        self.per_client: dict[str, int] = {}
        self.penalized: dict[str, float] = {}  # address → until (monotonic)

    def policy(self, path: str) -> RoutePolicy:
        s = self.settings
        if path.rstrip("/") == self.push_path:
            rate = s.push_max_messages_per_s
            burst = max(s.ws_message_burst, int(rate / 5))
            return RoutePolicy(s.push_limit_bytes, "AAR_PUSH_MAX_MB", rate, burst)
        return RoutePolicy(
            s.ws_message_limit_bytes,
            "AAR_WS_MAX_MESSAGE_KB",
            s.ws_max_messages_per_s,
            s.ws_message_burst,
        )

    def penalize(self, client: str) -> None:
        penalty = self.settings.ws_abuse_penalty_s
        if penalty <= 0:
            return
        now = time.monotonic()
        if len(self.penalized) > 10_000:  # bounded: forget the expired ones
            self.penalized = {k: v for k, v in self.penalized.items() if v > now}
        self.penalized[client] = now + penalty

    def is_penalized(self, client: str) -> bool:
        until = self.penalized.get(client)
        if until is None:
            return False
        if time.monotonic() < until:
            return True
        del self.penalized[client]
        return False

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "websocket":
            await self.app(scope, receive, send)
            return
        s = self.settings
        client = str((scope.get("client") or ("unknown", 0))[0])
        refusal = None
        if self.is_penalized(client):
            refusal = (
                "ws_refused_penalty",
                429,
                "WebSocket refused: this address broke a message limit (AAR_WS_ABUSE_PENALTY_S)",
            )
        elif self.open >= s.max_websockets:
            refusal = (
                "ws_refused_total",
                503,
                "too many WebSocket connections (AAR_MAX_WEBSOCKETS)",
            )
        elif self.per_client.get(client, 0) >= s.max_websockets_per_client:
            refusal = (
                "ws_refused_per_client",
                429,
                "too many WebSocket connections from this address (AAR_MAX_WEBSOCKETS_PER_CLIENT)",
            )
        if refusal is not None:
            guard_events.count(refusal[0])
            await deny_websocket(scope, receive, send, refusal[1], refusal[2])
            return
        self.open += 1
        self.per_client[client] = self.per_client.get(client, 0) + 1
        try:
            await self._run(scope, receive, send, client)
        finally:
            self.open -= 1
            n = self.per_client[client] - 1
            if n:
                self.per_client[client] = n
            else:
                del self.per_client[client]

    async def _run(self, scope: Scope, receive: Receive, send: Send, client: str) -> None:
        route = self.policy(scope["path"])
        bucket = TokenBucket(route.rate_per_s, route.burst)
        closed = False

        async def close(code: int, reason: str, event: str) -> Message:
            nonlocal closed
            closed = True
            guard_events.count(event)
            self.penalize(client)
            await send({"type": "websocket.close", "code": code, "reason": reason})
            return {"type": "websocket.disconnect", "code": code}

        async def limited_receive() -> Message:
            message = await receive()
            if message["type"] != "websocket.receive" or closed:
                return message
            data = message.get("bytes")
            text = message.get("text")
            size = len(data) if data is not None else len(text or "")
            if size <= route.max_bytes and text is not None and 4 * size > route.max_bytes:
                size = len(text.encode())
            if size > route.max_bytes:
                reason = f"message over {route.max_bytes / 1e3:g} kB ({route.size_setting})"
                return await close(1009, reason, "ws_message_too_big")
            if not bucket.take():
                reason = (
                    f"more than {route.burst} messages at {route.rate_per_s:g}/s "
                    "(AAR_WS_MAX_MESSAGES_PER_S)"
                )
                return await close(1008, reason, "ws_message_rate")
            return message

        async def guarded_send(message: Message) -> None:
            if closed:
                return  # we closed the connection: the application's late sends go nowhere
            await send(message)

        await self.app(scope, limited_receive, guarded_send)
