"""WebSocket fan-out: each client has a bounded queue that drops the oldest record."""

from __future__ import annotations

import asyncio
import threading

from app.model.frames import RawFrame
from app.model.tick import TickRecord

# The images are never part of a record; these bulky fields are left out of the stream too.
STREAM_EXCLUDE = {"led_truth_cam_mm": True}


class ClientQueue:
    """A bounded queue living on the event loop; ``put`` drops the oldest when full."""

    def __init__(self, maxsize: int) -> None:
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize=maxsize)
        self.dropped = 0

    def put(self, message: str) -> None:
        while self.queue.full():
            try:
                self.queue.get_nowait()
                self.dropped += 1
            except asyncio.QueueEmpty:  # pragma: no cover - race-free on one loop
                break
        self.queue.put_nowait(message)


class TelemetryHub:
    """Thread-safe publisher (tick thread) → asyncio consumers (WebSocket handlers)."""

    def __init__(self, queue_size: int = 64) -> None:
        self.queue_size = queue_size
        self._clients: set[ClientQueue] = set()
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self.sent = 0

    def bind_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def add_client(self) -> ClientQueue:
        client = ClientQueue(self.queue_size)
        with self._lock:
            self._clients.add(client)
        return client

    def remove_client(self, client: ClientQueue) -> None:
        with self._lock:
            self._clients.discard(client)

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._clients)

    def _fan_out(self, message: str) -> None:
        with self._lock:
            clients = list(self._clients)
        for c in clients:
            c.put(message)
        self.sent += 1

    def publish(self, record: TickRecord, raw: RawFrame | None = None) -> None:
        """Subscriber for :class:`TickLoop` (called from the tick thread)."""
        loop = self._loop
        if loop is None or loop.is_closed() or self.client_count == 0:
            return
        message = record.model_dump_json(exclude=STREAM_EXCLUDE)
        try:
            loop.call_soon_threadsafe(self._fan_out, message)
        except RuntimeError:  # loop closing during shutdown
            pass
