"""Camera streams in the service: the active frame source and its loop thread.

The simulation is stepped by the fixed-rate :class:`~app.server.tick_loop.TickLoop`; a frame
source (video, camera, push: :mod:`app.streams`) runs at its *own* pace in a dedicated thread
(``aar-stream``): read a pair (decoding in OpenCV, which releases the GIL), track it,
filter, compute guidance (:class:`~app.streams.processor.StreamProcessor`), then publish the
record through the tick loop's subscribers (history, WebSocket hub, 3-D scene, recorder).
Nothing of this runs on the web server's event loop; the push WebSocket handler only parses
the message header and hands the bytes over (the newest pair is kept).

One source is active at a time: switching to a stream stops the simulated stream, switching
back to ``sim`` restarts it. The controller runs only with the simulation (it needs the
receiver's own state); a real autopilot feed would be another source of own state.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

from app.server.settings import Settings
from app.server.tick_loop import TickLoop, tick_to_record
from app.streams.frames import EndOfStream, SourceError
from app.streams.processor import StreamProcessor
from app.streams.protocol import PushMessage
from app.streams.sources import (
    FrameSourceT,
    PushSource,
    SourceOptions,
    SourceSpec,
    open_source,
    parse_source,
)

log = logging.getLogger(__name__)
MAX_CONSECUTIVE_ERRORS = 20


class StreamService:
    def __init__(self, loop: TickLoop, calibration: Any, settings: Settings) -> None:
        self.loop = loop
        self.settings = settings
        self._calibration = calibration
        self._lock = threading.RLock()
        self.source: FrameSourceT | None = None
        self.processor: StreamProcessor | None = None
        self.spec = "sim"
        self.state = "sim"  # sim | running | ended | error
        self.last_error: str | None = None
        self.errors = 0
        self.frames = 0
        self.started_wall: float | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        loop.before_start_sim = self._on_sim_start

    def _on_sim_start(self) -> None:
        """``POST /sim/start`` (or the scene's button) while a stream runs: back to sim."""
        with self._lock:
            if self.source is not None:
                self._stop_stream()
                self.spec, self.state, self.last_error = "sim", "sim", None

    # ---- configuration --------------------------------------------------------------
    def options(self, *, realtime: bool | None = None, loop: bool | None = None) -> SourceOptions:
        s = self.settings
        return SourceOptions(
            realtime=s.stream_realtime if realtime is None else realtime,
            loop=s.stream_loop if loop is None else loop,
            fps=s.stream_fps,
            max_skew_s=s.stream_max_skew_ms / 1e3,
        )

    def _check_roots(self, spec: SourceSpec) -> None:
        """Sources switched through the API: video files only inside the allowed folders."""
        if spec.kind != "video":
            return
        roots = self.settings.stream_roots or [self.settings.recordings_dir]
        resolved = [Path(r).resolve() for r in roots]
        for part in (spec.left, spec.right):
            if not part:
                continue
            p = Path(part).resolve()
            if not any(p == r or r in p.parents for r in resolved):
                raise SourceError(
                    f"{part!r} is outside the folders a source may be read from over the API "
                    f"(AAR_STREAM_ROOTS: {', '.join(str(r) for r in resolved)})"
                )

    def switch(
        self,
        spec_text: str,
        *,
        realtime: bool | None = None,
        loop: bool | None = None,
        restricted: bool = False,
    ) -> dict[str, Any]:
        """Make ``spec_text`` the active source; :class:`SourceError` (nothing changed) if it
        cannot be opened."""
        spec = parse_source(spec_text)
        if restricted:
            self._check_roots(spec)
        with self._lock:
            if spec.kind is None:
                self.loop.start_sim()  # stops the stream first (_on_sim_start)
                return self.status()
            source = open_source(spec, self.options(realtime=realtime, loop=loop))
            self._stop_stream()
            self.loop.stop_sim()
            self.source = source
            # a frame recording replays with the calibration it was recorded with
            calibration = getattr(source, "calibration", None) or self._calibration
            if calibration is not self._calibration:
                log.info("%s: using the recording's own calibration", source.spec)
            self.processor = StreamProcessor(calibration)
            self.spec = source.spec
            self.state = "running"
            self.last_error = None
            self.errors = self.frames = 0
            self.started_wall = time.time()
            self._stop = stop = threading.Event()
            self._thread = threading.Thread(
                target=self._run,
                args=(source, self.processor, stop),
                name="aar-stream",
                daemon=True,
            )
            self._thread.start()
            log.info("frame source %s started", source.spec)
            return self.status()

    def _stop_stream(self) -> None:
        thread, source = self._thread, self.source
        self._stop.set()
        if source is not None and isinstance(source, PushSource):
            source.close()  # wakes a waiting read
        if thread is not None:
            thread.join(timeout=5.0)
        if source is not None:
            source.close()
        self._thread = None
        self.source = None
        self.processor = None

    def set_calibration(self, calibration: Any) -> None:
        with self._lock:
            self._calibration = calibration
            if self.processor is not None:
                self.processor.set_calibration(calibration)

    def close(self) -> None:
        with self._lock:
            self._stop_stream()

    # ---- the stream thread ----------------------------------------------------------
    def _run(self, source: FrameSourceT, processor: StreamProcessor, stop: threading.Event) -> None:
        consecutive = 0
        while not stop.is_set():
            try:
                frame = source.read(timeout_s=0.25)
                if frame is None:
                    continue
                t0 = time.perf_counter()
                tick = processor.process(frame, source.kind)
                if source.kind == "camera":  # grab time on this machine's monotonic clock
                    tick.extra_timings_ms["frame_age"] = (time.monotonic() - frame.t_s) * 1e3
                stats = source.stats
                tick.stream = {
                    "spec": source.spec,
                    "frame": frame.seq,
                    "frame_t_s": frame.t_s,
                    "mode": tick.mode,
                    "fps": round(stats.fps(), 3),
                    "pairs": stats.pairs,
                    "dropped_skew": stats.dropped_skew,
                    "dropped_backpressure": stats.dropped_backpressure,
                    "skew_ms": stats.last_skew_ms,
                }
                step_ms = (time.perf_counter() - t0) * 1e3
                record = tick_to_record(
                    tick,
                    seq=self.loop.next_seq(),
                    clock_s=self.loop.clock.now(),
                    run=self.loop.run,
                    step_ms=step_ms,
                )
                if stop.is_set():
                    break
                self.loop.publish_stream(record, tick)
                self.frames += 1
                consecutive = 0
            except EndOfStream:
                if not stop.is_set():
                    self.state = "ended"
                    log.info("frame source %s ended", source.spec)
                return
            except Exception as exc:
                self.errors += 1
                consecutive += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
                log.exception("frame source %s failed", source.spec)
                if consecutive >= MAX_CONSECUTIVE_ERRORS:
                    self.state = "error"
                    return
                time.sleep(0.05)

    # ---- push -------------------------------------------------------------------------
    def push(self, message: PushMessage) -> bool:
        """Hand a pushed pair to the push source; ``False`` if the active source is not
        ``push``."""
        source = self.source
        if not isinstance(source, PushSource):
            return False
        source.put(message)
        return True

    @property
    def accepts_push(self) -> bool:
        return isinstance(self.source, PushSource)

    # ---- status -----------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        source = self.source
        stats = source.stats.as_dict() if source is not None else {}
        return {
            "source": self.spec,
            "kind": source.kind if source is not None else self.spec.split(":")[0],
            "state": self.state,
            "fps": round(source.stats.fps(), 3) if source is not None else None,
            "frames": self.frames,
            "errors": self.errors,
            "last_error": self.last_error
            or (source.last_error if isinstance(source, PushSource) else None),
            "pairs": stats.get("pairs", 0),
            "dropped_skew": stats.get("dropped_skew", 0),
            "dropped_backpressure": stats.get("dropped_backpressure", 0),
            "rejected": stats.get("rejected", 0),
            "last_skew_ms": stats.get("last_skew_ms"),
            "max_skew_ms": stats.get("max_skew_ms"),
            "max_skew_ms_allowed": self.settings.stream_max_skew_ms,
            "received": source.received if isinstance(source, PushSource) else None,
        }
