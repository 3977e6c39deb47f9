"""Who may drive the simulation from the viser scene server (its own port, its own WebSocket).

The REST API asks for ``Authorization: Bearer <AAR_TOKEN>`` on every mutation; the viser
GUI must not be a way around it. Two checks, both on the server side:

* **Origin** (always): a browser page of another site must not drive the GUI from the
  operator's browser (viser itself checks no Origin). A WebSocket whose ``Origin`` is not
  this service's is closed (1008) before any of its messages is handled.
* **Operator token** (when ``AAR_TOKEN`` is set): a client may watch, but changes nothing
  until it has entered the token in its own (client-scoped) "Operator token" field and
  pressed Unlock. Non-GUI control messages (share-URL tunnel, scene interaction) are dropped
  here; updates of the client's own control widgets are refused by the GUI callbacks
  (:meth:`app.viz.gui.DockingGui.handle_change`), which re-check on every event and never
  trust the browser's disabled widgets.

viser exposes no hook on its HTTP upgrade request (``process_request`` is a private closure
of ``viser.infra.WebsockServer``), so :func:`install_gate` works one step later, in an
infra-level connect callback: it runs for each new connection *before* viser starts reading
that connection's messages, can see the handshake request, and wraps the connection's
message dispatch (``_handle_incoming_message``) with :meth:`AccessPolicy.admit`.
"""

from __future__ import annotations

import ipaddress
import logging
import secrets
import socket
import threading
from collections.abc import Callable, Coroutine, Iterable
from typing import Any
from urllib.parse import urlsplit

log = logging.getLogger(__name__)

MAX_TOKEN_CHARS = 1024
# client -> server messages that change nothing: camera pose, answers to server requests
VIEW_MESSAGES = frozenset(
    {"ViewerCameraMessage", "GetRenderResponseMessage", "LocalStorageGetItemResponseMessage"}
)
GuiFilter = Callable[[int, Any], bool]
"""``(client_id, GuiUpdateMessage) -> admit?`` for client-scoped GUI updates (the panel's)."""
_Dispatch = Callable[[Any, Any], Coroutine[Any, Any, None]]
_WILDCARD = {"", "0.0.0.0", "::", "[::]"}


def _origin_of(url: str) -> tuple[str, str, int] | None:
    """``(scheme, host, port)`` of an http(s) URL or Origin value; None if it is not one."""
    try:
        parts = urlsplit(url.strip())
        port = parts.port
    except ValueError:
        return None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return None
    return parts.scheme, parts.hostname.lower(), port or (443 if parts.scheme == "https" else 80)


def _hostname_of(host_header: str | None) -> str | None:
    if not host_header:
        return None
    try:
        return urlsplit("//" + host_header.strip()).hostname
    except ValueError:
        return None


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class OriginPolicy:
    """Accept a browser WebSocket only from this service's own pages.

    An ``Origin`` is accepted when it is one of ``extra_origins`` (the public viser URL,
    ``AAR_ALLOWED_ORIGINS``; ``*`` = any), or when its host equals the request's ``Host`` (the
    viser page itself, or the FastAPI page on the same host), its port is one of ``ports``
    (viser, FastAPI), and that host is trusted: an IP literal, ``localhost``, or one of
    ``names`` (bind host, public URL host, ``AAR_TRUSTED_HOSTS`` with ``*.example.org`` and
    ``*``), so that a DNS-rebinding name that resolves to this machine is still refused. No
    ``Origin`` header: not a browser, accepted (the operator token still applies).
    """

    def __init__(
        self, *, ports: Iterable[int], names: Iterable[str], extra_origins: Iterable[str] = ()
    ) -> None:
        self.ports = {int(p) for p in ports if p}
        self.names = {
            n.strip().lower().strip("[]").rstrip(".") for n in names if n.strip() not in _WILDCARD
        }
        extra = [u.strip() for u in extra_origins if u and u.strip()]
        self.any_origin = "*" in extra
        self.extra = {o for o in (_origin_of(u) for u in extra) if o is not None}

    def _trusted(self, name: str) -> bool:
        if _is_ip(name) or name == "localhost" or name in self.names or "*" in self.names:
            return True
        return any(n.startswith("*.") and name.endswith(n[1:]) for n in self.names)

    def allows(self, origin: str | None, host: str | None) -> bool:
        if origin is None:
            return True
        parsed = _origin_of(origin)
        if parsed is None:  # "null" (sandboxed frame, file://) or junk
            return False
        if self.any_origin or parsed in self.extra:
            return True
        _, name, port = parsed
        if port not in self.ports or _hostname_of(host) != name:
            return False
        return self._trusted(name)


class AccessPolicy:
    """The operator token and the set of clients allowed to drive the simulation."""

    def __init__(self, token: str | None = None, origins: OriginPolicy | None = None) -> None:
        self.token = token or None
        self.origins = origins
        self._lock = threading.Lock()
        self._operators: set[int] = set()
        self._refused: set[int] = set()

    @classmethod
    def from_settings(cls, settings: Any, *, viser_port: int) -> AccessPolicy:
        """Token and allowed origins from :class:`app.service.settings.Settings` (or None).

        The same settings as the REST guard: ``token``, ``host``/``viser_host``,
        ``public_viser_url`` and, where the settings have them, ``trusted_hosts`` and
        ``allowed_origins``.
        """

        def strings(name: str) -> list[str]:
            value = getattr(settings, name, None)
            if isinstance(value, str):
                return [value]
            if isinstance(value, (list, tuple)):
                return [v for v in value if isinstance(v, str)]
            return []

        public = strings("public_viser_url")
        names = ["localhost", socket.gethostname(), *strings("host"), *strings("viser_host")]
        names += strings("trusted_hosts")
        names += [o[1] for o in (_origin_of(u) for u in public) if o is not None]
        ports = [viser_port, int(getattr(settings, "port", 0) or 0)]
        origins = OriginPolicy(
            ports=ports, names=names, extra_origins=[*public, *strings("allowed_origins")]
        )
        token = getattr(settings, "token", None)
        return cls(token if isinstance(token, str) else None, origins)

    @property
    def token_required(self) -> bool:
        return self.token is not None

    def check_token(self, candidate: object) -> bool:
        if self.token is None:
            return True
        if not isinstance(candidate, str) or len(candidate) > MAX_TOKEN_CHARS:
            return False
        return secrets.compare_digest(candidate.encode(), self.token.encode())

    def grant(self, client_id: int) -> None:
        with self._lock:
            if client_id not in self._refused:
                self._operators.add(client_id)

    def refuse(self, client_id: int) -> None:
        with self._lock:
            self._refused.add(client_id)
            self._operators.discard(client_id)

    def forget(self, client_id: int) -> None:
        with self._lock:
            self._operators.discard(client_id)
            self._refused.discard(client_id)

    def is_refused(self, client_id: int | None) -> bool:
        return client_id is not None and client_id in self._refused

    def is_operator(self, client_id: int | None) -> bool:
        return client_id is not None and client_id in self._operators

    def may_control(self, client_id: int | None) -> bool:
        """May this client change the simulation? (None: not a client, i.e. not allowed.)"""
        if client_id is None or client_id in self._refused:
            return False
        return self.token is None or client_id in self._operators

    def origin_allowed(self, origin: str | None, host: str | None) -> bool:
        return self.origins is None or self.origins.allows(origin, host)

    def admit(self, client_id: int, message: Any, gui_filter: GuiFilter | None = None) -> bool:
        """Should viser handle this message from this client at all?"""
        if client_id in self._refused:
            return False
        kind = type(message).__name__
        if kind in VIEW_MESSAGES:
            return True
        if gui_filter is not None and kind == "GuiUpdateMessage":
            return gui_filter(client_id, message)
        return self.may_control(client_id)


def _gated(inner: _Dispatch, policy: AccessPolicy, gui_filter: GuiFilter | None) -> _Dispatch:
    async def dispatch(client_id: Any, message: Any) -> None:
        try:
            if policy.admit(int(client_id), message, gui_filter):
                await inner(client_id, message)
            else:
                log.debug("viser: dropped %s from client %s", type(message).__name__, client_id)
        except Exception:  # a bad message must not become an unhandled task exception
            log.warning(
                "viser: %s from client %s raised; ignored",
                type(message).__name__,
                client_id,
                exc_info=True,
            )

    return dispatch


def _handshake_headers(ws: Any, client_id: int) -> Any:
    raw = getattr(ws, "_live_connections", {}).get(client_id)
    request = getattr(raw, "request", None)
    return raw, getattr(request, "headers", None)


def handshake_path(server: Any, client_id: int) -> str | None:
    """The path of a client's WebSocket handshake (viser's client connects to the path of its
    page: ``/`` opened directly, ``/index.html`` as the operators' page embeds it)."""
    ws = getattr(server, "_websock_server", None)
    raw = getattr(ws, "_live_connections", {}).get(client_id)
    path = getattr(getattr(raw, "request", None), "path", None)
    return path.partition("?")[0] if isinstance(path, str) else None


def install_gate(server: Any, policy: AccessPolicy, gui_filter: GuiFilter | None = None) -> bool:
    """Put ``policy`` in front of every message handler of ``server`` (a ViserServer).

    Returns False (and logs an error) if this viser's internals are not the ones this was
    written against (viser 1.1: ``ViserServer._websock_server``, ``WebsockServer.
    _live_connections`` / ``_handle_incoming_message``); the GUI callbacks still check
    :meth:`AccessPolicy.may_control` themselves.
    """
    ws = getattr(server, "_websock_server", None)
    needed = ("_handle_incoming_message", "on_client_connect", "on_client_disconnect")
    if ws is None or not all(hasattr(ws, a) for a in needed):
        log.error("viser internals changed: no Origin check and no message gate on the 3-D port")
        return False
    # server-scoped handlers (shared GUI, share-URL tunnel, scene interaction). viser has no
    # public hook in front of its message handlers: the gate wraps the internal one (checked
    # above; the service refuses to trust the port without it), the one private access in app/
    handler = ws._handle_incoming_message  # noqa: SLF001 - viser internals, see above
    ws._handle_incoming_message = _gated(handler, policy, None)  # noqa: SLF001

    async def on_connect(conn: Any) -> None:
        client_id = int(conn.client_id)
        # client-scoped handlers (the client's own panel, camera): gate before viser reads
        # the first message of this connection (the consumer starts after this callback)
        handler = conn._handle_incoming_message  # noqa: SLF001 - viser internals, see above
        conn._handle_incoming_message = _gated(handler, policy, gui_filter)  # noqa: SLF001
        raw, headers = _handshake_headers(ws, client_id)
        if headers is None:
            log.error("viser: no handshake headers for client %s; Origin not checked", client_id)
            return
        origin = host = None
        try:
            origins, hosts = headers.get_all("Origin"), headers.get_all("Host")
            allowed = len(origins) <= 1 and len(hosts) <= 1
            origin, host = (origins or [None])[0], (hosts or [None])[0]
            allowed = allowed and policy.origin_allowed(origin, host)
        except Exception:
            allowed = False
        if allowed:
            return
        policy.refuse(client_id)
        log.warning("viser: refused client %s from Origin %r (Host %r)", client_id, origin, host)
        try:
            await raw.close(1008, "origin not allowed")
        except Exception:  # already gone
            log.debug("viser: closing refused client %s failed", client_id, exc_info=True)

    def on_disconnect(conn: Any) -> None:
        policy.forget(int(conn.client_id))

    ws.on_client_connect(on_connect)
    ws.on_client_disconnect(on_disconnect)
    # a browser that connected before the gate existed reconnects through it
    disconnect = getattr(ws, "disconnect_all_clients", None)
    if disconnect is not None:
        disconnect()
    return True
