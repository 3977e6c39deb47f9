"""WebSocket limits in the ASGI layer: connections at once, and message sizes per route.

A pure-ASGI middleware (in-process servers and tests see it too; ``aar-dock serve`` adds the
frame-level limits of :mod:`app.server.connection_guard` before any payload is buffered):

* at most ``AAR_MAX_WEBSOCKETS`` WebSockets at once (else the handshake is answered ``503``)
  and ``AAR_MAX_WEBSOCKETS_PER_CLIENT`` from one client address (else ``429``);
* a message above the route's limit (push: ``AAR_PUSH_MAX_MB``; every other WebSocket:
  ``AAR_WS_MAX_MESSAGE_KB``) closes the connection with 1009 and its reason.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.server import guard_events
from app.server.security import deny_websocket
from app.server.settings import Settings


class WebSocketGuard:
    def __init__(self, app: ASGIApp, *, settings: Settings, push_path: str) -> None:
        self.app = app
        self.settings = settings
        self.push_path = push_path
        self.open = 0
        self.per_client: dict[str, int] = {}

    def _limit(self, path: str) -> tuple[int, str]:
        if path.rstrip("/") == self.push_path:
            return self.settings.push_limit_bytes, "AAR_PUSH_MAX_MB"
        return self.settings.ws_message_limit_bytes, "AAR_WS_MAX_MESSAGE_KB"

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "websocket":
            await self.app(scope, receive, send)
            return
        s = self.settings
        client = str((scope.get("client") or ("unknown", 0))[0])
        if self.open >= s.max_websockets:
            guard_events.count("ws_refused_total")
            await deny_websocket(
                scope, receive, send, 503, "too many WebSocket connections (AAR_MAX_WEBSOCKETS)"
            )
            return
        if self.per_client.get(client, 0) >= s.max_websockets_per_client:
            guard_events.count("ws_refused_per_client")
            await deny_websocket(
                scope,
                receive,
                send,
                429,
                "too many WebSocket connections from this address (AAR_MAX_WEBSOCKETS_PER_CLIENT)",
            )
            return
        self.open += 1
        self.per_client[client] = self.per_client.get(client, 0) + 1
        try:
            await self._run(scope, receive, send)
        finally:
            self.open -= 1
            n = self.per_client[client] - 1
            if n:
                self.per_client[client] = n
            else:
                del self.per_client[client]

    async def _run(self, scope: Scope, receive: Receive, send: Send) -> None:
        limit, setting = self._limit(scope["path"])
        closed = False

        async def limited_receive() -> Message:
            nonlocal closed
            message = await receive()
            if message["type"] != "websocket.receive" or closed:
                return message
            data = message.get("bytes")
            text = message.get("text")
            size = len(data) if data is not None else len(text or "")
            if size <= limit and text is not None and 4 * size > limit:
                size = len(text.encode())
            if size > limit:
                closed = True
                guard_events.count("ws_message_too_big")
                await send(
                    {
                        "type": "websocket.close",
                        "code": 1009,
                        "reason": f"message over {limit / 1e3:g} kB ({setting})",
                    }
                )
                return {"type": "websocket.disconnect", "code": 1009}
            return message

        async def guarded_send(message: Message) -> None:
            if closed:
                return  # we closed the connection: the application's late sends go nowhere
            await send(message)

        await self.app(scope, limited_receive, guarded_send)
