"""The Host, Origin and bearer-token rules that the web guard (:mod:`app.server.security`) and
the Foxglove gate (:mod:`app.service.foxglove_gate`) apply alike: plain string checks on
header values, no web framework."""

from __future__ import annotations

import secrets
from urllib.parse import urlsplit

_DEFAULT_PORT = {"http": 80, "https": 443, "ws": 80, "wss": 443}
_HOST_CHARS = frozenset("abcdefghijklmnopqrstuvwxyz0123456789.-_")


def split_host(value: str) -> tuple[str, int | None] | None:
    """``"Example.org:8000"`` → ``("example.org", 8000)``; ``None`` if malformed."""
    value = value.strip().lower()
    if not value:
        return None
    if value.startswith("["):
        end = value.find("]")
        if end < 0:
            return None
        host, rest = value[1:end], value[end + 1 :]
        if not host or not all(c in "0123456789abcdef:." for c in host):
            return None
    else:
        if value.count(":") > 1:
            return None
        host, sep, port = value.partition(":")
        rest = sep + port
        if not host or not all(c in _HOST_CHARS for c in host):
            return None
    port_num: int | None = None
    if rest:
        if not rest.startswith(":") or not rest[1:].isdigit() or len(rest) > 6:
            return None
        port_num = int(rest[1:])
        if port_num > 65535:
            return None
    return host.rstrip("."), port_num


def host_matches(host: str, trusted: list[str]) -> bool:
    for pattern in trusted:
        if pattern == "*" or pattern == host:
            return True
        if pattern.startswith("*.") and host.endswith(pattern[1:]):
            return True
    return False


def origin_matches(origin: str, host_header: str | None, allowed: list[str]) -> bool:
    """Same-origin (Origin host:port = Host) or listed in ``allowed`` (or ``*`` there)."""
    o = origin.strip().lower().rstrip("/")
    if "*" in allowed or o in allowed:
        return True
    try:
        parts = urlsplit(o)
        o_port = parts.port
    except ValueError:
        return False
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return False  # "null" (sandboxed frames, file://) and other schemes
    if host_header is None or (h := split_host(host_header)) is None:
        return False
    o_port = o_port or _DEFAULT_PORT[parts.scheme]
    h_port = h[1] or _DEFAULT_PORT[parts.scheme]
    return parts.hostname.rstrip(".") == h[0] and o_port == h_port


def normalise_origins(origins: list[str]) -> list[str]:
    return [o.strip().lower().rstrip("/") for o in origins if o.strip()]


def token_ok(authorization: str | None, token: str) -> bool:
    if not authorization:
        return False
    scheme, _, value = authorization.strip().partition(" ")
    if scheme.lower() != "bearer":
        return False
    return secrets.compare_digest(value.strip().encode(), token.encode())
