"""WebSocket ``/telemetry``: tick records as JSON text frames (no images)."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from app.service.state import AppState

router = APIRouter(tags=["telemetry"])


@router.websocket("/telemetry")
async def telemetry(ws: WebSocket) -> None:
    """Each client gets a bounded queue (``AAR_TELEMETRY_QUEUE``) that drops the oldest."""
    state: AppState | None = getattr(ws.app.state, "aar", None)
    if state is None:
        await ws.close(code=1013)
        return
    await ws.accept()
    hub = state.hub
    hub.bind_loop(asyncio.get_running_loop())
    client = hub.add_client()

    async def drain_incoming() -> None:
        # the page sends nothing here; text or binary from a client is read and ignored (a
        # binary frame must not end the reader, which would stop this client's stream)
        try:
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    return
        except (WebSocketDisconnect, RuntimeError):
            pass

    reader = asyncio.create_task(drain_incoming())
    try:
        while not reader.done():
            getter = asyncio.ensure_future(client.queue.get())
            done, _ = await asyncio.wait({getter, reader}, return_when=asyncio.FIRST_COMPLETED)
            if getter not in done:
                getter.cancel()
                break
            await ws.send_text(getter.result())
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        hub.remove_client(client)
        reader.cancel()
