"""Request guard: a pure-ASGI middleware that decides on the headers, before any body is read.

In this order, for every HTTP request and WebSocket handshake:

1. **Host** must be a trusted host (``AAR_TRUSTED_HOSTS``; default localhost, 127.0.0.1, ::1
   and the bind host) → else ``400`` (DNS rebinding: a page on ``evil.example`` re-pointed at
   127.0.0.1 still sends ``Host: evil.example``).
2. **Origin**: mutating requests (POST/PUT/PATCH/DELETE) and WebSocket handshakes that carry
   an ``Origin`` must be same-origin (Origin host:port = Host) or listed in
   ``AAR_ALLOWED_ORIGINS`` → else ``403`` (cross-site requests; no Origin = curl/scripts: ok).
3. **Token**: mutating requests under ``/api/`` need ``Authorization: Bearer <AAR_TOKEN>``
   when a token is configured → else ``401`` without reading the body. The routes keep their
   ``require_token`` dependency as well (defence in depth).
4. **Size**: a declared ``Content-Length`` above the route's limit → ``413`` at once; bodies
   without one (chunked) are counted as they stream and answered ``413`` as soon as the count
   passes the limit (the application gets ``http.disconnect`` and its own answer is dropped).
5. **Concurrency**: ``POST /stereo`` and ``POST /calibration/checkerboard`` take a slot of a
   non-blocking semaphore → ``429`` with ``Retry-After`` when all are taken.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.server.server_limits import UNGUARDED, is_guarded
from app.service.host_rules import (
    host_matches,
    normalise_origins,
    origin_matches,
    split_host,
    token_ok,
)
from app.service.limits import ConcurrencyLimit
from app.service.settings import Settings

if TYPE_CHECKING:
    from starlette.applications import Starlette

log = logging.getLogger(__name__)

MUTATING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
# Starlette's TestClient and schemathesis' ASGI client talk to the app in-process with
# ``Host: testserver``, client "testclient" and server "testserver" in the ASGI scope. A real
# server puts socket addresses there (IPs), and a client behind uvicorn's proxy-header
# support that claims "testclient" in X-Forwarded-For is refused too: ``Host: testserver`` is
# accepted in-process only, so the tests need no settings and the network gains nothing.
IN_PROCESS_CLIENT = "testclient"
IN_PROCESS_HOST = "testserver"


def in_process(scope: Scope, headers: Headers) -> bool:
    client, server = scope.get("client"), scope.get("server")
    return bool(
        client
        and server
        and client[0] == IN_PROCESS_CLIENT
        and server[0] == IN_PROCESS_HOST
        and "x-forwarded-for" not in headers
    )


# ---- responses ----------------------------------------------------------------------------
async def _send_json(
    send: Send, status: int, detail: str, headers: dict[str, str] | None = None
) -> None:
    body = json.dumps({"detail": detail}).encode()
    raw = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
    ]
    raw += [(k.lower().encode("latin-1"), v.encode("latin-1")) for k, v in (headers or {}).items()]
    await send({"type": "http.response.start", "status": status, "headers": raw})
    await send({"type": "http.response.body", "body": body})


async def deny_websocket(
    scope: Scope, receive: Receive, send: Send, status: int, detail: str
) -> None:
    """Refuse a handshake: an HTTP answer if the server supports it, else close (→ 403)."""
    message = await receive()
    if message["type"] != "websocket.connect":  # pragma: no cover - protocol violation
        return
    if "websocket.http.response" in scope.get("extensions", {}):
        body = json.dumps({"detail": detail}).encode()
        await send(
            {
                "type": "websocket.http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                ],
            }
        )
        await send({"type": "websocket.http.response.body", "body": body})
    else:
        await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})


# ---- middleware ---------------------------------------------------------------------------
@dataclass(frozen=True)
class RouteLimit:
    """Body limit (bytes), its setting's name, and the concurrency slot of one route."""

    max_bytes: int
    setting: str
    slot: ConcurrencyLimit | None = None


class RequestGuard:
    """Pure-ASGI middleware (see the module docstring). ``routes`` maps ``(method, path)`` to
    a :class:`RouteLimit`; every other request gets ``default``."""

    def __init__(
        self,
        app: ASGIApp,
        *,
        settings: Settings,
        routes: dict[tuple[str, str], RouteLimit],
        default: RouteLimit,
        api_prefix: str = "/api/",
    ) -> None:
        self.app = app
        self.settings = settings
        self.trusted = settings.effective_trusted_hosts
        self.allowed_origins = normalise_origins(settings.allowed_origins)
        self.routes = routes
        self.default = default
        self.api_prefix = api_prefix
        self.unguarded_warned = False

    # -- checks --------------------------------------------------------------------------
    def _host_error(self, scope: Scope, headers: Headers) -> str | None:
        raw = headers.get("host")
        if raw is None:
            return "missing Host header"
        parsed = split_host(raw)
        if parsed is None:
            return "malformed Host header"
        host = parsed[0]
        if host_matches(host, self.trusted):
            return None
        if host == IN_PROCESS_HOST and in_process(scope, headers):
            return None
        return f"untrusted Host header {host!r} (add it to AAR_TRUSTED_HOSTS if it is yours)"

    def _origin_error(self, headers: Headers) -> str | None:
        origin = headers.get("origin")
        if origin is None or origin_matches(origin, headers.get("host"), self.allowed_origins):
            return None
        return f"cross-origin request from {origin[:100]!r} refused (AAR_ALLOWED_ORIGINS)"

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        if not self.unguarded_warned and not in_process(scope, headers):
            self.unguarded_warned = True  # the first real client: once per app
            if not is_guarded(scope.get("app")):
                log.warning("%s", UNGUARDED)
        error = self._host_error(scope, headers)
        status = 400
        if error is None and (kind == "websocket" or scope["method"] in MUTATING):
            error, status = self._origin_error(headers), 403
        if error is not None:
            log.info("refused %s %s: %s", kind, scope.get("path"), error)
            if kind == "websocket":
                await deny_websocket(scope, receive, send, status, error)
            else:
                await _send_json(send, status, error, {"connection": "close"})
            return
        if kind == "websocket":
            await self.app(scope, receive, send)
            return
        await self._http(scope, receive, send, headers)

    async def _http(self, scope: Scope, receive: Receive, send: Send, headers: Headers) -> None:
        method: str = scope["method"]
        path: str = scope["path"]
        close = {"connection": "close"}
        token = self.settings.token
        if (
            token
            and method in MUTATING
            and path.startswith(self.api_prefix)
            and not token_ok(headers.get("authorization"), token)
        ):
            await _send_json(
                send,
                401,
                "missing or wrong bearer token",
                {"www-authenticate": "Bearer", **close},
            )
            return
        route = self.routes.get((method, path.rstrip("/") or "/"), self.default)
        declared = headers.get("content-length")
        if declared is not None:
            if not declared.strip().isdigit():
                await _send_json(send, 400, "malformed Content-Length header", close)
                return
            if int(declared) > route.max_bytes:
                await _send_json(send, 413, self._too_large(route, int(declared)), close)
                return
        slot = route.slot
        if slot is not None and not slot.try_acquire():
            await _send_json(
                send,
                429,
                f"busy: {slot.slots} {slot.name} already in progress; retry later",
                {"retry-after": str(slot.retry_after_s), **close},
            )
            return
        try:
            await self._run_limited(scope, receive, send, route)
        finally:
            if slot is not None:
                slot.release()

    @staticmethod
    def _too_large(route: RouteLimit, size: int | None = None) -> str:
        got = "" if size is None else f" ({size / 1e6:.3g} MB)"
        return (
            f"request body too large{got}: the limit of this route is "
            f"{route.max_bytes / 1e6:.3g} MB ({route.setting})"
        )

    async def _run_limited(
        self, scope: Scope, receive: Receive, send: Send, route: RouteLimit
    ) -> None:
        received = 0
        started = False
        refused = False

        async def limited_receive() -> Message:
            nonlocal received, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > route.max_bytes:
                    refused = True
                    if not started:
                        await _send_json(send, 413, self._too_large(route), {"connection": "close"})
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if refused and not started:
                return  # our 413 went out instead of the application's answer
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, guarded_send)
        except Exception:
            if refused and not started:
                log.debug("request aborted after 413", exc_info=True)
                return
            raise


def install(app: Starlette, settings: Settings, api_prefix: str) -> dict[str, ConcurrencyLimit]:
    """Add the :class:`RequestGuard` to a FastAPI/Starlette ``app`` with the service's routes;
    returns the concurrency limits (also kept as ``app.state.limits``)."""
    slots = {
        "uploads": ConcurrencyLimit(
            "uploads", settings.max_concurrent_uploads, settings.retry_after_s
        ),
        "calibrations": ConcurrencyLimit(
            "calibrations", settings.max_concurrent_calibrations, settings.retry_after_s
        ),
    }
    routes = {
        ("POST", f"{api_prefix}/stereo"): RouteLimit(
            settings.stereo_request_limit_bytes, "AAR_MAX_REQUEST_MB", slots["uploads"]
        ),
        ("POST", f"{api_prefix}/calibration/checkerboard"): RouteLimit(
            settings.checkerboard_limit_bytes, "AAR_MAX_CHECKERBOARD_MB", slots["calibrations"]
        ),
    }
    default = RouteLimit(settings.json_limit_bytes, "AAR_MAX_JSON_KB")
    app.add_middleware(RequestGuard, settings=settings, routes=routes, default=default)
    app.state.limits = slots
    return slots
