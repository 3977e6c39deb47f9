"""Fixed-rate tick loop: ``sim.step()`` (render → pipeline → filter → controller → dynamics)
then publish. No FastAPI here: the loop runs in its own thread and hands each tick to the
:class:`~app.service.telemetry_bus.TelemetryBus` (history, WebSocket hub, 3-D scene, recorder).

The source (:class:`~app.service.sim_source.PacedSource`: the simulation worker,
:mod:`app.service.sim_worker`) keeps the schedule itself: a late tick is dropped and counted,
never queued (when a step overruns the period the missed deadlines are skipped), and its
``step()`` returns each tick when the source releases it at its deadline: the loop thread only
relays (converts, publishes) and counts the source's missed deadlines. While nothing runs (the
simulation stopped, or finished and waiting to restart) the loop keeps a schedule of its own
on its clock. The clock is injectable (:class:`~app.service.clock.FakeClock`, with a worker
on the same clock: ``tests/support/inline_sim.py``) so that tests can step the loop
deterministically with :meth:`TickLoop.run_iterations`.

Step latency (``timings_ms["step"]``, the ``/metrics`` stage ``step``): the time from the
worker's deadline a tick serves to the worker releasing it (computed ahead or, if late, just
finished). ``timings_ms["relay"]``: from the deadline to the record being ready to publish in
this process (``timings_ms["recv"]``: its part from the release to this process having read
the tick).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from app.model.tick import TickRecord
from app.service import records
from app.service.clock import Clock, MonotonicClock
from app.service.records import PacedTiming
from app.service.sim_source import PacedSource, SourceFactory, SourceRestarted
from app.service.sim_worker.priority import raise_thread_priority
from app.service.telemetry_bus import TelemetryBus
from app.sim.sim_config import SimConfig

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration

log = logging.getLogger(__name__)

MAX_CONSECUTIVE_ERRORS = 10  # then the simulated stream stops (healthz shows last_error)
TICK_THREAD_NICE = -10  # the tick thread's nice value where the process may raise it


@dataclass(frozen=True)
class Stepped:
    """One step's tick, the run it belongs to and the simulation's source epoch then."""

    tick: records.Tick
    run: int
    epoch: int | None


class TickLoop:
    """Runs the simulated stream at a fixed rate in a dedicated thread; its ticks go to the bus.

    Also the simulation's lifecycle: its config and calibration (each change builds a new
    source: a new ``run``), start / stop / reset, the restart after a finished run, and the
    count of failed steps."""

    def __init__(
        self,
        config: SimConfig,
        calibration: StereoCalibration | None,
        *,
        source_factory: SourceFactory,
        clock: Clock | None = None,
        history_s: float = 60.0,
        auto_restart_s: float | None = 3.0,
        realtime: bool = False,
        bus: TelemetryBus | None = None,
    ) -> None:
        """``source_factory``: builds the simulation's source for a config (the worker's
        :func:`~app.service.sim_worker.proxy.process_source_factory`); ``realtime``: the tick thread asks for ``SCHED_RR`` (else nice −10): for a thread
        that only relays a paced source's ticks (it would compete at that level otherwise).
        ``bus``: where the ticks are published (default: a bus of its own on ``clock``, which
        keeps ``history_s`` of ticks)."""
        self.clock: Clock = clock or MonotonicClock()
        self.realtime = realtime
        self.priority: str | None = None  # what the tick thread obtained
        self._factory = source_factory
        self._config = config
        self._calibration = calibration
        self._auto_restart_s = auto_restart_s
        self._history_s = history_s
        self.bus = bus if bus is not None else TelemetryBus(self.clock, self._history_len())
        self._lock = threading.RLock()  # guards the source and config
        self._source: PacedSource | None = None
        self.running = False
        self.run = 0
        self._done_at: float | None = None
        # metrics
        self.ticks = 0
        self.dropped = 0
        self.errors = 0
        self._consecutive_errors = 0
        self.last_error: str | None = None
        self._tick_times: deque[float] = deque(maxlen=256)
        self.last_tick_clock: float | None = None
        # thread
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._next_t: float | None = None
        self.heartbeat: float | None = None
        self.started_at: float | None = None
        self.before_start_sim: Callable[[], None] | None = None
        self._epoch: int | None = None  # the simulation's in bus.sources while it runs

    # ---- configuration ------------------------------------------------------------
    def _history_len(self) -> int:
        return max(16, int(self._history_s * self._config.tick_hz) + 1)

    @property
    def period_s(self) -> float:
        return 1.0 / self._config.tick_hz

    @property
    def config(self) -> SimConfig:
        return self._config

    @property
    def calibration(self) -> StereoCalibration | None:
        return self._calibration

    @property
    def done(self) -> bool:
        src = self._source
        return bool(src is not None and src.done)

    def set_config(self, config: SimConfig) -> None:
        """Apply a new config: the simulation is rebuilt (a new run).

        The new simulation is built first: if that raises (e.g. ``ValueError``), the running
        one and its config are kept and the exception propagates.
        """
        with self._lock:
            source = self._factory(config, self._calibration)
            self._config = config
            self.bus.set_history_len(self._history_len())
            self._source = source
            self.run += 1
            self._done_at = None

    def set_calibration(self, calibration: StereoCalibration) -> None:
        with self._lock:
            source = self._factory(self._config, calibration)
            self._calibration = calibration
            self._source = source
            self.run += 1
            self._done_at = None

    def _rebuild(self) -> None:
        self._source = self._factory(self._config, self._calibration)
        self.run += 1
        self._done_at = None

    def reset(self, seed: int | None = None) -> None:
        """Start a new run (same config; optionally a new seed)."""
        with self._lock:
            if seed is not None:
                self._config = self._config.model_copy(update={"seed": seed})
            self._rebuild()

    def start_sim(self) -> None:
        """Run the simulated stream; a camera stream that is active is stopped first
        (``before_start_sim``, set by ``app.service.stream_service``): one source at a time."""
        hook = self.before_start_sim
        if hook is not None:
            hook()
        with self._lock:
            if self._source is None or self._source.done:
                self._rebuild()
            self.running = True
            self._epoch = self.bus.sources.begin("sim")

    def _end_epoch(self) -> None:
        """The simulation is no longer the active source (under ``self._lock``)."""
        if self._epoch is not None:
            self.bus.sources.end(self._epoch)
            self._epoch = None

    def stop_sim(self) -> None:
        with self._lock:
            self.running = False
            self._end_epoch()
            if self._source is not None:
                self._source.pause()  # the worker stops its schedule

    # ---- one tick -----------------------------------------------------------------
    def _step_failed(self, exc: Exception) -> None:
        """Count a failed step (under ``self._lock``)."""
        self.errors += 1
        self._consecutive_errors += 1
        self.last_error = f"{type(exc).__name__}: {exc}"
        if isinstance(exc, SourceRestarted):  # rebuilt from its config: a new run
            log.error("simulation step failed: %s", self.last_error)
            self.run += 1
            self._done_at = None
        else:
            log.error("simulation step failed", exc_info=exc)
        if self._consecutive_errors >= MAX_CONSECUTIVE_ERRORS:
            log.error("simulation stopped after %d failed steps", MAX_CONSECUTIVE_ERRORS)
            self.running = False
            self._end_epoch()
            self._consecutive_errors = 0

    def _current_source(self, now: float) -> PacedSource | None:
        """The source to step now (rebuilt or restarted as due); ``None``: nothing to step.
        Under ``self._lock``."""
        if not self.running:
            return None
        if self._source is None:
            self._rebuild()
        src = self._source
        assert src is not None
        if not src.done:
            return src
        if self._done_at is None:
            self._done_at = now
        if self._auto_restart_s is not None and now - self._done_at >= self._auto_restart_s:
            self.reset(seed=self._config.seed + 1)
            return self._source
        return None

    def _step_paced(self, src: PacedSource) -> Stepped | None:
        """Wait for a paced source's next tick (outside the loop's lock): the tick and its
        run; ``None`` if the step failed, or if the source was stopped or replaced meanwhile
        (not an error)."""
        try:
            raw = src.step()  # the source's next deadline's tick
        except Exception as exc:
            with self._lock:
                if src is self._source and self.running:
                    self._step_failed(exc)
            return None
        with self._lock:
            if src is not self._source or not self.running:
                return None
            self.dropped += int(raw.missed_deadlines)
            self._consecutive_errors = 0
            run, epoch = self.run, self._epoch
        tick = records.from_sim(
            raw.state,
            step_ms=(raw.released_s - raw.deadline_s) * 1e3,
            extra_timings_ms=raw.extra_timings_ms,
            paced=PacedTiming(raw.deadline_s, raw.released_s, raw.received_s),
            raw=raw,
        )
        return Stepped(tick, run, epoch)

    def tick(self) -> TickRecord | None:
        """Step the simulation once and publish; ``None`` if not running or finished.

        The source's ``step()`` (a wait of up to a period for the worker's next tick) runs
        outside the loop's lock, so that ``set_config`` or ``stop_sim`` never wait for it; a
        tick of a source replaced or stopped meanwhile is dropped, not published."""
        with self._lock:
            src = self._current_source(self.clock.now())
            if src is None:
                return None
        stepped = self._step_paced(src)
        if stepped is None:
            return None
        record = self.bus.publish(stepped.tick, run=stepped.run, epoch=stepped.epoch)
        self.ticks += 1
        t_now = self.clock.now()
        self._tick_times.append(t_now)
        self.last_tick_clock = t_now
        return record

    # ---- the fixed-rate schedule ----------------------------------------------------
    def _iterate(self) -> None:
        """One pass of the scheduler: wait for the deadline, skip missed ones, tick."""
        period = self.period_s
        now = self.clock.now()
        self.heartbeat = now
        src = self._source
        if self.running and src is not None and not src.done:
            self._next_t = None  # the source keeps the schedule: wait for its next tick
            self.tick()
            return
        if self._next_t is None:
            self._next_t = now
        if now < self._next_t:
            self.clock.sleep(min(self._next_t - now, 0.05))
            return
        missed = int((now - self._next_t) / period + 1e-9)
        if missed > 0:
            if self.running:  # a stopped simulation has no ticks to drop (healthz says so)
                self.dropped += missed
            self._next_t += missed * period
        self._next_t += period
        self.tick()

    def run_iterations(self, n: int) -> None:
        """Drive the scheduler synchronously (tests, with a :class:`FakeClock`)."""
        for _ in range(n):
            self._iterate()

    def _run(self) -> None:
        # it wakes up before the server's other threads (and a browser on the same machine)
        self.priority = raise_thread_priority(TICK_THREAD_NICE, realtime=self.realtime)
        while not self._stop.is_set():
            try:
                self._iterate()
            except Exception:
                self.errors += 1
                log.exception("tick loop iteration failed")
                time.sleep(0.05)

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._next_t = None
        self.started_at = self.clock.now()
        self._thread = threading.Thread(target=self._run, name="aar-tick-loop", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout)
            self._thread = None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ---- metrics -----------------------------------------------------------------
    def tick_rate_hz(self, window_s: float = 2.0) -> float:
        times = list(self._tick_times)
        if len(times) < 2:
            return 0.0
        now = self.clock.now()
        recent = [t for t in times if t >= now - window_s]
        if len(recent) < 2:
            return 0.0
        span = recent[-1] - recent[0]
        return (len(recent) - 1) / span if span > 0 else 0.0
