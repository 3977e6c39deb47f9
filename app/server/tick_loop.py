"""Fixed-rate tick loop: ``sim.step()`` (render → pipeline → filter → controller → dynamics)
then publish. No FastAPI here: the loop runs in its own thread and hands records to
subscribers (history, WebSocket hub, 3-D scene, recorder).

A late tick is dropped and counted, never queued: when a step overruns the period the
missed deadlines are skipped. The clock is injectable (:class:`FakeClock`) so that tests can
step the loop deterministically with :meth:`TickLoop.run_iterations`.

A *paced* source (``source.paced``: the simulation worker process,
:mod:`app.server.sim_process`) keeps the schedule itself, by the same rule, and its
``step()`` returns each tick when the source releases it at its deadline: the loop thread
then only relays (converts, publishes), and the source's missed deadlines are counted here.

Step latency (``timings_ms["step"]``, the ``/metrics`` stage ``step``): the time from the
deadline a tick serves to its result being available: for a paced source, from the worker's
deadline to the worker releasing the tick (computed ahead or, if late, just finished); for an
in-process source, from the loop's deadline to ``step()`` returning (the thread's lateness in
waking up included). ``timings_ms["relay"]`` (paced sources): from the deadline to the record
being ready to publish in this process (``timings_ms["recv"]``: its part from the release to
this process having read the tick).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from app.server.schemas import Control, Guidance, SimConfig, StreamInfo, TickRecord

log = logging.getLogger(__name__)

MAX_CONSECUTIVE_ERRORS = 10  # then the simulated stream stops (healthz shows last_error)
STAGES = ("preprocess", "extract", "describe", "match", "triangulate", "pose", "total")


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


class StepSource(Protocol):
    """What the loop drives: :class:`app.sim.docking.DockingSimulation` satisfies it.

    Optional: ``paced = True`` (the source keeps the schedule: ``step()`` blocks until its
    next deadline's tick, which carries ``deadline_s``, ``released_s`` on the monotonic clock
    and ``missed_deadlines``) and ``pause()`` (stop that schedule; called by ``stop_sim``)."""

    @property
    def done(self) -> bool: ...

    def step(self) -> Any: ...


SourceFactory = Callable[[SimConfig, Any], StepSource]


class SourceRestarted(RuntimeError):
    """Raised by ``step()`` of a source whose backend was lost and has been rebuilt from its
    config (e.g. a crashed simulation worker process): this step failed (an error is counted)
    and the next one starts a new run (``TickLoop.run`` is incremented)."""


class SourceUnavailable(RuntimeError):
    """A source could not be built because its backend is unavailable (not a refused config)."""


def docking_config(config: SimConfig) -> Any:
    """The :class:`app.sim.docking.DockingConfig` for a service :class:`SimConfig`."""
    from app.sim.docking import DockingConfig

    return DockingConfig(
        plant=config.plant,
        turbulence=config.turbulence,
        seed=config.seed,
        closure_speed_mps=config.closure_speed_mps,
        tick_hz=config.tick_hz,
        vision=config.vision,
        matcher=config.matcher,
        noise_sigma=config.noise_sigma,
        clutter=config.clutter,
        led_dropout=tuple(config.led_dropout),
    )


def default_source_factory(config: SimConfig, calibration: Any) -> StepSource:
    """Build the docking simulation (vision in the loop) for ``config``, in this process."""
    from app.sim.docking import DockingSimulation

    return DockingSimulation(docking_config(config), calibration=calibration)


def _vec(value: Any) -> tuple[float, float, float] | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float).ravel()
    if arr.size != 3 or not np.all(np.isfinite(arr)):
        return None
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _finite(value: Any) -> float | None:
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def tick_to_record(tick: Any, *, seq: int, clock_s: float, run: int, step_ms: float) -> TickRecord:
    """Convert a ``DockingTick`` or a stream's ``StreamTick`` (duck-typed) to the published
    :class:`TickRecord`."""
    pose = getattr(tick, "pose", None)
    timings: dict[str, float] = {"step": step_ms}
    if pose is not None:
        for name, value in pose.timing_ms.model_dump().items():
            timings[name] = float(value)
    extra = getattr(tick, "extra_timings_ms", None)  # e.g. "sim": the worker process's step
    if extra:
        for name, value in extra.items():
            timings[name] = float(value)
    ctrl = getattr(tick, "control", None)
    control = None
    if ctrl is not None:
        c = np.asarray(ctrl, dtype=float).ravel()
        if c.size >= 4:
            control = Control(
                throttle=float(c[0]), aileron=float(c[1]), elevator=float(c[2]), rudder=float(c[3])
            )
    leds = getattr(tick, "led_truth_cam_mm", None)
    uav = getattr(tick, "uav_state", None)
    miss = getattr(tick, "miss_m", None)
    captured = getattr(tick, "captured", None)
    source = getattr(tick, "source", "sim")
    guidance = stream = None
    if source != "sim":  # a camera stream (app.streams.processor.StreamTick)
        g = tick.guidance
        guidance = Guidance(
            closure_speed_mps=_finite(g.closure_speed_mps),
            predicted_miss_m=_finite(g.predicted_miss_m),
            time_to_contact_s=_finite(g.time_to_contact_s),
            drogue_velocity_mps=_vec(g.drogue_velocity_mps),
            coast_s=float(g.coast_s) if math.isfinite(g.coast_s) else 0.0,
        )
        info = getattr(tick, "stream", None)
        stream = StreamInfo.model_validate(info) if info else None
        miss = None  # the predicted miss is guidance, not a measured crossing
    return TickRecord(
        seq=seq,
        source=source,
        t_s=float(getattr(tick, "t_s", 0.0)),
        clock_s=clock_s,
        wall_time=time.time(),
        run=run,
        phase=getattr(tick, "phase", None),
        pose=pose,
        lock=bool(getattr(tick, "lock", pose.lock if pose is not None else False)),
        lock_reason=getattr(tick, "lock_reason", pose.reason if pose is not None else None),
        drogue_truth_m=_vec(getattr(tick, "drogue_truth_m", None)),
        drogue_normal=_vec(getattr(tick, "drogue_normal", None)),
        drogue_measured_m=_vec(getattr(tick, "drogue_measured_m", None)),
        drogue_estimate_m=_vec(getattr(tick, "drogue_estimate_m", None)),
        probe_tip_m=_vec(getattr(tick, "probe_tip_m", None)),
        rel_position_m=_vec(getattr(tick, "rel_position_m", None)),
        reference_m=_vec(getattr(tick, "reference_m", None)),
        uav_state=None if uav is None else [float(x) for x in np.asarray(uav).ravel()],
        control=control,
        captured=None if captured is None else bool(captured),
        miss_m=None if miss is None or not math.isfinite(float(miss)) else float(miss),
        led_truth_cam_mm=(
            None
            if leds is None
            else [(float(p[0]), float(p[1]), float(p[2])) for p in np.asarray(leds)]
        ),
        timings_ms=timings,
        guidance=guidance,
        stream=stream,
    )


Subscriber = Callable[[TickRecord, Any], None]
"""Called in the loop thread with the record and the raw tick (images; ``None`` for uploads)."""


TICK_THREAD_NICE = -10  # the tick thread's nice value where the process may raise it
SERVICE_NICE = -5  # the web server's other threads (app.server.main), where permitted
RT_PRIORITY = 1  # SCHED_RR priority asked for (the lowest real-time level)


def raise_thread_priority(nice: int, *, realtime: bool = False) -> str:
    """Raise the calling thread's CPU priority where permitted (Linux: each thread has its
    own; threads it starts later inherit it), silently keeping the default elsewhere.

    ``realtime``: ``SCHED_RR`` at :data:`RT_PRIORITY` first (root or CAP_SYS_NICE; the
    kernel's real-time throttling still leaves ≥ 5 % of each CPU to the others); then nice
    ``nice`` (never lowered). Returns what was obtained: ``"rr"``, ``"nice"`` or
    ``"default"``."""
    try:
        tid = threading.get_native_id()
    except AttributeError:  # pragma: no cover - no native thread ids
        return "default"
    if realtime:
        try:
            os.sched_setscheduler(tid, os.SCHED_RR, os.sched_param(RT_PRIORITY))
            return "rr"
        except (OSError, AttributeError):
            pass
    try:
        if os.getpriority(os.PRIO_PROCESS, tid) > nice:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        return "nice"
    except (OSError, AttributeError):
        return "default"


class TickLoop:
    """Runs the simulated stream at a fixed rate in a dedicated thread and publishes records."""

    def __init__(
        self,
        config: SimConfig,
        calibration: Any,
        *,
        source_factory: SourceFactory = default_source_factory,
        clock: Clock | None = None,
        history_s: float = 60.0,
        auto_restart_s: float | None = 3.0,
        realtime: bool = False,
    ) -> None:
        """``realtime``: the tick thread asks for ``SCHED_RR`` (else nice −10): for a thread
        that only relays a paced source's ticks (it would compete at that level otherwise)."""
        self.clock: Clock = clock or MonotonicClock()
        self.realtime = realtime
        self.priority: str | None = None  # what the tick thread obtained
        self._factory = source_factory
        self._config = config
        self._calibration = calibration
        self._auto_restart_s = auto_restart_s
        self._history_s = history_s
        self._lock = threading.RLock()  # guards the source and config
        self._pub_lock = threading.Lock()  # guards seq + subscribers
        self._subscribers: list[Subscriber] = []
        self._source: StepSource | None = None
        self.running = False
        self.run = 0
        self._done_at: float | None = None
        self._seq = 0
        # metrics
        self.ticks = 0
        self.dropped = 0
        self.errors = 0
        self._consecutive_errors = 0
        self.last_error: str | None = None
        self._tick_times: deque[float] = deque(maxlen=256)
        self.stage_ms: dict[str, deque[float]] = {}
        self.last_tick_clock: float | None = None
        self._history: deque[TickRecord] = deque(maxlen=self._history_len())
        self.latest: TickRecord | None = None
        # thread
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._next_t: float | None = None
        self.heartbeat: float | None = None
        self.started_at: float | None = None
        self.before_start_sim: Callable[[], None] | None = None

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
    def calibration(self) -> Any:
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
            hist = list(self._history)
            self._history = deque(hist, maxlen=self._history_len())
            self._source = source
            self.run += 1
            self._done_at = None

    def set_calibration(self, calibration: Any) -> None:
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
        (``before_start_sim``, set by ``app.server.stream_service``): one source at a time."""
        hook = self.before_start_sim
        if hook is not None:
            hook()
        with self._lock:
            if self._source is None or self._source.done:
                self._rebuild()
            self.running = True

    def stop_sim(self) -> None:
        with self._lock:
            self.running = False
            pause = getattr(self._source, "pause", None)
            if pause is not None:
                pause()  # a paced source stops its schedule

    # ---- publication --------------------------------------------------------------
    def subscribe(self, fn: Subscriber) -> None:
        with self._pub_lock:
            self._subscribers.append(fn)

    def unsubscribe(self, fn: Subscriber) -> None:
        with self._pub_lock:
            if fn in self._subscribers:
                self._subscribers.remove(fn)

    def next_seq(self) -> int:
        with self._pub_lock:
            self._seq += 1
            return self._seq

    def publish(self, record: TickRecord, raw: Any = None) -> None:
        """Store and fan out a record (sim ticks and uploads alike)."""
        t0 = time.perf_counter()
        self.latest = record
        self._history.append(record)
        with self._pub_lock:
            subs = list(self._subscribers)
        for fn in subs:
            try:
                fn(record, raw)
            except Exception:  # a broken subscriber must not stop the loop
                log.exception("tick subscriber failed")
        self._add_stage("publish", (time.perf_counter() - t0) * 1e3)

    def publish_stream(self, record: TickRecord, raw: Any = None) -> None:
        """Publish a record of a camera stream (its own thread, its own pace: see
        ``app.server.stream_service``); its stage timings join the loop's metrics."""
        for name, value in record.timings_ms.items():
            self._add_stage(name, value)
        self.publish(record, raw)

    def history(self, seconds: float | None = None) -> list[TickRecord]:
        items = list(self._history)
        if seconds is None:
            return items
        cutoff = self.clock.now() - seconds
        return [r for r in items if r.clock_s >= cutoff]

    def _add_stage(self, name: str, ms: float) -> None:
        dq = self.stage_ms.get(name)
        if dq is None:
            dq = self.stage_ms[name] = deque(maxlen=512)
        dq.append(ms)

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
            self._consecutive_errors = 0

    def tick(self, deadline: float | None = None) -> TickRecord | None:
        """Step the simulation once and publish; ``None`` if not running or finished.

        ``deadline``: the loop clock's deadline this tick serves (the scheduler's; ``None``
        when called directly) — the step latency starts there. A paced source's ``step()``
        (a wait of up to a period) runs outside the loop's lock, so that ``set_config`` or
        ``stop_sim`` never wait for it; a tick of a source replaced or stopped meanwhile is
        dropped, not published."""
        with self._lock:
            now = self.clock.now()
            if not self.running:
                return None
            if self._source is None:
                self._rebuild()
            src = self._source
            assert src is not None
            if src.done:
                if self._done_at is None:
                    self._done_at = now
                if self._auto_restart_s is not None and now - self._done_at >= self._auto_restart_s:
                    self.reset(seed=self._config.seed + 1)
                    src = self._source
                    assert src is not None
                else:
                    return None
            paced = bool(getattr(src, "paced", False))
            if not paced:
                t0 = time.perf_counter()
                try:
                    raw = src.step()
                except Exception as exc:
                    self._step_failed(exc)
                    return None
                late_s = 0.0 if deadline is None else max(0.0, now - deadline)
                step_ms = (late_s + time.perf_counter() - t0) * 1e3
        if paced:
            try:
                raw = src.step()  # the source's next deadline's tick
            except Exception as exc:
                with self._lock:
                    if src is self._source and self.running:
                        self._step_failed(exc)
                return None  # else: stopped or replaced while waiting, not an error
        with self._lock:
            if paced:
                if src is not self._source or not self.running:
                    return None
                step_ms = (raw.released_s - raw.deadline_s) * 1e3
                self.dropped += int(raw.missed_deadlines)
            self._consecutive_errors = 0
            run = self.run
        record = tick_to_record(
            raw, seq=self.next_seq(), clock_s=self.clock.now(), run=run, step_ms=step_ms
        )
        if paced:  # the source's deadline is on the monotonic clock
            record.timings_ms["relay"] = (time.monotonic() - raw.deadline_s) * 1e3
            received = getattr(raw, "received_s", None)
            if received is not None:  # released → read here (pipe, wake-up, GIL)
                record.timings_ms["recv"] = (received - raw.released_s) * 1e3
        for name, value in record.timings_ms.items():
            self._add_stage(name, value)
        self.publish(record, raw)
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
        if self.running and src is not None and getattr(src, "paced", False) and not src.done:
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
        deadline = self._next_t
        self._next_t += period
        self.tick(deadline)

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

    def stage_quantiles(self, q: float) -> dict[str, float]:
        out: dict[str, float] = {}
        for name, dq in list(self.stage_ms.items()):
            vals = list(dq)
            if vals:
                out[name] = float(np.quantile(vals, q))
        return out
