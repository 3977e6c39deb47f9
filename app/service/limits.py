"""Non-blocking concurrency limits for the expensive routes (uploads, checkerboard calibration),
and the process's file-descriptor limit (:func:`fd_limit`).

A request that finds every slot taken is answered ``429`` with ``Retry-After`` at once, before
its body is read (see :mod:`app.server.security`), instead of queueing: a queue of uploads
would still cost the event loop and the tick thread the multipart parsing and the spooling.
"""

from __future__ import annotations

import resource
import threading
from collections.abc import Iterator
from contextlib import contextmanager


class BusyError(RuntimeError):
    """All slots of a :class:`ConcurrencyLimit` are taken."""


class ConcurrencyLimit:
    """A counting semaphore that never waits (thread-safe: tests may hold it from a thread)."""

    def __init__(self, name: str, slots: int, retry_after_s: int) -> None:
        if slots < 1:
            raise ValueError("slots must be >= 1")
        self.name = name
        self.slots = slots
        self.retry_after_s = retry_after_s
        self._in_use = 0
        self._lock = threading.Lock()
        self.refused = 0

    @property
    def in_use(self) -> int:
        with self._lock:
            return self._in_use

    def try_acquire(self) -> bool:
        with self._lock:
            if self._in_use >= self.slots:
                self.refused += 1
                return False
            self._in_use += 1
            return True

    def release(self) -> None:
        with self._lock:
            if self._in_use <= 0:  # pragma: no cover - a release without acquire is a bug
                raise RuntimeError(f"{self.name}: release without acquire")
            self._in_use -= 1

    @contextmanager
    def hold(self, n: int | None = None) -> Iterator[None]:
        """Take ``n`` slots (default: all) for the duration of the block; ``BusyError`` if not free."""
        n = self.slots if n is None else n
        taken = 0
        try:
            for _ in range(n):
                if not self.try_acquire():
                    raise BusyError(f"{self.name}: only {taken} of {n} slots free")
                taken += 1
            yield
        finally:
            for _ in range(taken):
                self.release()


def fd_limit() -> int | None:
    """The soft ``RLIMIT_NOFILE`` of this process (None: unlimited or unknown)."""
    try:
        soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    except (OSError, ValueError):  # pragma: no cover - not on Linux/macOS
        return None
    return None if soft == resource.RLIM_INFINITY else int(soft)
