"""Camera streams in the service: the active frame source and its loop thread.

The simulation is stepped by the fixed-rate :class:`~app.service.tick_loop.TickLoop`; a frame
source (video, camera, push: :mod:`app.streams`) runs at its *own* pace in a dedicated thread
(``aar-stream``): read a pair (decoding in OpenCV, which releases the GIL), track it,
filter, compute guidance (:class:`~app.streams.processor.StreamProcessor`), then publish the
record on the telemetry bus (history, WebSocket hub, 3-D scene, recorder).
Nothing of this runs on the web server's event loop; the push WebSocket handler only parses
the message header and hands the bytes over (the newest pair is kept).

One source is active at a time: switching to a stream stops the simulated stream, switching
back to ``sim`` restarts it. The controller runs only with the simulation (it needs the
receiver's own state); a real autopilot feed would be another source of own state.

Supervision: a source that stops — its thread exits, ``AAR_STREAM_FAILURE_STREAK``
pairs in a row fail (undecodable, refused, processing error), a camera stops delivering, or a
pushed pair waits unread for ``AAR_STREAM_STALL_S`` — is reopened by a watchdog thread
(``aar-stream-watchdog``) after a back-off (``AAR_STREAM_RESTART_BACKOFF_S``, doubling up to
``AAR_STREAM_RESTART_BACKOFF_MAX_S``; back to the start after a source ran 30 s). Meanwhile
:meth:`StreamService.health` says ``degraded`` with the reason (``/healthz``, ``/metrics``,
the page), and a pusher into the failed source is closed with 1013 and the reason. A file
whose data turns out corrupt mid-way (:class:`~app.streams.frames.SourceCorrupt`: an MCAP
message that does not parse) is not reopened — it would meet the same bytes — but stays
``failed`` and ``degraded`` with the reason; only a clean end of file is ``ended``.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from app.model.tick import StreamInfo
from app.service import records
from app.service.limits import ConcurrencyLimit
from app.service.settings import Settings
from app.service.telemetry_bus import TelemetryBus
from app.service.tick_loop import TickLoop
from app.streams.frames import EndOfStream, SourceCorrupt, SourceError
from app.streams.processor import StreamProcessor
from app.streams.protocol import PushMessage
from app.streams.sources import (
    FrameSourceT,
    PushSource,
    PutResult,
    SourceOptions,
    SourceSpec,
    open_source,
    parse_source,
)
from app.types import JsonObject
from app.vision.drogue import DrogueProfile

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration

log = logging.getLogger(__name__)
STABLE_S = 30.0  # a source that ran this long before failing restarts after the first back-off
WATCHDOG_PERIOD_S = 0.1
LOG_INTERVAL_S = 5.0  # repeated failures of one run: one log line per interval
PushOutcome = PutResult | Literal["not_push", "restarting"]


@dataclass(frozen=True)
class SourceHealth:
    """The active frame source as ``/healthz`` reports it (component ``stream``)."""

    source: str
    status: Literal["ok", "degraded"]
    reason: str | None
    rate_hz: float


class StreamService:
    def __init__(
        self,
        loop: TickLoop,
        calibration: StereoCalibration,
        settings: Settings,
        bus: TelemetryBus | None = None,
    ) -> None:
        """``loop``: the simulation (stopped while a stream runs, and started to switch back);
        ``bus``: where the stream's records go (default: the loop's)."""
        self.loop = loop
        self.bus = loop.bus if bus is None else bus
        self.settings = settings
        self._calibration = calibration
        self.drogue = settings.drogue_profile()  # the configured drogue (AAR_DROGUE)
        self.active_drogue = self.drogue  # the running stream's (a recording's own)
        self._lock = threading.RLock()  # switching, stopping, restarting (joins threads)
        self._flock = threading.Lock()  # the failure fields (taken by the stream thread)
        self.source: FrameSourceT | None = None
        self.processor: StreamProcessor | None = None
        self.spec = "sim"
        self.state = "sim"  # sim | running | restarting | ended | failed
        self.last_error: str | None = None
        self.errors = 0
        self.frames = 0
        self.started_wall: float | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        # supervision
        self._parsed: SourceSpec | None = None
        self._options: SourceOptions | None = None
        self.generation = 0  # one per (re)opened source
        self._epoch: int | None = None  # the running source's in bus.sources
        self.restarts = 0
        self.streak = 0  # failed pairs since the last good one (across restarts)
        self.failure: str | None = None  # why the source is restarting (None: it is not)
        self._failed: dict[int, str] = {}  # generation → why it failed (pushers are told)
        self._restart_at: float | None = None
        self._backoff_s = settings.stream_restart_backoff_s
        self._run_started = time.monotonic()
        self._last_delivered = time.monotonic()
        self._wake = threading.Event()
        self._closed = threading.Event()
        self._watchdog: threading.Thread | None = None
        self.push_slots = ConcurrencyLimit("pushers", settings.push_max_clients, 1)
        loop.before_start_sim = self._on_sim_start

    def _on_sim_start(self) -> None:
        """``POST /sim/start`` (or the scene's button) while a stream runs: back to sim."""
        with self._lock:
            if self.source is not None or self._parsed is not None:
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
    ) -> JsonObject:
        """Make ``spec_text`` the active source; :class:`SourceError` (nothing changed) if it
        cannot be opened."""
        spec = parse_source(spec_text)
        if restricted:
            self._check_roots(spec)
        with self._lock:
            if spec.kind is None:
                self.loop.start_sim()  # stops the stream first (_on_sim_start)
                return self.status()
            options = self.options(realtime=realtime, loop=loop)
            source = open_source(spec, options)
            self._stop_stream()
            self.loop.stop_sim()
            with self._flock:
                self._parsed, self._options = spec, options
                self.failure = None
                self._failed.clear()
            self.errors = self.frames = self.restarts = self.streak = 0
            self.last_error = None
            self._backoff_s = self.settings.stream_restart_backoff_s
            self.started_wall = time.time()
            self._start(source)
            self._ensure_watchdog()
            log.info("frame source %s started", source.spec)
            return self.status()

    def _start(self, source: FrameSourceT) -> None:
        """Run ``source`` in a new stream thread (under ``self._lock``)."""
        self.source = source
        # a frame recording replays with the calibration it was recorded with
        calibration = getattr(source, "calibration", None) or self._calibration
        if calibration is not self._calibration:
            log.info("%s: using the recording's own calibration", source.spec)
        # ... and with the drogue it was recorded with
        self.active_drogue = getattr(source, "drogue", None) or self.drogue
        self.processor = StreamProcessor(calibration, self.active_drogue.pipeline_config())
        self.spec = source.spec
        with self._flock:
            self.state = "running"
            self.generation += 1
            self._restart_at = None
        self._run_started = self._last_delivered = time.monotonic()
        self._stop = stop = threading.Event()
        self._epoch = epoch = self.bus.sources.begin(source.kind)
        self._thread = threading.Thread(
            target=self._run,
            args=(source, self.processor, stop, self.generation, epoch),
            name="aar-stream",
            daemon=True,
        )
        self._thread.start()

    def _stop_source(self, join_s: float = 5.0) -> None:
        thread, source = self._thread, self.source
        self._stop.set()
        if self._epoch is not None:  # from now on nothing of this run goes out (MAVLink)
            self.bus.sources.end(self._epoch)
            self._epoch = None
        if source is not None and isinstance(source, PushSource):
            source.close()  # wakes a waiting read
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=join_s)
        if source is not None:
            source.close()
        self._thread = None
        self.source = None
        self.processor = None

    def _stop_stream(self) -> None:
        self._stop_source()
        with self._flock:
            self._parsed = self._options = None
            self.failure = None
            self._restart_at = None

    def set_calibration(self, calibration: StereoCalibration) -> None:
        with self._lock:
            self._calibration = calibration
            if self.processor is not None:
                self.processor.set_calibration(calibration)

    def close(self) -> None:
        self._closed.set()
        self._wake.set()
        with self._lock:
            self._stop_stream()
        if self._watchdog is not None:
            self._watchdog.join(timeout=2.0)
            self._watchdog = None

    # ---- supervision ----------------------------------------------------------------
    def _ensure_watchdog(self) -> None:
        if self._watchdog is None or not self._watchdog.is_alive():
            self._watchdog = threading.Thread(
                target=self._watch, name="aar-stream-watchdog", daemon=True
            )
            self._watchdog.start()

    def _fail(self, generation: int, reason: str, stop: threading.Event | None = None) -> None:
        """The run ``generation`` stopped for ``reason``: restart it after the back-off."""
        with self._flock:
            if (
                generation != self.generation
                or self._parsed is None
                or self.failure
                or (stop is not None and stop.is_set())
            ):
                return  # replaced, switched away, stopped or already restarting
            now = time.monotonic()
            if now - self._run_started >= STABLE_S:
                self._backoff_s = self.settings.stream_restart_backoff_s
            delay = self._backoff_s
            self._backoff_s = min(2.0 * delay, self.settings.stream_restart_backoff_max_s)
            self.failure = reason
            self._failed[generation] = reason
            while len(self._failed) > 16:
                self._failed.pop(next(iter(self._failed)))
            self.state = "restarting"
            self._restart_at = now + delay
            log.warning(
                "frame source %s stopped (%s); restarting in %.2g s", self.spec, reason, delay
            )
        self._wake.set()

    def _watch(self) -> None:
        while not self._closed.is_set():
            self._wake.wait(WATCHDOG_PERIOD_S)
            self._wake.clear()
            try:
                self._check()
            except Exception:  # pragma: no cover - the watchdog must outlive a bug
                log.exception("stream watchdog check failed")

    def _check(self) -> None:
        with self._flock:
            if self._parsed is None:
                return
            gen, thread, source = self.generation, self._thread, self.source
            restart_at = self._restart_at
        if restart_at is None:
            stalled = self._stalled(source)
            # (a thread not started yet — ident None — is a switch in progress: _start
            # publishes the new generation and thread before it starts it)
            exited = thread is not None and thread.ident is not None and not thread.is_alive()
            if exited and self.state == "running":
                self._fail(gen, "the stream thread exited")
            elif stalled is not None:
                self._fail(gen, stalled)
            return
        if time.monotonic() < restart_at:
            return
        with self._lock:
            if self._parsed is None or self._restart_at is None:
                return
            self._stop_source(join_s=1.0)
            assert self._options is not None
            try:
                source = open_source(self._parsed, self._options)
            except SourceError as exc:
                with self._flock:
                    delay = self._backoff_s
                    self._backoff_s = min(2.0 * delay, self.settings.stream_restart_backoff_max_s)
                    self.failure = f"cannot reopen {self.spec}: {exc}"
                    self._restart_at = time.monotonic() + delay
                return
            self.restarts += 1
            with self._flock:
                self.failure = None
            self._start(source)
            log.info("frame source %s restarted (restart %d)", source.spec, self.restarts)

    def _stalled(self, source: FrameSourceT | None) -> str | None:
        """Why a running source that should deliver pairs does not (None: it does)."""
        if source is None or self.state != "running":
            return None
        limit = self.settings.stream_stall_s
        if isinstance(source, PushSource):
            age = source.pending_age_s()
            if age is not None and age > limit:
                return f"a pushed pair waited {age:.1f} s unread (AAR_STREAM_STALL_S={limit:g})"
            return None
        idle = time.monotonic() - self._last_delivered
        if idle > limit:
            return f"no frames for {idle:.1f} s (AAR_STREAM_STALL_S={limit:g})"
        return None

    def failure_of(self, generation: int) -> str | None:
        """Why the run ``generation`` failed (None: it did not)."""
        with self._flock:
            return self._failed.get(generation)

    def drogue_in_use(self) -> DrogueProfile:
        """The drogue the active source's navigation looks for: the simulation's while it is
        the source, else the stream's (a recording's own, or the configured one)."""
        with self._flock:
            if self._parsed is None:
                return self.loop.config.drogue
        return self.active_drogue

    def health(self) -> SourceHealth | None:
        """The active stream's health; None while the simulation is the source."""
        with self._flock:
            if self._parsed is None:
                return None
            source, state, failure, streak = self.source, self.state, self.failure, self.streak
            restart_at, spec = self._restart_at, self.spec
        rate = round(source.stats.fps(), 3) if source is not None and state == "running" else 0.0
        limit = self.settings.stream_failure_streak
        reason: str | None = None
        if state == "failed":  # corrupt data: final, a restart would meet it again
            reason = f"{spec}: {self.last_error}"
        elif failure is not None:
            wait = 0.0 if restart_at is None else max(0.0, restart_at - time.monotonic())
            reason = f"{spec}: restarting in {wait:.1f} s after: {failure}"
        elif streak >= limit:
            last = self.last_error or (
                source.last_error if isinstance(source, PushSource) else None
            )
            reason = f"{spec}: the last {streak} pairs failed (last: {last})"
        elif (stalled := self._stalled(source)) is not None:
            reason = f"{spec}: {stalled}"
        return SourceHealth(spec, "ok" if reason is None else "degraded", reason, rate)

    # ---- the stream thread ----------------------------------------------------------
    def _run(
        self,
        source: FrameSourceT,
        processor: StreamProcessor,
        stop: threading.Event,
        gen: int,
        epoch: int,
    ) -> None:
        consecutive = 0  # failures of this run (the restart rule)
        rejected = source.stats.rejected
        last_log = 0.0
        limit = self.settings.stream_failure_streak

        def failed(reason: str, exc: BaseException | None = None) -> bool:
            """Count a failed pair; True when this run must stop (the streak is reached)."""
            nonlocal consecutive, last_log
            consecutive += 1
            self.streak += 1
            now = time.monotonic()
            if exc is not None and (consecutive == 1 or now - last_log >= LOG_INTERVAL_S):
                last_log = now
                log.error(
                    "frame source %s: pair failed (%d in a row): %s",
                    source.spec,
                    consecutive,
                    reason,
                    exc_info=exc if consecutive == 1 else None,
                )
            if consecutive >= limit:
                self._fail(gen, f"{consecutive} consecutive failed pairs (last: {reason})", stop)
                return True
            return False

        while not stop.is_set():
            try:
                frame = source.read(timeout_s=0.25)
                now_rejected = source.stats.rejected
                if now_rejected > rejected:  # refused by the push handler or undecodable
                    n, rejected = now_rejected - rejected, now_rejected
                    why = (
                        source.last_error if isinstance(source, PushSource) else None
                    ) or "rejected"
                    if any(failed(why) for _ in range(n)):
                        return
                if frame is None:
                    continue
                t0 = time.perf_counter()
                tick = processor.process(frame, source.kind)
                timings = dict(tick.extra_timings_ms)
                if source.kind == "camera":  # grab time on this machine's monotonic clock
                    timings["frame_age"] = (time.monotonic() - frame.t_s) * 1e3
                stats = source.stats
                info = StreamInfo(
                    spec=source.spec,
                    frame=frame.seq,
                    frame_t_s=frame.t_s,
                    mode=tick.mode,
                    fps=round(stats.fps(), 3),
                    pairs=stats.pairs,
                    dropped_skew=stats.dropped_skew,
                    dropped_backpressure=stats.dropped_backpressure,
                    skew_ms=stats.last_skew_ms,
                )
                step_ms = (time.perf_counter() - t0) * 1e3
                if stop.is_set():
                    break
                self.bus.publish(
                    records.from_stream(tick, info, step_ms=step_ms, extra_timings_ms=timings),
                    run=self.loop.run,
                    epoch=epoch,
                )
                self.frames += 1
                consecutive = self.streak = 0
                self._last_delivered = time.monotonic()
            except EndOfStream as exc:
                if stop.is_set():
                    return
                if source.kind == "video":  # a file's end (without --loop): finished
                    self.state = "ended"
                    log.info("frame source %s ended", source.spec)
                else:  # a camera that stopped delivering, a push source closed under us
                    self._fail(gen, f"the source ended: {exc}", stop)
                return
            except SourceCorrupt as exc:
                if stop.is_set():
                    return
                self.errors += 1
                self.last_error = str(exc)
                with self._flock:
                    self.state = "failed"
                log.error("frame source %s failed: %s", source.spec, exc)
                return
            except Exception as exc:
                self.errors += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
                if failed(self.last_error, exc):
                    return
                time.sleep(0.05)

    # ---- push -------------------------------------------------------------------------
    def push(self, message: PushMessage) -> tuple[PushOutcome, int]:
        """Hand a pushed pair to the push source: the outcome and the source's generation
        (``not_push``: another source is active; ``restarting``: wait and reconnect)."""
        with self._flock:
            source, gen, failure = self.source, self.generation, self.failure
            parsed = self._parsed
        if parsed is None or parsed.kind != "push":
            return "not_push", gen
        if failure is not None or not isinstance(source, PushSource):
            return "restarting", gen
        return source.put(message), gen

    def begin_push_session(self) -> None:
        source = self.source
        if isinstance(source, PushSource):
            source.begin_session()

    # ---- status -----------------------------------------------------------------------
    def status(self) -> JsonObject:
        """The active source and its counters (``GET /stream``'s body)."""
        source = self.source
        stats = source.stats.as_dict() if source is not None else {}
        health = self.health()
        return {
            "source": self.spec,
            "kind": source.kind if source is not None else self.spec.split(":")[0],
            "state": self.state,
            "health": "ok" if health is None else health.status,
            "health_reason": None if health is None else health.reason,
            "fps": round(source.stats.fps(), 3) if source is not None else None,
            "frames": self.frames,
            "errors": self.errors,
            "restarts": self.restarts,
            "consecutive_failures": self.streak,
            "last_error": self.last_error
            or (source.last_error if isinstance(source, PushSource) else None),
            "pairs": stats.get("pairs", 0),
            "dropped_skew": stats.get("dropped_skew", 0),
            "dropped_backpressure": stats.get("dropped_backpressure", 0),
            "rejected": stats.get("rejected", 0),
            "seq_duplicate": stats.get("seq_duplicate", 0),
            "seq_out_of_order": stats.get("seq_out_of_order", 0),
            "last_skew_ms": stats.get("last_skew_ms"),
            "max_skew_ms": stats.get("max_skew_ms"),
            "max_skew_ms_allowed": self.settings.stream_max_skew_ms,
            "received": source.received if isinstance(source, PushSource) else None,
            "pushers": self.push_slots.in_use,
        }
