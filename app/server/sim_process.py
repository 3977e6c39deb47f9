"""The docking simulation in a persistent worker process that keeps the tick schedule.

Rendering the 1280×1024 pair and running the pipeline take 5–20 ms of CPU per tick at 30 Hz;
in the web server's process they would share its GIL with request handling. Here one worker
process (``spawn`` context) builds and steps the :class:`app.sim.docking.DockingSimulation`
*and keeps the fixed-rate schedule itself*: the web server's process no longer sits in the
loop's critical path (its tick thread, which shares the GIL with 50 WebSocket clients, uploads'
HTTP work and the 3-D scene, woke up to 30 ms late and waited up to 60 ms more for the GIL to
read a reply that was ready: measured, see ``docs/service.md``). The parent holds a
``StepSource`` proxy (``paced``); ``process_source_factory()`` returns a ``TickLoop`` source
factory.

What crosses the process boundary (one duplex pipe):

* ``build``: the validated :class:`DockingConfig` (already checked in the parent, so a refused
  config raises there exactly as in-process) and the calibration as a dict (exact floats);
  the worker answers once the new simulation is built, or with the error (the previous
  simulation and its schedule are kept, so a refused config leaves the running source
  untouched);
* ``run`` (sent by the first ``step()`` for a simulation, with the period and the first
  deadline) starts the worker's schedule; from then on the worker sends, at each deadline and
  unasked, the tick computed for it: the :class:`DockingTick` without its images (≈ 3 kB
  pickled), the worker's compute time, the deadline, the release time and the deadlines it
  missed (the same rule as the tick loop: a late tick skips the deadlines that passed).
  Between deadlines it computes up to ``lookahead`` ticks ahead (default 2), so a tick is
  normally ready before its deadline and an occasional slow one (a descheduled render) does
  not make the next late. The parent's ``step()`` returns the next released tick; ``pause``
  (``TickLoop.stop_sim``) ends the schedule, a new ``build`` too; a finished or failed
  simulation ends it by itself;
* camera images (2 × 1.3 MB per tick) never go through the pipe: the worker copies them into a
  ring of slots in :mod:`multiprocessing.shared_memory` (a seqlock-style stamp per slot), and
  the parent's tick reads them lazily, only when a subscriber asks for ``left_image`` /
  ``right_image`` (the 3-D scene, at its image rate). A slot overwritten before it was read
  gives ``None`` (the dashboard keeps the last image). Images that do not fit a slot (a
  calibration with a larger image size) or without shared memory travel in the pipe, at
  ``image_hz`` at most.

The worker asks for a real-time CPU priority (``SCHED_RR``, the lowest level) where it may
(root, CAP_SYS_NICE), else nice −10, else keeps the default, silently.

Failures: every wait on the pipe has a timeout (start-up, build, the next tick); a worker that
died (EOF, exit) or did not answer in time is killed and a new one spawned, the simulation
rebuilt from its last config: the failed ``step()`` raises :class:`WorkerRestarted` (the tick
loop counts an error and starts a new run). The tick thread never waits longer than a timeout.
"""

from __future__ import annotations

import gc
import logging
import multiprocessing
import os
import signal
import struct
import threading
import time
import traceback
from collections import deque
from dataclasses import replace
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from app.server.lazy_images import ImagePair, LazyImagePair
from app.server.schemas import SimConfig
from app.server.tick_loop import (
    SourceRestarted,
    SourceUnavailable,
    docking_config,
    raise_thread_priority,
)

log = logging.getLogger(__name__)

SPAWN = multiprocessing.get_context("spawn")
DEFAULT_IMAGE_SIZE = (1280, 1024)  # (w, h) when no calibration says otherwise
RING_SLOTS = 8  # ≈ 0.23 s of ticks at 30 Hz before a slot is reused
LOOKAHEAD = 2  # ticks the worker computes ahead of their deadlines
POLL_SLACK_S = 0.002  # the pipe is polled until this long before a deadline, then a sleep
_HDR = struct.Struct("<qqqqq")  # stamp, left h, left w, right h, right w
_HDR_BYTES = 64


class SimWorkerError(SourceUnavailable):
    """The simulation worker could not answer (did not start, crashed, timed out)."""


class WorkerRestarted(SourceRestarted):
    """The worker was lost during a step; a new one runs the same config from its start."""


class StepCancelled(RuntimeError):
    """The schedule a ``step()`` waited on was paused or its simulation replaced meanwhile."""


class _Lost(Exception):
    """Internal: the pipe or the process is gone, or the reply is late."""


# ---- calibration over the wire ---------------------------------------------------------------
def calibration_to_wire(calibration: Any) -> dict[str, Any] | None:
    """A JSON-able dict of a :class:`StereoCalibration` (``None`` stays ``None``)."""
    return None if calibration is None else dict(calibration.to_dict())


def calibration_from_wire(data: dict[str, Any] | None) -> Any:
    """Rebuild the calibration bit for bit (no re-validation: the parent validated it;
    ``StereoCalibration.from_dict`` would re-orthonormalise R and move it by an ulp)."""
    if data is None:
        return None
    from app.streams.recording import exact_calibration

    return exact_calibration(data)


# ---- images in shared memory -------------------------------------------------------------------
class ImageRing:
    """``slots`` pairs of uint8 images in one shared-memory block, each slot stamped.

    Writer (worker): stamp ← −1, data, shapes, stamp ← tick id. Reader (parent): stamp, copy,
    stamp again; the copy is valid only if both stamps equal the tick id it wants.
    """

    def __init__(self, shm: Any, slots: int, capacity: int, *, owner: bool) -> None:
        self.shm = shm
        self.slots = slots
        self.capacity = capacity  # bytes for both images of one slot
        self.slot_bytes = _HDR_BYTES + ((capacity + 63) // 64) * 64
        self.owner = owner
        self._lock = threading.Lock()
        self._closed = False

    @classmethod
    def create(cls, slots: int, pixels_per_image: int) -> ImageRing:
        from multiprocessing import shared_memory

        capacity = 2 * pixels_per_image
        slot_bytes = _HDR_BYTES + ((capacity + 63) // 64) * 64
        shm: Any = shared_memory.SharedMemory(create=True, size=slots * slot_bytes)
        ring = cls(shm, slots, capacity, owner=True)
        for i in range(slots):
            _HDR.pack_into(shm.buf, i * slot_bytes, -1, 0, 0, 0, 0)
        return ring

    @classmethod
    def attach(cls, name: str, slots: int, capacity: int) -> ImageRing:
        from multiprocessing import shared_memory

        return cls(shared_memory.SharedMemory(name=name), slots, capacity, owner=False)

    @property
    def name(self) -> str:
        return str(self.shm.name)

    def write(self, slot: int, stamp: int, left: np.ndarray, right: np.ndarray) -> bool:
        """Worker side; ``False`` if the pair does not fit (or is not 2-D uint8)."""
        if left.dtype != np.uint8 or right.dtype != np.uint8 or left.ndim != 2 or right.ndim != 2:
            return False
        nl, nr = left.size, right.size
        if nl + nr > self.capacity:
            return False
        buf = self.shm.buf
        base = slot * self.slot_bytes
        data = base + _HDR_BYTES
        _HDR.pack_into(buf, base, -1, 0, 0, 0, 0)
        np.frombuffer(buf, np.uint8, count=nl, offset=data).reshape(left.shape)[...] = left
        np.frombuffer(buf, np.uint8, count=nr, offset=data + nl).reshape(right.shape)[...] = right
        _HDR.pack_into(buf, base, stamp, left.shape[0], left.shape[1], *right.shape)
        return True

    def read(self, slot: int, stamp: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Parent side: copies of the pair stamped ``stamp``, or ``None`` if overwritten."""
        with self._lock:
            if self._closed:
                return None
            buf = self.shm.buf
            base = slot * self.slot_bytes
            data = base + _HDR_BYTES
            s0, lh, lw, rh, rw = _HDR.unpack_from(buf, base)
            if s0 != stamp:
                return None
            nl, nr = lh * lw, rh * rw
            left = np.frombuffer(buf, np.uint8, count=nl, offset=data).reshape(lh, lw).copy()
            right = np.frombuffer(buf, np.uint8, count=nr, offset=data + nl).reshape(rh, rw).copy()
            if _HDR.unpack_from(buf, base)[0] != stamp:
                return None
            return left, right

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self.shm.close()
            except BufferError:  # pragma: no cover - a view still exported: freed with it
                pass
            if self.owner:
                try:
                    self.shm.unlink()
                except FileNotFoundError:  # pragma: no cover
                    pass


# ---- the worker process -----------------------------------------------------------------------
class _WorkerState:
    def __init__(self, ring: ImageRing | None, epoch: int, image_period_s: float) -> None:
        self.ring = ring
        self.epoch = epoch
        self.image_period_s = image_period_s
        self.k = 0
        self.last_inline = -1e9

    def step(self, sim: Any) -> tuple[Any, ...]:
        t0 = time.perf_counter()
        try:
            tick = sim.step()
        except Exception as exc:
            return ("error", type(exc).__name__, str(exc), traceback.format_exc())
        sim_ms = (time.perf_counter() - t0) * 1e3
        self.k += 1
        stamp = (self.epoch << 32) | self.k
        slot = -1
        inline = None
        left, right = tick.left_image, tick.right_image
        if left is not None and right is not None:
            ring = self.ring
            if ring is not None and ring.write(self.k % ring.slots, stamp, left, right):
                slot = self.k % ring.slots
            else:
                now = time.monotonic()
                if now - self.last_inline >= self.image_period_s:
                    self.last_inline = now
                    inline = (left, right)
        light = replace(tick, left_image=None, right_image=None)
        return ("tick", light, bool(sim.done), sim_ms, slot, stamp, inline)


def _error_reply(exc: BaseException) -> tuple[Any, ...]:
    return ("error", type(exc).__name__, str(exc), traceback.format_exc())


WORKER_NICE = -10  # nice value the worker asks for where real-time scheduling is refused


def _raise_priority() -> str:
    """Ask for a CPU priority above the web server, the upload workers (nice +10) and a
    browser on the same machine: the loop's deadline is the service's first duty.
    ``SCHED_RR`` where permitted (root, CAP_SYS_NICE; the worker sleeps between ticks), else
    nice −10, else the default, silently (:func:`app.server.tick_loop.raise_thread_priority`)."""
    return raise_thread_priority(WORKER_NICE, realtime=True)


class _Pace:
    """The worker's fixed-rate schedule for one simulation (``sid``) and run request (``gen``).

    Same rule as :class:`app.server.tick_loop.TickLoop`: deadlines ``period_s`` apart; a tick
    released after the next deadline has passed skips the missed deadlines (counted)."""

    def __init__(self, sid: int, gen: int, period_s: float, first_deadline: float) -> None:
        self.sid = sid
        self.gen = gen
        self.period_s = period_s
        self.next_t = first_deadline

    def due(self, now: float) -> tuple[float, int]:
        """The deadline served now and the deadlines missed before it (``now ≥ next_t``)."""
        missed = int((now - self.next_t) / self.period_s + 1e-9)
        deadline = self.next_t + missed * self.period_s
        self.next_t = deadline + self.period_s
        return deadline, missed


def _worker_main(
    conn: Connection,
    ring_name: str | None,
    ring_slots: int,
    ring_capacity: int,
    epoch: int,
    image_period_s: float,
    lookahead: int,
) -> None:
    """Entry point of the worker: serve ``build`` / ``run`` / ``pause`` / ``ping`` / ``stop``.

    ``run`` starts the worker's own fixed-rate schedule for a built simulation: at each
    deadline it sends the next tick (``("tick", sid, gen, …, deadline, released, missed)``)
    without being asked, and in between computes up to ``lookahead`` ticks ahead (their
    images go to the ring when computed). Requests are read between ticks, never while a
    deadline is due. A simulation that finished or raised ends its schedule (the parent asks
    again); ``pause``, a new ``build`` or ``run`` replace it.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    policy = _raise_priority()
    ring = None
    if ring_name is not None:
        try:
            ring = ImageRing.attach(ring_name, ring_slots, ring_capacity)
        except OSError:
            ring = None
    from app.sim.docking import DockingSimulation
    from app.sim.warmup import compile_kernels

    compile_kernels()  # the compiled loops loaded (disk cache) before the first deadline
    gc.collect()
    gc.freeze()  # the modules out of the cyclic collector's sight (its pauses stay short)
    state = _WorkerState(ring, epoch, image_period_s)
    sim: Any = None
    sim_id = -1
    ahead: deque[tuple[Any, ...]] = deque()  # computed, not yet released (this sim)
    pace: _Pace | None = None
    conn.send(("ready", os.getpid(), policy))

    def release(p: _Pace) -> bool:
        """Send the tick for the deadline due now; ``False`` ends the schedule."""
        deadline, missed = p.due(time.monotonic())
        reply = ahead.popleft() if ahead else state.step(sim)  # late if not computed ahead
        if reply[0] != "tick":
            conn.send(("tickerror", p.sid, p.gen, *reply[1:]))
            return False
        conn.send(("tick", p.sid, p.gen, *reply[1:], deadline, time.monotonic(), missed))
        return not reply[2]  # the simulation finished with this tick

    while True:
        try:
            if pace is not None:
                now = time.monotonic()
                if now >= pace.next_t:
                    if not release(pace):
                        pace = None
                    continue
                if conn.poll(0):
                    pass  # a request first
                elif (
                    len(ahead) < lookahead
                    and not sim.done
                    and not (ahead and ahead[-1][0] != "tick")  # a raise ends the look-ahead
                ):
                    ahead.append(state.step(sim))
                    continue
                elif not conn.poll(max(0.0, pace.next_t - now - POLL_SLACK_S)):
                    time.sleep(max(0.0, pace.next_t - time.monotonic()))  # ms-rounded poll
                    continue  # the deadline
            msg = conn.recv()
        except (EOFError, OSError):
            break  # the parent is gone
        op = msg[0]
        if op == "stop":
            break
        if op == "ping":
            conn.send(("pong", os.getpid()))
        elif op == "build":
            _, new_id, dcfg, calib_wire = msg
            try:
                new = DockingSimulation(dcfg, calibration=calibration_from_wire(calib_wire))
            except Exception as exc:
                conn.send(_error_reply(exc))  # the running simulation (and schedule) is kept
                continue
            sim, sim_id, pace = new, new_id, None
            ahead.clear()
            conn.send(("built", new_id, bool(sim.done)))
        elif op == "run":
            _, sid, gen, period_s, first_deadline = msg
            if sim is None or sid != sim_id:
                conn.send(("tickerror", sid, gen, "RuntimeError", "stale simulation source", ""))
            elif not ahead and sim.done:
                conn.send(("tickerror", sid, gen, "RuntimeError", "simulation finished", ""))
            else:
                pace = _Pace(sid, gen, float(period_s), float(first_deadline))
        elif op == "pause":
            pace = None  # the ticks computed ahead are kept for the next run
        else:
            conn.send(("error", "RuntimeError", f"unknown request {op!r}", ""))
    if ring is not None:
        ring.close()


# ---- the parent side --------------------------------------------------------------------------
class ProcessTick(LazyImagePair):
    """A tick from the worker: the :class:`DockingTick`'s fields, images read on demand.

    Its schedule, on the machine's monotonic clock (``time.monotonic``, the same in every
    process): ``deadline_s`` (the worker's deadline this tick serves), ``released_s`` (when
    the worker sent it: its result available), ``received_s`` (when this process had it) and
    ``missed_deadlines`` (deadlines the worker skipped just before this one)."""

    paced = True  # the worker keeps the schedule (app.server.tick_loop.TickLoop reads this)

    def __init__(
        self,
        tick: Any,
        ring: ImageRing | None,
        slot: int,
        stamp: int,
        inline: tuple[np.ndarray, np.ndarray] | None,
        sim_ms: float,
        *,
        deadline_s: float,
        released_s: float,
        received_s: float,
        missed_deadlines: int,
    ) -> None:
        super().__init__(inline)
        self._tick = tick
        self._ring = ring
        self._slot = slot
        self._stamp = stamp
        self.deadline_s = deadline_s
        self.released_s = released_s
        self.received_s = received_s
        self.missed_deadlines = missed_deadlines
        self.extra_timings_ms = {"sim": sim_ms}

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._tick, name)

    @property
    def tick(self) -> Any:
        """The :class:`DockingTick` itself (its images are ``None``)."""
        return self._tick

    def _load(self) -> ImagePair:
        got = None
        if self._ring is not None and self._slot >= 0:
            got = self._ring.read(self._slot, self._stamp)
        return got if got is not None else (None, None)


def _raise_remote(reply: tuple[Any, ...]) -> None:
    _, kind, message, tb = reply
    if kind == "ValueError":
        raise ValueError(message)
    if kind == "TypeError":
        raise TypeError(message)
    if tb:
        log.debug("simulation worker traceback:\n%s", tb)
    raise RuntimeError(f"{kind}: {message}")


_STREAM = ("tick", "tickerror")  # what the worker sends unasked, on its schedule
INBOX_MAX = 64  # stream messages kept while a request waits for its reply
STEP_POLL_S = 0.05  # a waiting step() re-checks pause / replacement this often


class SimWorker:
    """One persistent worker process (respawned when lost) and its image ring.

    The worker keeps the tick schedule (:func:`_worker_main`); :meth:`step` starts it on the
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
    ) -> None:
        self.image_period_s = 1.0 / image_hz if image_hz > 0 else float("inf")
        self.step_timeout_s = step_timeout_s
        self.build_timeout_s = build_timeout_s
        self.start_timeout_s = start_timeout_s
        self.ring_slots = ring_slots
        self.shared_images = shared_images
        self.lookahead = max(0, int(lookahead))
        self._lock = threading.RLock()
        self._proc: Any = None
        self._conn: Connection | None = None
        self._ring: ImageRing | None = None
        self._epoch = 0
        self._next_id = 0
        self._current: tuple[int, Any, dict[str, Any] | None] | None = None
        self._restarted_sid: int | None = None
        self._closed = False
        self._gen = 0  # run requests sent (a tick of an older one is stale)
        self._pacing: int | None = None  # the sid the worker's schedule runs for
        self._inbox: deque[tuple[Any, ...]] = deque(maxlen=INBOX_MAX)
        self.pid: int | None = None
        self.policy: str | None = None  # the worker's CPU priority: "rr", "nice", "default"
        self.spawns = 0
        self.restarts = 0  # workers lost (crash, exit, timeout) and replaced

    # ---- process management ----------------------------------------------------------
    @property
    def alive(self) -> bool:
        proc = self._proc
        return proc is not None and proc.is_alive()

    def _ensure_ring(self, calibration_wire: dict[str, Any] | None) -> None:
        if self._ring is not None or not self.shared_images:
            return
        w, h = DEFAULT_IMAGE_SIZE
        if calibration_wire is not None:
            w, h = calibration_wire["image_size"]
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
        parent, child = SPAWN.Pipe(duplex=True)
        ring = self._ring
        proc = SPAWN.Process(
            target=_worker_main,
            args=(
                child,
                None if ring is None else ring.name,
                self.ring_slots,
                0 if ring is None else ring.capacity,
                self._epoch,
                self.image_period_s,
                self.lookahead,
            ),
            name=f"aar-sim-worker-{self._epoch}",
            daemon=True,
        )
        proc.start()
        child.close()  # so that the worker's death reads as EOF here
        self._proc, self._conn = proc, parent
        self.spawns += 1
        try:
            reply = self._wait_for(("ready",), self.start_timeout_s)
        except _Lost as exc:
            self._kill()
            raise SimWorkerError(f"simulation worker did not start: {exc}") from None
        self.pid = int(reply[1])
        self.policy = str(reply[2])
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

    def _wait(self, timeout_s: float) -> tuple[Any, ...]:
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
                    reply: tuple[Any, ...] = conn.recv()
                    return reply
                if not proc.is_alive() and not conn.poll(0):
                    raise _Lost(f"worker exited with code {proc.exitcode}")
            except (EOFError, OSError) as exc:
                proc.join(timeout=0.2)  # for its exit code
                raise _Lost(
                    f"{type(exc).__name__} on the pipe, exit code {proc.exitcode}"
                ) from None

    def _wait_for(self, kinds: tuple[str, ...], timeout_s: float) -> tuple[Any, ...]:
        """The reply to a request (a message of ``kinds`` or an ``error``); ticks the worker
        sends meanwhile are kept in the inbox for :meth:`step`."""
        deadline = time.monotonic() + timeout_s
        held: list[tuple[Any, ...]] = []
        try:
            while True:
                msg = self._wait(max(1e-3, deadline - time.monotonic()))
                if msg[0] in kinds or msg[0] == "error":
                    return msg
                if msg[0] in _STREAM:
                    held.append(msg)
        finally:
            self._inbox.extendleft(reversed(held))

    def _send(self, msg: tuple[Any, ...]) -> None:
        conn = self._conn
        if conn is None:
            raise _Lost("no worker")
        try:
            conn.send(msg)
        except (OSError, ValueError) as exc:
            raise _Lost(f"send failed ({type(exc).__name__})") from None

    def _build_in_worker(self, sid: int, dcfg: Any, wire: dict[str, Any] | None) -> bool:
        self._send(("build", sid, dcfg, wire))
        reply = self._wait_for(("built",), self.build_timeout_s)
        if reply[0] == "error":
            _raise_remote(reply)
        self._pacing = None  # a new simulation: the worker's schedule ended
        return bool(reply[2])

    def _replace(self) -> None:
        """Start a new worker and rebuild the current simulation in it (from its start)."""
        self._kill()
        self._spawn()
        if self._current is not None:
            sid, dcfg, wire = self._current
            try:
                self._build_in_worker(sid, dcfg, wire)
            except _Lost as exc:
                self.restarts += 1
                self._kill()
                raise SimWorkerError(f"the new simulation worker was lost too: {exc}") from None

    # ---- the factory's and the source's calls ----------------------------------------------
    def build(self, config: SimConfig, calibration: Any) -> ProcessSimSource:
        """Build a simulation for ``config`` in the worker; raises as the in-process factory
        does (``ValueError`` for a refused config), the running simulation kept if it does."""
        dcfg = docking_config(config)
        dcfg.validate()  # the in-process factory's ValueError, raised here
        wire = calibration_to_wire(calibration)
        with self._lock:
            if self._closed:
                raise SimWorkerError("the simulation worker is shut down")
            self._ensure_ring(wire)
            if not self.alive:
                if self._proc is not None:  # died while idle
                    self.restarts += 1
                self._replace()  # the running simulation too, should this build be refused
                if self._current is not None:
                    self._restarted_sid = self._current[0]
            self._next_id += 1
            sid = self._next_id
            try:
                done = self._build_in_worker(sid, dcfg, wire)
            except _Lost as exc:
                # the running simulation is lost with the worker: its next step respawns
                self.restarts += 1
                self._kill()
                raise SimWorkerError(f"simulation worker lost while building: {exc}") from None
            self._current = (sid, dcfg, wire)
            return ProcessSimSource(self, sid, done, 1.0 / float(dcfg.tick_hz))

    def _lost(self, exc: _Lost) -> WorkerRestarted:
        """The worker was lost during a step: replace it (under ``self._lock``)."""
        self.restarts += 1
        log.error("simulation worker lost (%s); starting a new one", exc)
        self._replace()
        return WorkerRestarted(f"simulation worker lost ({exc}); restarted: a new run")

    def _take(self, sid: int, gen: int) -> tuple[Any, ...] | None:
        """The next stream message of run ``gen`` of ``sid`` if one has arrived (stale ones
        are dropped); ``None`` if none yet. Under ``self._lock``."""
        while self._inbox:
            msg = self._inbox.popleft()
            if msg[0] in _STREAM and msg[1] == sid and msg[2] == gen:
                return msg
        conn, proc = self._conn, self._proc
        if conn is None or proc is None:
            raise _Lost("no worker")
        try:
            while conn.poll(0):
                msg = conn.recv()
                if msg[0] in _STREAM and msg[1] == sid and msg[2] == gen:
                    return msg
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
                    self._send(("run", sid, self._gen, period_s, time.monotonic()))
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
        received = time.monotonic()
        with self._lock:
            if msg[0] == "tickerror":
                if self._pacing == sid and self._gen == gen:
                    self._pacing = None  # the worker's schedule ended with the error
                _raise_remote(("error", *msg[3:]))
            tick, done, sim_ms, slot, stamp, inline, deadline, released, missed = msg[3:]
            if done and self._pacing == sid and self._gen == gen:
                self._pacing = None  # the worker's schedule ended with the simulation
            ring = self._ring if slot >= 0 else None
        pt = ProcessTick(
            tick,
            ring,
            slot,
            stamp,
            inline,
            sim_ms,
            deadline_s=deadline,
            released_s=released,
            received_s=received,
            missed_deadlines=int(missed),
        )
        return pt, bool(done)

    def pause(self, sid: int) -> None:
        """Stop the worker's schedule for ``sid`` (the simulation is kept; ticks computed
        ahead are released when it runs again)."""
        with self._lock:
            if self._pacing != sid or self._conn is None:
                return
            self._pacing = None
            try:
                self._send(("pause",))
            except _Lost:
                pass  # noticed (and replaced) at the next step

    def ping(self, timeout_s: float = 5.0) -> int:
        """The worker's pid (a round trip through the pipe)."""
        with self._lock:
            try:
                self._send(("ping",))
                reply = self._wait_for(("pong",), timeout_s)
            except _Lost as exc:
                raise SimWorkerError(str(exc)) from None
            return int(reply[1])

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
                    conn.send(("stop",))
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
    """``StepSource`` proxy of the simulation built in the worker (``done`` + ``step()``).

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

    def __call__(self, config: SimConfig, calibration: Any) -> ProcessSimSource:
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
        )
    )
