"""The service's loop clock: real (monotonic) time, or a fake one that tests step by hand."""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class MonotonicClock:
    """Real time (``time.monotonic``)."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))


class FakeClock:
    """Deterministic clock: ``sleep`` advances time instantly; ``advance`` moves it by hand."""

    def __init__(self, start: float = 0.0) -> None:
        self.t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self.t

    def sleep(self, seconds: float) -> None:
        self.advance(max(0.0, seconds))
        time.sleep(0)  # let other threads run

    def advance(self, seconds: float) -> None:
        with self._lock:
            self.t += seconds
