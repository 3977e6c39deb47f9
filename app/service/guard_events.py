"""Counters of what the connection and WebSocket guards refused or closed, by reason.

One registry per process (the guards of the uvicorn protocol layer and of the ASGI layer both
count here); ``/metrics`` exposes it as ``aar_guard_events_total{reason=...}``.
"""

from __future__ import annotations

import threading
from collections import Counter

_lock = threading.Lock()
_events: Counter[str] = Counter()


def count(reason: str, n: int = 1) -> None:
    with _lock:
        _events[reason] += n


def snapshot() -> dict[str, int]:
    with _lock:
        return dict(_events)
