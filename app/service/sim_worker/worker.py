"""The simulation worker process: its main loop and its fixed-rate schedule (child side).

The worker builds :class:`app.sim.docking.DockingSimulation` instances on request and, once
asked to ``run`` one, keeps its tick schedule itself: at each deadline it sends, unasked, the
tick computed for it (the :class:`DockingTick` without its images, ≈ 3 kB pickled), its
compute time, the deadline, the release time and the deadlines it missed (the same rule as
the tick loop: a late tick skips the deadlines that passed). Between deadlines it computes up
to ``lookahead`` ticks ahead (default 2), so a tick is normally ready before its deadline and
an occasional slow one (a descheduled render) does not make the next late. The messages are
listed in :mod:`app.service.sim_worker.wire`.

Camera images go to the shared-memory ring (:mod:`app.service.sim_worker.image_ring`); a pair
that does not fit a slot (a calibration with a larger image size), or any pair when there is
no shared memory, travels in the pipe, at ``image_hz`` at most.

The worker asks for a real-time CPU priority (``SCHED_RR``, the lowest level) where it may
(root, CAP_SYS_NICE), else nice −10, else keeps the default, silently.

This module imports nothing of ``app.service`` outside :mod:`app.service.sim_worker`.
"""

from __future__ import annotations

import gc
import os
import signal
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Protocol

from app.service.sim_worker.image_ring import ImageRing
from app.service.sim_worker.priority import raise_thread_priority
from app.service.sim_worker.wire import (
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
    calibration_from_wire,
    error_reply,
)
from app.types import UInt8Array

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration
    from app.sim.docking import DockingConfig, DockingSimulation, DockingTick

LOOKAHEAD = 2  # ticks the worker computes ahead of their deadlines
POLL_SLACK_S = 0.002  # the pipe is polled until this long before a deadline, then a sleep
WORKER_NICE = -10  # nice value the worker asks for where real-time scheduling is refused


@dataclass(frozen=True, slots=True)
class ComputedTick:
    """A tick computed (ahead of its deadline or at it), not yet released.

    ``tick``: the :class:`DockingTick` without its images; ``done``: the simulation finished
    with it; ``sim_ms``: the compute time (ms); the images in ring ``slot`` under ``stamp``
    (``slot`` −1: not in the ring), or ``inline``, or neither (rate-limited)."""

    tick: DockingTick
    done: bool
    sim_ms: float
    slot: int
    stamp: int
    inline: tuple[UInt8Array, UInt8Array] | None

    def released(
        self, sid: int, gen: int, deadline_s: float, released_s: float, missed: int
    ) -> TickMessage:
        """The :class:`TickMessage` that releases it at ``deadline_s`` (sent ``released_s``,
        after ``missed`` skipped deadlines; monotonic clock, s)."""
        return TickMessage(
            sid=sid,
            gen=gen,
            tick=self.tick,
            done=self.done,
            sim_ms=self.sim_ms,
            slot=self.slot,
            stamp=self.stamp,
            inline=self.inline,
            deadline_s=deadline_s,
            released_s=released_s,
            missed_deadlines=missed,
        )


class WorkerState:
    """The worker's step counter, its ring and the rate of images sent inline."""

    def __init__(self, ring: ImageRing | None, epoch: int, image_period_s: float) -> None:
        self.ring = ring
        self.epoch = epoch
        self.image_period_s = image_period_s
        self.k = 0
        self.last_inline = -1e9

    def step(self, sim: StepSim) -> ComputedTick | ErrorReply:
        """Step ``sim`` once: the :class:`ComputedTick` (its images in the ring or inline), or
        the error it raised."""
        t0 = time.perf_counter()
        try:
            tick = sim.step()
        except Exception as exc:
            return error_reply(exc)
        sim_ms = (time.perf_counter() - t0) * 1e3
        self.k += 1
        stamp = (self.epoch << 32) | self.k
        slot = -1
        inline: tuple[UInt8Array, UInt8Array] | None = None
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
        light = (
            tick
            if left is None and right is None
            else replace(tick, left_image=None, right_image=None)
        )
        return ComputedTick(light, bool(sim.done), sim_ms, slot, stamp, inline)


def raise_priority() -> str:
    """Ask for a CPU priority above the web server, the upload workers (nice +10) and a
    browser on the same machine: the loop's deadline is the service's first duty.
    ``SCHED_RR`` where permitted (root, CAP_SYS_NICE; the worker sleeps between ticks), else
    nice −10, else the default, silently."""
    return raise_thread_priority(WORKER_NICE, realtime=True)


class Pace:
    """The worker's fixed-rate schedule for one simulation (``sid``) and run request (``gen``).

    Same rule as :class:`app.service.tick_loop.TickLoop`: deadlines ``period_s`` apart; a tick
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


def _refused(reason: str) -> ErrorReply:
    """A :class:`Run` the worker cannot serve (the parent raises it as a ``RuntimeError``)."""
    return ErrorReply("RuntimeError", reason, "")


class Conn(Protocol):
    """The worker's end of the pipe (a ``multiprocessing`` connection, or a test's stand-in)."""

    def send(self, obj: Reply) -> None: ...
    def recv(self) -> Request: ...
    def poll(self, timeout: float = 0.0) -> bool: ...


class StepSim(Protocol):
    """What the worker steps: :class:`app.sim.docking.DockingSimulation` satisfies it (its
    ``step()`` returns a :class:`DockingTick`, a dataclass the worker copies without images)."""

    @property
    def done(self) -> bool: ...

    def step(self) -> DockingTick: ...


#: builds the simulation for a :class:`Build` (default: ``DockingSimulation``)
SimFactory = Callable[["DockingConfig", "StereoCalibration | None"], StepSim]


@dataclass(frozen=True, slots=True)
class WorkerSpec:
    """What a worker is started with: its image ring (``ring_name`` ``None``: no shared
    memory, images in the pipe), its epoch (the parent's count of workers started: the ring's
    stamps), the period of inline images (s) and the ticks it computes ahead."""

    ring_name: str | None
    ring_slots: int
    ring_capacity: int
    epoch: int
    image_period_s: float
    lookahead: int


def attach_state(spec: WorkerSpec) -> WorkerState:
    """The worker's :class:`WorkerState`, attached to the parent's image ring if it has one."""
    ring = None
    if spec.ring_name is not None:
        try:
            ring = ImageRing.attach(spec.ring_name, spec.ring_slots, spec.ring_capacity)
        except OSError:
            ring = None
    return WorkerState(ring, spec.epoch, spec.image_period_s)


class WorkerLoop:
    """The worker's requests and schedule, one pass at a time (:meth:`serve`).

    :class:`Run` starts the worker's own fixed-rate schedule for a built simulation: at each
    deadline it sends the next tick (a :class:`TickMessage`) without being asked, and in
    between computes up to ``lookahead`` ticks ahead (their images go to the ring when
    computed). Requests are read between ticks, never while a deadline is due. A simulation
    that finished or raised ends its schedule (the parent asks again); :class:`Pause`, a new
    :class:`Build` or :class:`Run` replace it. ``now`` / ``sleep``: the clock the schedule
    keeps (s; the machine's monotonic clock in the worker process)."""

    def __init__(
        self,
        conn: Conn,
        state: WorkerState,
        sim_factory: SimFactory,
        *,
        lookahead: int,
        now: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.conn = conn
        self.state = state
        self.sim_factory = sim_factory
        self.lookahead = lookahead
        self.now = now
        self.sleep = sleep
        self.sim: StepSim | None = None
        self.sim_id = -1
        self.ahead: deque[ComputedTick | ErrorReply] = deque()  # computed, not released
        self.pace: Pace | None = None

    @property
    def scheduled(self) -> bool:
        """A schedule runs: :meth:`serve` moves on its own (else it waits for a request)."""
        return self.pace is not None and self.sim is not None

    def _release(self, p: Pace, sim: StepSim) -> bool:
        """Send the tick for the deadline due now; ``False`` ends the schedule."""
        deadline, missed = p.due(self.now())
        computed = self.ahead.popleft() if self.ahead else self.state.step(sim)  # late
        if isinstance(computed, ErrorReply):
            self.conn.send(TickError(p.sid, p.gen, computed))
            return False
        self.conn.send(computed.released(p.sid, p.gen, deadline, self.now(), missed))
        return not computed.done  # the simulation finished with this tick

    def _next_request(self) -> Request | None:
        """Release a due tick, compute one ahead or wait for the deadline (``None``: done one
        of those), else the next request (waited for while no schedule runs)."""
        pace, sim, conn = self.pace, self.sim, self.conn
        if pace is not None and sim is not None:
            now = self.now()
            if now >= pace.next_t:
                if not self._release(pace, sim):
                    self.pace = None
                return None
            if conn.poll(0):
                pass  # a request first
            elif (
                len(self.ahead) < self.lookahead
                and not sim.done
                and not (self.ahead and isinstance(self.ahead[-1], ErrorReply))  # a raise ends it
            ):
                self.ahead.append(self.state.step(sim))
                return None
            elif not conn.poll(max(0.0, pace.next_t - now - POLL_SLACK_S)):
                self.sleep(max(0.0, pace.next_t - self.now()))  # ms-rounded poll
                return None  # the deadline
        return conn.recv()

    def serve(self) -> bool:
        """One pass: a tick released, computed ahead or waited for, or one request served;
        ``False`` once the worker is to exit (:class:`Stop`, or the parent is gone)."""
        try:
            msg = self._next_request()
        except (EOFError, OSError):
            return False  # the parent is gone
        if msg is None:
            return True
        conn = self.conn
        match msg:
            case Stop():
                return False
            case Ping():
                conn.send(Pong(pid=os.getpid()))
            case Build(sid=new_id, config=dcfg, calibration=wire):
                try:
                    calibration = None if wire is None else calibration_from_wire(wire)
                    new = self.sim_factory(dcfg, calibration)
                except Exception as exc:
                    conn.send(error_reply(exc))  # the running simulation (and schedule) is kept
                    return True
                self.sim, self.sim_id, self.pace = new, new_id, None
                self.ahead.clear()
                conn.send(Built(sid=new_id, done=bool(new.done)))
            case Run(sid=sid, gen=gen, period_s=period_s, first_deadline_s=first_deadline_s):
                if self.sim is None or sid != self.sim_id:
                    conn.send(TickError(sid, gen, _refused("stale simulation source")))
                elif not self.ahead and self.sim.done:
                    conn.send(TickError(sid, gen, _refused("simulation finished")))
                else:
                    self.pace = Pace(sid, gen, float(period_s), float(first_deadline_s))
            case Pause():
                self.pace = None  # the ticks computed ahead are kept for the next run
            case _:
                unknown = f"unknown request {type(msg).__name__}"
                conn.send(ErrorReply("RuntimeError", unknown, ""))
        return True


def default_sim_factory(
    config: DockingConfig, calibration: StereoCalibration | None
) -> DockingSimulation:
    """The docking simulation (vision in the loop) for ``config`` (the worker's default)."""
    from app.sim.docking import DockingSimulation

    return DockingSimulation(config, calibration=calibration)


def worker_main(conn: Connection, spec: WorkerSpec, sim_factory: SimFactory | None) -> None:
    """Entry point of the worker process: compile the kernels, say :class:`Ready`, then serve
    :class:`Build`, :class:`Run`, :class:`Pause`, :class:`Ping` and :class:`Stop`
    (:class:`WorkerLoop`) until :class:`Stop` or the parent is gone. ``sim_factory`` (picklable;
    ``None``: :func:`default_sim_factory`) builds each simulation."""
    # Ctrl-C, and the SIGTERM a service manager sends the whole group (systemd, a shell's
    # `timeout`), are the parent's to handle: it stops the worker itself at shutdown (Stop,
    # else SIGKILL); a worker that died of the group's SIGTERM would be replaced meanwhile
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    policy = raise_priority()
    state = attach_state(spec)
    from app.sim.warmup import compile_kernels

    compile_kernels()  # the compiled loops loaded (disk cache) before the first deadline
    gc.collect()
    gc.freeze()  # the modules out of the cyclic collector's sight (its pauses stay short)
    loop = WorkerLoop(conn, state, sim_factory or default_sim_factory, lookahead=spec.lookahead)
    conn.send(Ready(pid=os.getpid(), policy=policy))
    while loop.serve():
        pass
    if state.ring is not None:
        state.ring.close()
