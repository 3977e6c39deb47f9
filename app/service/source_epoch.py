"""Which producer is the service's active source, and its epoch: one per start of a source.

The simulation (:class:`~app.service.tick_loop.TickLoop`) and a frame source
(:class:`~app.service.stream_service.StreamService`: camera, video, push, MCAP) take turns;
each start of one (a switch, a stream's restart by the watchdog, the simulation started
again) *begins* a new epoch and each stop *ends* it. A producer stamps every tick with the
epoch it runs in (``TickRecord.source_epoch``), so that an output that must carry only the
configured source (MAVLink: :mod:`app.service.mavlink_output`) drops a tick whose producer
was stopped or replaced while the tick was on its way.

:meth:`SourceEpoch.current` holds the lock that :meth:`~SourceEpoch.begin` and
:meth:`~SourceEpoch.end` take: what an output sends inside it cannot overlap a switch, so
once a switch has returned nothing of the old source goes out.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Literal

SourceKindName = Literal["sim", "video", "camera", "push"]


@dataclass(frozen=True)
class ActiveSource:
    """The producer in force: its kind (``None`` while none runs) and epoch."""

    kind: SourceKindName | None
    epoch: int


class SourceEpoch:
    """The active source's epoch (thread-safe; see the module docstring)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._active = ActiveSource(None, 0)

    @property
    def active(self) -> ActiveSource:
        return self._active

    def begin(self, kind: SourceKindName) -> int:
        """``kind`` is now the active source: a new epoch (returned)."""
        with self._lock:
            self._active = ActiveSource(kind, self._active.epoch + 1)
            return self._active.epoch

    def end(self, epoch: int) -> None:
        """The source of ``epoch`` stopped (nothing if another one has begun since)."""
        with self._lock:
            if self._active.epoch == epoch and self._active.kind is not None:
                self._active = ActiveSource(None, epoch + 1)

    @contextmanager
    def current(self, epoch: int | None) -> Iterator[bool]:
        """Whether ``epoch`` is the active source's, held (no switch) for the block's time."""
        with self._lock:
            yield (
                epoch is not None
                and self._active.kind is not None
                and (epoch == self._active.epoch)
            )
