"""The telemetry bus: every producer's ticks become records here and go to the subscribers.

The simulation (:class:`~app.service.tick_loop.TickLoop`), a camera stream
(:class:`~app.service.stream_service.StreamService`) and an upload (``POST /stereo``) each hand
a :class:`~app.service.records.Tick` to :meth:`TelemetryBus.publish`, which stamps it (the
publication counter ``seq``, the loop clock), builds the
:class:`~app.model.tick.TickRecord`, keeps it (the latest, a bounded history), adds its
stage timings to the statistics behind ``/metrics`` and calls every subscriber with
``(record, raw)`` in the publishing thread: the WebSocket hub, the 3-D scene, the recorder,
the camera view, the MAVLink and Foxglove outputs.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from app.model.tick import TickRecord
from app.service.clock import Clock
from app.service.records import RawFrame, Tick, to_record
from app.service.source_epoch import SourceEpoch

log = logging.getLogger(__name__)

STAGE_WINDOW = 512  # samples kept per stage for the quantiles

Subscriber = Callable[[TickRecord, RawFrame | None], None]
"""Called in the publishing thread with the record and its raw side (images; ``None`` for an
upload whose images are not shown)."""


class TelemetryBus:
    """Publication counter, clock, history, subscribers and stage statistics of all sources."""

    def __init__(self, clock: Clock, history_len: int) -> None:
        self.clock = clock
        self._lock = threading.Lock()  # guards seq + subscribers
        self._seq = 0
        self._subscribers: list[Subscriber] = []
        self._history: deque[TickRecord] = deque(maxlen=history_len)
        self.latest: TickRecord | None = None
        self.stage_ms: dict[str, deque[float]] = {}
        self.sources = SourceEpoch()  # the producer in force and its epoch

    # ---- subscribers ----------------------------------------------------------------
    def subscribe(self, fn: Subscriber, *, first: bool = False) -> None:
        """Call ``fn`` with every record from now on; ``first``: before the subscribers
        already there (an output whose latency counts: MAVLink)."""
        with self._lock:
            if first:
                self._subscribers.insert(0, fn)
            else:
                self._subscribers.append(fn)

    # ---- publication ----------------------------------------------------------------
    def _next_seq(self) -> int:
        with self._lock:
            self._seq += 1
            return self._seq

    def publish(
        self, tick: Tick, *, run: int, stages: bool = True, epoch: int | None = None
    ) -> TickRecord:
        """Stamp ``tick``, build its record, keep it and fan it out; returns the record.

        ``run``: the simulation's run counter the record carries; ``stages``: add the record's
        timings to the stage statistics (the simulation's and the streams' ticks; an upload
        adds only its publication time); ``epoch``: the producer's epoch in
        :attr:`sources` (``None``: an upload, which is no source)."""
        record = to_record(
            tick, seq=self._next_seq(), clock_s=self.clock.now(), run=run, source_epoch=epoch
        )
        if stages:
            for name, value in record.timings_ms.items():
                self._add_stage(name, value)
        t0 = time.perf_counter()
        self.latest = record
        self._history.append(record)
        with self._lock:
            subs = list(self._subscribers)
        for fn in subs:
            try:
                fn(record, tick.raw)
            except Exception:  # a broken subscriber must not stop the producer
                log.exception("tick subscriber failed")
        self._add_stage("publish", (time.perf_counter() - t0) * 1e3)
        return record

    # ---- history --------------------------------------------------------------------
    def set_history_len(self, n: int) -> None:
        """Keep the last ``n`` records from now on (the newest kept)."""
        self._history = deque(list(self._history), maxlen=n)

    def history(self, seconds: float | None = None) -> list[TickRecord]:
        """The records of the last ``seconds`` on the loop clock (all kept: ``None``)."""
        items = list(self._history)
        if seconds is None:
            return items
        cutoff = self.clock.now() - seconds
        return [r for r in items if r.clock_s >= cutoff]

    # ---- stage statistics -------------------------------------------------------------
    def _add_stage(self, name: str, ms: float) -> None:
        dq = self.stage_ms.get(name)
        if dq is None:
            dq = self.stage_ms[name] = deque(maxlen=STAGE_WINDOW)
        dq.append(ms)

    def stage_quantiles(self, q: float) -> dict[str, float]:
        """The ``q`` quantile of each stage's last :data:`STAGE_WINDOW` samples (ms)."""
        out: dict[str, float] = {}
        for name, dq in list(self.stage_ms.items()):
            vals = list(dq)
            if vals:
                out[name] = float(np.quantile(vals, q))
        return out
