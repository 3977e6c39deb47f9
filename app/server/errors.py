"""Error bodies that are always valid JSON.

FastAPI's default 422 handler echoes each offending ``input``; a request body with ``NaN`` or
``Infinity`` (which Python's JSON parser accepts) made that echo unserialisable (strict JSON
has no such numbers) and the client got a 500. Here non-finite numbers are written as the
strings ``"NaN"``, ``"Infinity"``, ``"-Infinity"``, long inputs are cut, and the body names the
first offending field (``"field": "closure_speed_mps"``), like the calibration route does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from app.types import JsonObject

MAX_ECHO_CHARS = 200
MAX_ECHO_ITEMS = 20
_LOCATIONS = ("body", "query", "path", "header", "cookie", "form")


def json_safe(value: object, depth: int = 0) -> object:
    """A copy of ``value`` that strict JSON can encode (non-finite floats → strings, bounded)."""
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "Infinity" if value > 0 else "-Infinity"
        return value
    if isinstance(value, str):
        return value if len(value) <= MAX_ECHO_CHARS else value[:MAX_ECHO_CHARS] + "…"
    if value is None or isinstance(value, bool | int):
        return value
    if isinstance(value, bytes | bytearray):
        return json_safe(bytes(value[: MAX_ECHO_CHARS + 1]).decode("utf-8", "replace"), depth)
    if depth > 8:
        return "…"
    if isinstance(value, dict):
        items = list(value.items())
        out = {str(k)[:MAX_ECHO_CHARS]: json_safe(v, depth + 1) for k, v in items[:MAX_ECHO_ITEMS]}
        if len(items) > MAX_ECHO_ITEMS:
            out["…"] = f"{len(items) - MAX_ECHO_ITEMS} more"
        return out
    if isinstance(value, list | tuple):
        seq = [json_safe(v, depth + 1) for v in list(value)[:MAX_ECHO_ITEMS]]
        if len(value) > MAX_ECHO_ITEMS:
            seq.append(f"… {len(value) - MAX_ECHO_ITEMS} more")
        return seq
    return json_safe(str(value), depth + 1)


def field_name(loc: Sequence[object] | None) -> str:
    """``("body", "left", 0)`` → ``"left.0"``; ``("body",)`` → ``"<root>"``."""
    parts = [str(p) for p in (loc or ())]
    if parts and parts[0] in _LOCATIONS:
        parts = parts[1:]
    return ".".join(parts) or "<root>"


async def validation_exception_handler(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    raw = list(exc.errors())
    errors = json_safe(raw)  # bytes, exceptions in ctx … → str; NaN → "NaN"
    content: JsonObject = {"detail": errors}
    if raw:
        content["field"] = field_name(raw[0].get("loc"))
    return JSONResponse(status_code=422, content=content)
