"""Frame sources: ``GET /stream`` (status), ``PUT /stream/source`` (switch, token),
WebSocket ``/stream/push`` (stereo pairs pushed by a camera computer, token).

Push protocol: :mod:`app.streams.protocol` (one binary message per pair: a 10-byte prefix,
a JSON header with ``t_s``, ``seq``, optional ``exposure_ms``, the two image lengths, then
the two encoded images). The service keeps the newest pair (older unread ones are dropped
and counted). The handler answers only problems, as JSON text messages
``{"error": ...}`` (at most one a second), and a text message ``stats`` with the source's
counters. A message above ``AAR_PUSH_MAX_MB`` closes the connection (1009).

Close codes (docs/service.md, "health, limits"): 1008 bad token, or a pusher beyond
``AAR_PUSH_MAX_CLIENTS`` (refused; the first keeps pushing); 1007 a header that cannot be
parsed; 1009 a message over the limit; 1013 the push source this pusher fed failed and is
being restarted (the reason says why; reconnect). A repeated or backward ``seq`` is dropped
and counted (``seq_duplicate``, ``seq_out_of_order``).
"""

from __future__ import annotations

import asyncio
import json
import time
from typing import Annotated

from fastapi import APIRouter, Body, Depends, HTTPException, WebSocket, WebSocketDisconnect
from pydantic import BaseModel, Field

from app.server.dependencies import StateDep, require_token
from app.server.schemas import STRICT
from app.service.host_rules import token_ok
from app.service.image_guard import ImageRefused, check
from app.service.state import AppState
from app.streams.frames import SourceError
from app.streams.protocol import HeaderSyntaxError, ProtocolError, decode_message
from app.streams.sources import PushSource

router = APIRouter(prefix="/stream", tags=["stream"])
ERROR_INTERVAL_S = 1.0


class StreamStatus(BaseModel):
    source: str = Field(description="active source spec: sim, push, video:..., camera:...")
    kind: str
    state: str = Field(
        description="sim | running | restarting | ended | failed (corrupt data: see health)"
    )
    health: str = Field("ok", description="ok | degraded (the source failed, stalled)")
    health_reason: str | None = None
    restarts: int = Field(0, description="times the source was reopened after a failure")
    consecutive_failures: int = Field(0, description="failed pairs since the last good one")
    fps: float | None = None
    frames: int = 0
    errors: int = 0
    last_error: str | None = None
    pairs: int = 0
    dropped_skew: int = Field(0, description="frames dropped by the left/right pairing")
    dropped_backpressure: int = Field(0, description="pushed pairs replaced by newer ones")
    rejected: int = Field(0, description="pushed pairs refused (header, image)")
    seq_duplicate: int = Field(0, description="pushed pairs dropped: seq repeated")
    seq_out_of_order: int = Field(0, description="pushed pairs dropped: seq went back")
    last_skew_ms: float | None = None
    max_skew_ms: float | None = None
    max_skew_ms_allowed: float
    received: int | None = None
    pushers: int = Field(0, description="pushers connected")


class SourceRequest(BaseModel):
    model_config = STRICT

    source: str = Field(
        max_length=2048,
        description="sim, push, video:LEFT,RIGHT, video:DIR, camera:I,J or camera:I",
    )
    realtime: bool | None = Field(None, description="pace video at its frame times")
    loop: bool | None = Field(None, description="restart a video source at its end")


def _status(state: AppState) -> StreamStatus:
    return StreamStatus.model_validate(state.streams.status())


@router.get("", response_model=StreamStatus)
def stream_status(state: StateDep) -> StreamStatus:
    return _status(state)


@router.put("/source", response_model=StreamStatus, dependencies=[Depends(require_token)])
def put_source(request: Annotated[SourceRequest, Body()], state: StateDep) -> StreamStatus:
    """Switch the frame source (video files only inside ``AAR_STREAM_ROOTS``); 422 with the
    reason if it cannot be opened (the active source is kept)."""
    try:
        state.streams.switch(
            request.source, realtime=request.realtime, loop=request.loop, restricted=True
        )
    except SourceError as exc:
        raise HTTPException(422, f"cannot open source: {exc}") from None
    if state.viz is not None and request.source.strip() in ("", "sim"):
        state.viz.on_reset()
    return _status(state)


def _ws_token(ws: WebSocket, token: str) -> bool:
    if token_ok(ws.headers.get("authorization"), token):
        return True
    query = ws.query_params.get("token")
    return query is not None and token_ok(f"Bearer {query}", token)


def _close_reason(text: str) -> str:
    """A WebSocket close reason: at most 123 bytes of UTF-8."""
    raw = text.encode()
    return text if len(raw) <= 123 else raw[:120].decode(errors="ignore") + "..."


@router.websocket("/push")
async def push(ws: WebSocket) -> None:
    state: AppState | None = getattr(ws.app.state, "aar", None)
    if state is None:
        await ws.close(code=1013)
        return
    token = state.settings.token
    if token and not _ws_token(ws, token):
        await ws.close(code=1008, reason="missing or wrong bearer token")
        return
    await ws.accept()
    streams = state.streams
    slots = streams.push_slots
    if not slots.try_acquire():
        await ws.close(
            code=1008,
            reason=f"refused: {slots.slots} pusher(s) already connected (AAR_PUSH_MAX_CLIENTS)",
        )
        return
    try:
        await _push_session(ws, state)
    finally:
        slots.release()


async def _push_session(ws: WebSocket, state: AppState) -> None:
    limit = state.settings.push_limit_bytes
    max_pixels = state.settings.max_image_pixels
    last_error = 0.0
    streams = state.streams
    streams.begin_push_session()
    pushed_into: int | None = None  # the generation of the push source this pusher fed

    async def problem(text: str, *, rejected: bool = True) -> None:
        nonlocal last_error
        src = streams.source
        if rejected and isinstance(src, PushSource):
            src.stats.add("rejected")
            src.last_error = text
        now = time.monotonic()
        if now - last_error >= ERROR_INTERVAL_S:
            last_error = now
            await ws.send_text(json.dumps({"error": text}))

    try:
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            data = message.get("bytes")
            if data is None:
                if (message.get("text") or "").strip() == "stats":
                    await ws.send_text(json.dumps(streams.status()))
                continue
            if len(data) > limit:
                await ws.close(
                    code=1009, reason=f"message over {limit / 1e6:g} MB (AAR_PUSH_MAX_MB)"
                )
                return
            if pushed_into is not None and (why := streams.failure_of(pushed_into)):
                await ws.close(code=1013, reason=_close_reason(f"stream restarting: {why}"))
                return
            try:
                msg = decode_message(data, limit)
                w, h = state.calibrations.current.image_size
                for name, blob in (("left", msg.left), ("right", msg.right)):
                    hdr = check(blob, name, max_pixels=max_pixels)  # the uploads' guard
                    if (hdr.width, hdr.height) != (w, h):
                        raise ProtocolError(
                            f"{name}: {hdr.describe()} but the calibration is for {w}x{h} px"
                        )
            except HeaderSyntaxError as exc:
                await ws.close(code=1007, reason=_close_reason(str(exc)))
                return
            except (ProtocolError, ImageRefused) as exc:
                await problem(str(exc))
                continue
            outcome, generation = streams.push(msg)
            if outcome == "not_push":
                await problem(f"the active source is {streams.spec!r}, not push", rejected=False)
            elif outcome == "restarting":
                await problem("the push stream is restarting; pair dropped", rejected=False)
            else:
                pushed_into = generation
                if outcome != "queued":
                    await problem(f"pair seq {msg.seq} dropped: {outcome}", rejected=False)
            await asyncio.sleep(0)
    except WebSocketDisconnect:
        return
    except RuntimeError as exc:  # the socket went away under a send (Starlette's state)
        if "websocket" not in str(exc).lower():
            raise
        return
