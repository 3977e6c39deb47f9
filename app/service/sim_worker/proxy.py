"""The parent's side of the simulation worker: the process, its pipe and the source proxy.

:class:`SimWorker` owns one persistent worker process (:mod:`app.service.sim_worker.worker`,
started by a :class:`SpawnLauncher`: ``spawn`` context) and its image ring;
:class:`ProcessSimSource` is the paced source the tick loop steps (``step()`` returns the next tick the worker released on
its schedule, ``pause()`` ends the schedule); :func:`process_source_factory` gives the tick
loop's source factory. The messages are listed in :mod:`app.service.sim_worker.wire`.

Failures: every wait on the pipe has a timeout (start-up, build, the next tick); a worker that
died (EOF, exit) or did not answer in time is killed and a new one spawned, the simulation
rebuilt from its last config: the failed ``step()`` raises :class:`WorkerRestarted` (the tick
loop counts an error and starts a new run). The tick thread never waits longer than a timeout.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import TYPE_CHECKING, Protocol, TypeVar

from app.service.lazy_images import ImagePair, LazyImagePair
from app.service.sim_source import SourceRestarted, SourceUnavailable, docking_config
from app.service.sim_worker.image_ring import RING_SLOTS, ImageRing
from app.service.sim_worker.wire import (
    STREAM,
    Build,
    Built,
    ErrorReply,
    Pause,
    Ping,
    Pong,
    Ready,
    Reply,
    Request,
    Run,
    Stop,
    TickError,
    TickMessage,
    WireCalibration,
    calibration_to_wire,
    raise_remote,
)
from app.service.sim_worker.worker import LOOKAHEAD, SimFactory, WorkerSpec, worker_main
from app.sim.sim_config import SimConfig
from app.types import FloatArray, UInt8Array

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration
    from app.sim.docking import DockingTick
    from app.types import Rect

log = logging.getLogger(__name__)


SPAWN = multiprocessing.get_context("spawn")


class WorkerProcess(Protocol):
    """The worker as the parent sees it (a :class:`multiprocessing.process.BaseProcess`)."""

    @property
    def exitcode(self) -> int | None: ...

    def is_alive(self) -> bool: ...
    def kill(self) -> None: ...
    def join(self, timeout: float | None = None) -> None: ...


class ParentConn(Protocol):
    """The parent's end of the pipe (a :class:`multiprocessing.connection.Connection`)."""

    def send(self, obj: Request) -> None: ...
    def recv(self) -> Reply: ...
    def poll(self, timeout: float = 0.0) -> bool: ...
    def close(self) -> None: ...


#: starts a worker for a :class:`WorkerSpec`: the worker and the parent's end of its pipe
WorkerLauncher = Callable[[WorkerSpec], tuple[WorkerProcess, ParentConn]]


@dataclass(frozen=True)
class SpawnLauncher:
    """Starts :func:`~app.service.sim_worker.worker.worker_main` in a ``spawn`` process, the
    one way the service runs its simulation; ``sim_factory`` (picklable; ``None``: the docking
    simulation) builds each simulation in it. Tests inject another launcher (one that runs the
    same :class:`~app.service.sim_worker.worker.WorkerLoop` in their process), not another
    path."""

    sim_factory: SimFactory | None = None

    def __call__(self, spec: WorkerSpec) -> tuple[BaseProcess, Connection]:
        parent, child = SPAWN.Pipe(duplex=True)
        proc = SPAWN.Process(
            target=worker_main,
            args=(child, spec, self.sim_factory),
            name=f"aar-sim-worker-{spec.epoch}",
            daemon=True,
        )
        proc.start()
        child.close()  # so that the worker's death reads as EOF here
        return proc, parent


Answer = TypeVar("Answer", Ready, Built, Pong)  # the replies that answer a request
DEFAULT_IMAGE_SIZE = (1280, 1024)  # (w, h) when no calibration says otherwise


class SimWorkerError(SourceUnavailable):
    """The simulation worker could not answer (did not start, crashed, timed out)."""


class WorkerRestarted(SourceRestarted):
    """The worker was lost during a step; a new one runs the same config from its start."""


class StepCancelled(RuntimeError):
    """The schedule a ``step()`` waited on was paused or its simulation replaced meanwhile."""


class _Lost(Exception):
    """Internal: the pipe or the process is gone, or the reply is late."""


class ProcessTick(LazyImagePair):
    """A tick from the worker: the simulation's state, its images read on demand, its schedule.

    ``state``: the :class:`DockingTick` (every field, ``rta_reason`` and ``run_outcome``
    included; its images ``None``: they are in the ring or inline);
    on the machine's monotonic clock (``time.monotonic``, the same in every process):
    ``deadline_s`` (the worker's deadline this tick serves), ``released_s`` (when the worker
    sent it: its result available), ``received_s`` (when this process had it) and
    ``missed_deadlines`` (deadlines the worker skipped just before this one);
    ``extra_timings_ms["sim"]``: the worker's compute time for it."""

    def __init__(
        self,
        state: DockingTick,
        ring: ImageRing | None,
        slot: int,
        stamp: int,
        inline: tuple[UInt8Array, UInt8Array] | None,
        sim_ms: float,
        *,
        deadline_s: float,
        released_s: float,
        received_s: float,
        missed_deadlines: int,
    ) -> None:
        super().__init__(inline)
        self.state = state
        self._ring = ring
        self._slot = slot
        self._stamp = stamp
        self.deadline_s = deadline_s
        self.released_s = released_s
        self.received_s: float | None = received_s
        self.missed_deadlines = missed_deadlines
        self.extra_timings_ms = {"sim": sim_ms}

    @classmethod
    def of(cls, msg: TickMessage, ring: ImageRing | None, *, received_s: float) -> ProcessTick:
        """The tick ``msg`` released, received at ``received_s`` (its images in ``ring``)."""
        return cls(
            msg.tick,
            ring,
            msg.slot,
            msg.stamp,
            msg.inline,
            msg.sim_ms,
            deadline_s=msg.deadline_s,
            released_s=msg.released_s,
            received_s=received_s,
            missed_deadlines=msg.missed_deadlines,
        )

    # what the subscribers read besides the images (the 3-D scene, the camera view, MCAP)
    @property
    def image_windows_px(self) -> tuple[list[Rect], list[Rect]] | None:
        """The rectangles rendered in the left / right image (``None``: a full render)."""
        return self.state.image_windows_px

    @property
    def camera_pose_T(self) -> tuple[FloatArray, FloatArray] | None:
        """The left camera's true pose in the tanker frame (R_TC, origin m) at this frame."""
        return self.state.camera_pose_T

    def _load(self) -> ImagePair:
        got = None
        if self._ring is not None and self._slot >= 0:
            got = self._ring.read(self._slot, self._stamp)
        return got if got is not None else (None, None)


INBOX_MAX = 64  # stream messages kept while a request waits for its reply
STEP_POLL_S = 0.05  # a waiting step() re-checks pause / replacement this often


class SimWorker:
    """One persistent worker process (respawned when lost) and its image ring.

    The worker keeps the tick schedule (:func:`~app.service.sim_worker.worker.worker_main`); :meth:`step` starts it on the
    first call for a simulation and then returns the next tick the worker released."""

    def __init__(
        self,
        *,
        image_hz: float = 5.0,
        step_timeout_s: float = 5.0,
        build_timeout_s: float = 30.0,
        start_timeout_s: float = 60.0,
        ring_slots: int = RING_SLOTS,
        shared_images: bool = True,
        lookahead: int = LOOKAHEAD,
        launcher: WorkerLauncher | None = None,
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        """``launcher``: what starts a worker (default: :class:`SpawnLauncher`, a process);
        ``now``: the worker's schedule clock (s; the machine's monotonic clock)."""
        self._launch: WorkerLauncher = launcher or SpawnLauncher()
        self.now = now
        self.image_period_s = 1.0 / image_hz if image_hz > 0 else float("inf")
        self.step_timeout_s = step_timeout_s
        self.build_timeout_s = build_timeout_s
        self.start_timeout_s = start_timeout_s
        self.ring_slots = ring_slots
        self.shared_images = shared_images
        self.lookahead = max(0, int(lookahead))
        self._lock = threading.RLock()
        self._proc: WorkerProcess | None = None
        self._conn: ParentConn | None = None
        self._ring: ImageRing | None = None
        self._epoch = 0
        self._next_id = 0
        self._current: Build | None = None  # the running simulation's build request
        self._restarted_sid: int | None = None
        self._closed = False
        self._gen = 0  # run requests sent (a tick of an older one is stale)
        self._pacing: int | None = None  # the sid the worker's schedule runs for
        self._inbox: deque[Reply] = deque(maxlen=INBOX_MAX)
        self.pid: int | None = None
        self.policy: str | None = None  # the worker's CPU priority: "rr", "nice", "default"
        self.spawns = 0
        self.restarts = 0  # workers lost (crash, exit, timeout) and replaced

    # ---- process management ----------------------------------------------------------
    @property
    def alive(self) -> bool:
        proc = self._proc
        return proc is not None and proc.is_alive()

    def _ensure_ring(self, calibration: WireCalibration | None) -> None:
        if self._ring is not None or not self.shared_images:
            return
        w, h = DEFAULT_IMAGE_SIZE
        if calibration is not None:
            w, h = calibration["image_size"]
        try:
            self._ring = ImageRing.create(self.ring_slots, int(w) * int(h))
        except OSError as exc:  # no /dev/shm: images go through the pipe at image_hz
            log.warning("no shared memory for camera images (%s): using the pipe", exc)
            self.shared_images = False

    def _spawn(self) -> None:
        if self._closed:
            raise SimWorkerError("the simulation worker is shut down")
        self._kill()
        self._epoch += 1
        ring = self._ring
        spec = WorkerSpec(
            ring_name=None if ring is None else ring.name,
            ring_slots=self.ring_slots,
            ring_capacity=0 if ring is None else ring.capacity,
            epoch=self._epoch,
            image_period_s=self.image_period_s,
            lookahead=self.lookahead,
        )
        proc, parent = self._launch(spec)
        self._proc, self._conn = proc, parent
        self.spawns += 1
        try:
            reply = self._wait_for(Ready, self.start_timeout_s)
        except _Lost as exc:
            self._kill()
            raise SimWorkerError(f"simulation worker did not start: {exc}") from None
        if isinstance(reply, ErrorReply):  # the worker answers nothing before it is ready
            self._kill()
            raise SimWorkerError(f"simulation worker did not start: {reply.kind}: {reply.message}")
        self.pid = reply.pid
        self.policy = reply.policy
        log.info("simulation worker started (pid %d, scheduling %s)", self.pid, self.policy)

    def _kill(self) -> None:
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        self.pid = None
        self._pacing = None
        self._inbox.clear()
        if conn is not None:
            conn.close()
        if proc is not None:
            if proc.is_alive():
                proc.kill()
            proc.join(timeout=5.0)

    def _wait(self, timeout_s: float) -> Reply:
        """The next message from the worker (the inbox first)."""
        if self._inbox:
            return self._inbox.popleft()
        conn, proc = self._conn, self._proc
        if conn is None or proc is None:
            raise _Lost("no worker")
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise _Lost(f"no answer within {timeout_s:g} s")
            try:
                if conn.poll(min(remaining, 0.25)):
                    reply: Reply = conn.recv()
                    return reply
                if not proc.is_alive() and not conn.poll(0):
                    raise _Lost(f"worker exited with code {proc.exitcode}")
            except (EOFError, OSError) as exc:
                proc.join(timeout=0.2)  # for its exit code
                raise _Lost(
                    f"{type(exc).__name__} on the pipe, exit code {proc.exitcode}"
                ) from None

    def _wait_for(self, kind: type[Answer], timeout_s: float) -> Answer | ErrorReply:
        """The reply to a request (a ``kind`` or an :class:`ErrorReply`); ticks the worker
        sends meanwhile are kept in the inbox for :meth:`step`."""
        deadline = time.monotonic() + timeout_s
        held: list[Reply] = []
        try:
            while True:
                msg = self._wait(max(1e-3, deadline - time.monotonic()))
                if isinstance(msg, (kind, ErrorReply)):
                    return msg
                if isinstance(msg, STREAM):
                    held.append(msg)
        finally:
            self._inbox.extendleft(reversed(held))

    def _send(self, msg: Request) -> None:
        conn = self._conn
        if conn is None:
            raise _Lost("no worker")
        try:
            conn.send(msg)
        except (OSError, ValueError) as exc:
            raise _Lost(f"send failed ({type(exc).__name__})") from None

    def _build_in_worker(self, request: Build) -> bool:
        """Build ``request`` in the worker: whether the simulation is already done."""
        self._send(request)
        reply = self._wait_for(Built, self.build_timeout_s)
        if isinstance(reply, ErrorReply):
            raise_remote(reply)
        self._pacing = None  # a new simulation: the worker's schedule ended
        return reply.done

    def _replace(self) -> None:
        """Start a new worker and rebuild the current simulation in it (from its start)."""
        self._kill()
        self._spawn()
        if self._current is not None:
            try:
                self._build_in_worker(self._current)
            except _Lost as exc:
                self.restarts += 1
                self._kill()
                raise SimWorkerError(f"the new simulation worker was lost too: {exc}") from None

    # ---- the factory's and the source's calls ----------------------------------------------
    def build(self, config: SimConfig, calibration: StereoCalibration | None) -> ProcessSimSource:
        """Build a simulation for ``config`` in the worker; raises as the in-process factory
        does (``ValueError`` for a refused config), the running simulation kept if it does."""
        dcfg = docking_config(config)
        dcfg.validate()  # the in-process factory's ValueError, raised here
        wire = None if calibration is None else calibration_to_wire(calibration)
        with self._lock:
            if self._closed:
                raise SimWorkerError("the simulation worker is shut down")
            self._ensure_ring(wire)
            if not self.alive:
                if self._proc is not None:  # died while idle
                    self.restarts += 1
                self._replace()  # the running simulation too, should this build be refused
                if self._current is not None:
                    self._restarted_sid = self._current.sid
            self._next_id += 1
            request = Build(sid=self._next_id, config=dcfg, calibration=wire)
            try:
                done = self._build_in_worker(request)
            except _Lost as exc:
                # the running simulation is lost with the worker: its next step respawns
                self.restarts += 1
                self._kill()
                raise SimWorkerError(f"simulation worker lost while building: {exc}") from None
            self._current = request
            return ProcessSimSource(self, request.sid, done, 1.0 / float(dcfg.tick_hz))

    def _lost(self, exc: _Lost) -> WorkerRestarted:
        """The worker was lost during a step: replace it (under ``self._lock``)."""
        self.restarts += 1
        log.error("simulation worker lost (%s); starting a new one", exc)
        self._replace()
        return WorkerRestarted(f"simulation worker lost ({exc}); restarted: a new run")

    def _take(self, sid: int, gen: int) -> TickMessage | TickError | None:
        """The next stream message of run ``gen`` of ``sid`` if one has arrived (stale ones
        are dropped); ``None`` if none yet. Under ``self._lock``."""
        while self._inbox:
            msg = self._inbox.popleft()
            if isinstance(msg, STREAM) and msg.sid == sid and msg.gen == gen:
                return msg
        conn, proc = self._conn, self._proc
        if conn is None or proc is None:
            raise _Lost("no worker")
        try:
            while conn.poll(0):
                got: Reply = conn.recv()
                if isinstance(got, STREAM) and got.sid == sid and got.gen == gen:
                    return got
        except (EOFError, OSError) as exc:
            proc.join(timeout=0.2)  # for its exit code
            raise _Lost(f"{type(exc).__name__} on the pipe, exit code {proc.exitcode}") from None
        if not proc.is_alive() and not conn.poll(0):
            raise _Lost(f"worker exited with code {proc.exitcode}")
        return None

    def step(self, sid: int, period_s: float) -> tuple[ProcessTick, bool]:
        """The next tick the worker releases on its schedule (started here if it is not
        running for ``sid``: first deadline now, then every ``period_s``).

        The wait for it holds no lock (``build``, ``pause`` and ``ping`` go ahead meanwhile);
        if the schedule is paused or the simulation replaced during the wait, this raises
        :class:`StepCancelled`."""
        with self._lock:
            if self._closed:
                raise SimWorkerError("the simulation worker is shut down")
            if self._proc is None:  # lost earlier (counted then), not replaced yet
                self._replace()
                raise WorkerRestarted("simulation worker restarted: a new run")
            if sid == self._restarted_sid:  # rebuilt by a build() after a loss: say so once
                self._restarted_sid = None
                raise WorkerRestarted("simulation worker restarted: a new run")
            if self._pacing != sid:
                self._gen += 1
                try:
                    self._send(Run(sid, self._gen, period_s, first_deadline_s=self.now()))
                except _Lost as exc:
                    raise self._lost(exc) from None
                self._pacing = sid
            gen = self._gen
        give_up = time.monotonic() + self.step_timeout_s
        while True:
            with self._lock:
                if self._closed:
                    raise SimWorkerError("the simulation worker is shut down")
                if self._proc is None:  # lost by another call meanwhile (counted there)
                    self._replace()
                    raise WorkerRestarted("simulation worker restarted: a new run")
                if self._pacing != sid or self._gen != gen:
                    raise StepCancelled("the schedule was paused or its simulation replaced")
                try:
                    msg = self._take(sid, gen)
                    if msg is None and time.monotonic() >= give_up:
                        raise _Lost(f"no answer within {self.step_timeout_s:g} s")
                except _Lost as exc:
                    raise self._lost(exc) from None
                conn = self._conn
            if msg is not None:
                break
            try:  # outside the lock: wait for the pipe (a short slice: re-check the state)
                assert conn is not None
                conn.poll(min(STEP_POLL_S, max(0.0, give_up - time.monotonic())))
            except (EOFError, OSError, ValueError):
                pass  # closed meanwhile: seen under the lock
        received = self.now()
        with self._lock:
            if isinstance(msg, TickError):
                if self._pacing == sid and self._gen == gen:
                    self._pacing = None  # the worker's schedule ended with the error
                raise_remote(msg.error)
            if msg.done and self._pacing == sid and self._gen == gen:
                self._pacing = None  # the worker's schedule ended with the simulation
            ring = self._ring if msg.slot >= 0 else None
        return ProcessTick.of(msg, ring, received_s=received), msg.done

    def pause(self, sid: int) -> None:
        """Stop the worker's schedule for ``sid`` (the simulation is kept; ticks computed
        ahead are released when it runs again)."""
        with self._lock:
            if self._pacing != sid or self._conn is None:
                return
            self._pacing = None
            try:
                self._send(Pause())
            except _Lost:
                pass  # noticed (and replaced) at the next step

    def ping(self, timeout_s: float = 5.0) -> int:
        """The worker's pid (a round trip through the pipe)."""
        with self._lock:
            try:
                self._send(Ping())
                reply = self._wait_for(Pong, timeout_s)
            except _Lost as exc:
                raise SimWorkerError(str(exc)) from None
            if isinstance(reply, ErrorReply):
                raise_remote(reply)
            return reply.pid

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the worker (politely, then by force) and free the shared memory."""
        self._closed = True  # no respawn from here on
        if not self._lock.acquire(timeout=timeout_s):
            # a step or build is waiting on the worker: end it, the wait then ends at once
            proc = self._proc
            if proc is not None:
                proc.kill()
            if not self._lock.acquire(timeout=timeout_s):  # pragma: no cover
                log.error("simulation worker: the waiting call did not return")
                return
        try:
            proc, conn = self._proc, self._conn
            if proc is not None and conn is not None and proc.is_alive():
                try:
                    conn.send(Stop())
                except (OSError, ValueError):
                    pass
                proc.join(timeout=timeout_s)
            self._kill()
            if self._ring is not None:
                self._ring.close()
                self._ring = None
        finally:
            self._lock.release()


class ProcessSimSource:
    """The paced source of the simulation built in the worker (``done``, ``step()``, ``pause()``).

    ``paced``: the worker keeps the schedule; ``step()`` waits for its next tick (at most a
    period, the first one is due at once) and ``pause()`` stops the schedule."""

    paced = True

    def __init__(self, worker: SimWorker, sid: int, done: bool, period_s: float) -> None:
        self.worker = worker
        self.sid = sid
        self.period_s = period_s
        self._done = done

    @property
    def done(self) -> bool:
        return self._done

    def step(self) -> ProcessTick:
        tick, self._done = self.worker.step(self.sid, self.period_s)
        return tick

    def pause(self) -> None:
        self.worker.pause(self.sid)


class ProcessSourceFactory:
    """``TickLoop`` source factory: every call builds in the same (persistent) worker."""

    def __init__(self, worker: SimWorker) -> None:
        self.worker = worker

    def __call__(
        self, config: SimConfig, calibration: StereoCalibration | None
    ) -> ProcessSimSource:
        return self.worker.build(config, calibration)

    def close(self) -> None:
        self.worker.close()


def process_source_factory(
    *,
    image_hz: float = 5.0,
    step_timeout_s: float = 5.0,
    build_timeout_s: float = 30.0,
    start_timeout_s: float = 60.0,
    shared_images: bool = True,
    lookahead: int = LOOKAHEAD,
    launcher: WorkerLauncher | None = None,
    now: Callable[[], float] = time.monotonic,
) -> ProcessSourceFactory:
    """A factory for ``TickLoop(source_factory=...)`` running the simulation in a worker
    process (started on the first build; ``factory.close()`` stops it)."""
    return ProcessSourceFactory(
        SimWorker(
            image_hz=image_hz,
            step_timeout_s=step_timeout_s,
            build_timeout_s=build_timeout_s,
            start_timeout_s=start_timeout_s,
            shared_images=shared_images,
            lookahead=lookahead,
            launcher=launcher,
            now=now,
        )
    )
