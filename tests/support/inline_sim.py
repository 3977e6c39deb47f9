"""The simulation worker in the test's own process: ``create_app(settings,
source_factory=inline_sim(factory))`` or ``TickLoop(..., source_factory=inline_sim(...))``.

The service takes its one path: the tick loop steps the worker's proxy
(:class:`~app.service.sim_worker.proxy.SimWorker`), which speaks the pipe protocol to the
worker's own loop (:class:`~app.service.sim_worker.worker.WorkerLoop`: the requests, the
schedule, the ticks computed ahead). Only the launcher differs from the deployed service's
spawned process: here the worker's loop runs in the test's process, driven by the parent's
waits on the pipe (each wait serves the worker until it has sent something), on the test's
clock (a :class:`~app.service.clock.FakeClock` makes the schedule deterministic), with a
stand-in simulation the test builds.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque

from app.service.clock import Clock, MonotonicClock
from app.service.sim_worker.proxy import ProcessSourceFactory, process_source_factory
from app.service.sim_worker.wire import Ready, Reply, Request
from app.service.sim_worker.worker import (
    SimFactory,
    WorkerLoop,
    WorkerSpec,
    attach_state,
    default_sim_factory,
)

IDLE_WAIT_S = 0.001  # a wait with nothing to serve sleeps this long between checks


class _Pipe:
    """Both directions of one worker's pipe and the worker's loop, served under one lock."""

    def __init__(self) -> None:
        self.to_worker: deque[Request] = deque()
        self.to_parent: deque[Reply] = deque()
        self.lock = threading.RLock()
        self.loop: WorkerLoop | None = None
        self.dead = False  # the worker's loop ended (Stop) or was killed
        self.closed = False  # the parent closed its end

    def serve_once(self) -> bool:
        """Serve the worker's loop once if it has something to do; whether it did."""
        with self.lock:
            loop = self.loop
            if self.dead or loop is None or not (loop.scheduled or self.to_worker):
                return False
            if not loop.serve():
                self.dead = True
            return True


class _WorkerEnd:
    """The worker's end: what the worker's loop sends and reads (never waits: the loop's
    clock does)."""

    def __init__(self, pipe: _Pipe) -> None:
        self.pipe = pipe

    def send(self, obj: Reply) -> None:
        self.pipe.to_parent.append(obj)

    def recv(self) -> Request:
        if not self.pipe.to_worker:
            raise EOFError("nothing sent to the worker")
        return self.pipe.to_worker.popleft()

    def poll(self, timeout: float = 0.0) -> bool:
        return bool(self.pipe.to_worker)


class _ParentEnd:
    """The parent's end: a wait on it (``poll`` with a timeout) serves the worker's loop."""

    def __init__(self, pipe: _Pipe) -> None:
        self.pipe = pipe

    def send(self, obj: Request) -> None:
        if self.pipe.closed:
            raise OSError("handle is closed")
        self.pipe.to_worker.append(obj)

    def recv(self) -> Reply:
        if not self.pipe.to_parent:
            self.poll(60.0)
        if not self.pipe.to_parent:
            raise EOFError("the worker is gone")
        return self.pipe.to_parent.popleft()

    def poll(self, timeout: float = 0.0) -> bool:
        pipe = self.pipe
        end = time.monotonic() + max(0.0, timeout)
        while True:
            if pipe.closed:
                raise OSError("handle is closed")
            if pipe.to_parent or pipe.dead:
                return True  # a message, or EOF for the next recv
            if timeout <= 0.0:
                return False
            if not pipe.serve_once():
                if time.monotonic() >= end:
                    return False
                time.sleep(IDLE_WAIT_S)

    def close(self) -> None:
        self.pipe.closed = True


class _InlineWorker:
    """The worker as the parent sees it: alive until its loop ends or it is killed."""

    def __init__(self, pipe: _Pipe) -> None:
        self.pipe = pipe

    @property
    def exitcode(self) -> int | None:
        return 0 if self.pipe.dead else None

    def is_alive(self) -> bool:
        return not self.pipe.dead

    def kill(self) -> None:
        self.pipe.dead = True

    def join(self, timeout: float | None = None) -> None:
        end = time.monotonic() + (5.0 if timeout is None else timeout)
        while not self.pipe.dead and time.monotonic() < end:
            if not self.pipe.serve_once():
                return  # nothing left to serve (a Stop would have ended it)


class InlineLauncher:
    """A ``WorkerLauncher`` whose worker's loop runs in this process on ``clock``."""

    def __init__(self, sim_factory: SimFactory, clock: Clock) -> None:
        self.sim_factory = sim_factory
        self.clock = clock
        self.started = 0

    def __call__(self, spec: WorkerSpec) -> tuple[_InlineWorker, _ParentEnd]:
        pipe = _Pipe()
        pipe.loop = WorkerLoop(
            _WorkerEnd(pipe),
            attach_state(spec),
            self.sim_factory,
            lookahead=spec.lookahead,
            now=self.clock.now,
            sleep=self.clock.sleep,
        )
        pipe.to_parent.append(Ready(pid=os.getpid(), policy="inline"))
        self.started += 1
        return _InlineWorker(pipe), _ParentEnd(pipe)


def inline_sim(
    sim_factory: SimFactory = default_sim_factory,
    *,
    clock: Clock | None = None,
    image_hz: float = float("inf"),
    **worker: float,
) -> ProcessSourceFactory:
    """The tick loop's source factory with the worker's loop in this process: ``sim_factory``
    builds each simulation from its :class:`~app.sim.docking.DockingConfig` and calibration;
    ``clock``: the schedule's (default: real time); ``image_hz``: the images' rate (default:
    every tick's); ``worker``: the proxy's timeouts (``step_timeout_s``, ...)."""
    run_on: Clock = clock or MonotonicClock()
    return process_source_factory(
        launcher=InlineLauncher(sim_factory, run_on),
        now=run_on.now,
        shared_images=False,  # one process: every tick's images travel with it
        image_hz=image_hz,
        **worker,  # type: ignore[arg-type]
    )
