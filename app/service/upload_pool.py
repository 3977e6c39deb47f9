"""Uploaded pairs decoded and processed in an executor: worker processes by default (off the
web server's GIL).

``POST /stereo`` checks the token, the sizes and the image headers in the web server's
process (``app.server.security``, ``app.service.image_guard``); only then are the encoded bytes,
the calibration (:class:`~app.service.sim_worker.wire.WireCalibration`) and the matcher sent to
a :class:`UploadPool` worker, which decodes the pair, checks the decoded sizes and runs a fresh
:class:`NavigationPipeline`. The answer is an :class:`UploadOutcome`: status 200 and the
:class:`PoseResult`, or a 4xx and exactly the detail the in-process route gives.

The workers (``spawn``; ``max_workers = AAR_MAX_CONCURRENT_UPLOADS``, the same bound the
request guard enforces, so nothing queues) run at a lower CPU priority (``nice``): the
closed-loop simulation comes first. A worker that dies breaks a ``ProcessPoolExecutor``; the
pool is then replaced and the request answered 503.

This is the uploads' one execution path: the executor is injectable
(``UploadPool(executor_factory=...)``, threaded from ``create_app(upload_executor=...)``), so a
test that must see the work in its own process gives a thread pool, not another route.

This module imports neither FastAPI nor the server: the workers stay light.
"""

from __future__ import annotations

# sets OPENCV_IO_MAX_IMAGE_PIXELS; first, before cv2 loads (in the workers too)
from app.service import image_guard  # noqa: F401  # isort: skip

import asyncio
import json
import logging
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import BrokenExecutor, Executor, ProcessPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from multiprocessing.process import BaseProcess
from typing import TYPE_CHECKING, ParamSpec, TypeVar

import numpy as np

from app.types import JsonObject

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration
    from app.model.pose import PoseResult
    from app.service.sim_worker.wire import WireCalibration

log = logging.getLogger(__name__)

Params = ParamSpec("Params")  # the arguments of a function run in a worker
Result = TypeVar("Result")  # what it returns
ExecutorFactory = Callable[[int], Executor]  # max_workers → a fresh executor
WORKER_NICE = 10  # uploads are best effort; the tick loop's worker keeps priority


class UploadError(Exception):
    """A 4xx answer of ``POST /stereo`` (status and detail), raised without FastAPI."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(status, detail)
        self.status = status
        self.detail = detail


@dataclass(frozen=True, slots=True)
class UploadOutcome:
    """An upload worker's answer: ``status`` 200 and the ``result``, or a 4xx ``status`` and
    its ``detail`` (``traceback``: the pipeline's, when it raised; else ``""``)."""

    status: int
    result: PoseResult | None = None
    detail: str = ""
    traceback: str = ""


class UploadWorkerCrashed(RuntimeError):
    """The worker processing the upload died (the pool has been replaced)."""


def decode_upload_image(data: bytes, name: str) -> np.ndarray:
    """Bytes (PNG/JPEG/BMP/TIFF) → the pipeline's grey or BGR image (the package's one
    decoder, :func:`app.vision.io.decode_image`: colour is kept where the camera has it);
    ``UploadError(400)`` if not an image."""
    from app.vision.io import decode_image
    from app.vision.preprocess import ImageError

    try:
        return decode_image(data, name)
    except ImageError as exc:
        raise UploadError(400, str(exc)) from None


def check_pair_sizes(
    left: tuple[int, int], right: tuple[int, int], expected: tuple[int, int] | None
) -> None:
    """``(width, height)`` of both images: equal, and the calibration's (else ``UploadError(422)``)."""
    (lw, lh), (rw, rh) = left, right
    if (lw, lh) != (rw, rh):
        raise UploadError(422, f"left and right sizes differ: {lw}x{lh} vs {rw}x{rh}")
    if expected is not None and (lw, lh) != tuple(expected):
        w, h = expected
        raise UploadError(422, f"image size {lw}x{lh} does not match the calibration ({w}x{h})")


# ---- in the worker ----------------------------------------------------------------------------
def _exit_with_parent(parent_pid: int, period_s: float = 1.0) -> None:
    """A pool worker waits on a queue whose write end it holds itself: it would outlive a
    parent killed with -9. This thread ends it once it has been re-parented."""

    def watch() -> None:
        while True:
            time.sleep(period_s)
            if os.getppid() != parent_pid:
                os._exit(0)

    threading.Thread(target=watch, name="aar-parent-watch", daemon=True).start()


def _init_worker(nice: int, parent_pid: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    _exit_with_parent(parent_pid)
    if nice:
        try:  # absolute: the web server's own priority (raised where permitted) is not added
            os.setpriority(os.PRIO_PROCESS, 0, max(nice, os.getpriority(os.PRIO_PROCESS, 0)))
        except OSError:  # pragma: no cover - not permitted here
            pass
    # the heavy imports now, not in the first request
    import app.vision.pipeline  # noqa: F401


@lru_cache(maxsize=4)
def _calibration(key: str) -> StereoCalibration:
    """The calibration of ``key`` (its wire form as JSON text), built once per worker."""
    from app.service.sim_worker.wire import calibration_from_wire

    return calibration_from_wire(json.loads(key))


def process_upload(
    left: bytes,
    right: bytes,
    calibration: WireCalibration,
    matcher: str,
    expected: tuple[int, int] | None,
    drogue: JsonObject | None = None,
) -> UploadOutcome:
    """Decode + size check + pipeline (in a worker) for the configured drogue (its
    ``DrogueProfile.to_dict()``; None: the paper's ring). Never raises for a bad upload."""
    from app.vision.drogue import PAPER_DROGUE, DrogueProfile
    from app.vision.pipeline import NavigationPipeline, PipelineConfig

    try:
        left_img = decode_upload_image(left, "left")
        right_img = decode_upload_image(right, "right")
        check_pair_sizes(
            (left_img.shape[1], left_img.shape[0]),
            (right_img.shape[1], right_img.shape[0]),
            expected,
        )
    except UploadError as exc:
        return UploadOutcome(exc.status, detail=exc.detail)
    calib = _calibration(json.dumps(calibration, sort_keys=True))
    profile = PAPER_DROGUE if drogue is None else DrogueProfile.from_dict(drogue)
    config = profile.pipeline_config(PipelineConfig(matcher=matcher))  # type: ignore[arg-type]
    pipeline = NavigationPipeline(calib, config)
    try:
        result = pipeline.process(left_img, right_img)
    except Exception as exc:  # the contract is a 4xx with a detail, never a 500
        return UploadOutcome(
            422,
            detail=f"pipeline failed: {type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(),
        )
    return UploadOutcome(200, result=result)


def _warm() -> int:
    return os.getpid()


# ---- in the web server ------------------------------------------------------------------------
class RecordingSpawnContext:
    """The ``spawn`` multiprocessing context, keeping every process it makes: the executor's
    workers known through the public context interface (``ProcessPoolExecutor`` makes its
    workers with ``mp_context.Process``), not through the executor's private state."""

    def __init__(self) -> None:
        import multiprocessing

        self._spawn = multiprocessing.get_context("spawn")
        self.processes: list[BaseProcess] = []

    def Process(self, *args: object, **kwargs: object) -> BaseProcess:  # noqa: N802 (the API's name)
        proc = self._spawn.Process(*args, **kwargs)  # type: ignore[arg-type]
        self.processes.append(proc)
        return proc

    def __getattr__(self, name: str) -> object:  # queues, locks, the start method
        return getattr(self._spawn, name)


class SpawnedProcessPool(ProcessPoolExecutor):
    """A ``ProcessPoolExecutor`` on a :class:`RecordingSpawnContext`, which knows its workers."""

    def __init__(self, max_workers: int, nice: int) -> None:
        self.context = RecordingSpawnContext()
        super().__init__(  # type: ignore[call-overload]  # a BaseContext by duck typing
            max_workers=max_workers,
            mp_context=self.context,
            initializer=_init_worker,
            initargs=(nice, os.getpid()),
        )

    def worker_processes(self) -> list[BaseProcess]:
        """The workers started so far (living or not)."""
        return [p for p in self.context.processes if p.pid is not None]


def spawn_process_pool(max_workers: int, nice: int = WORKER_NICE) -> SpawnedProcessPool:
    """The default executor: ``max_workers`` spawned processes at CPU priority ``nice``, each
    ending with this process."""
    return SpawnedProcessPool(max_workers, nice)


def _worker_processes(pool: Executor) -> list[BaseProcess]:
    """``pool``'s worker processes: none for an executor of threads (or another's)."""
    return pool.worker_processes() if isinstance(pool, SpawnedProcessPool) else []


class UploadPool:
    """An executor (by default a spawn ``ProcessPoolExecutor``) that is replaced when it breaks
    (one of its workers died).

    ``executor_factory(max_workers)`` makes each executor (the first and every replacement);
    ``None``: :func:`spawn_process_pool` at ``nice``. A factory's functions and arguments are
    pickled only if its executor pickles them (a ``ThreadPoolExecutor`` does not).
    """

    def __init__(
        self,
        max_workers: int,
        *,
        nice: int = WORKER_NICE,
        executor_factory: ExecutorFactory | None = None,
    ) -> None:
        self.max_workers = max_workers
        self.nice = nice
        self._factory = executor_factory
        self._lock = threading.Lock()
        self._pool = self._new()
        self.restarts = 0
        self.submitted = 0

    def _new(self) -> Executor:
        if self._factory is not None:
            return self._factory(self.max_workers)
        return spawn_process_pool(self.max_workers, self.nice)

    def _replace(self, broken: Executor) -> Executor:
        with self._lock:
            if self._pool is broken:
                log.error("an upload worker died: replacing the upload pool")
                broken.shutdown(wait=False, cancel_futures=True)
                self._pool = self._new()
                self.restarts += 1
            return self._pool

    def warm(self) -> None:
        """Start the workers now (not on the first upload); does not wait for them."""
        with self._lock:
            pool = self._pool
        for _ in range(self.max_workers):
            pool.submit(_warm)

    async def run(
        self, fn: Callable[Params, Result], *args: Params.args, **kwargs: Params.kwargs
    ) -> Result:
        """``fn(*args, **kwargs)`` in a worker (for processes: ``fn`` and its arguments
        pickled); raises ``UploadWorkerCrashed`` if the worker dies."""
        with self._lock:
            pool = self._pool
        try:
            future = pool.submit(fn, *args, **kwargs)
        except BrokenExecutor:
            pool = self._replace(pool)
            future = pool.submit(fn, *args, **kwargs)
        self.submitted += 1
        try:
            return await asyncio.wrap_future(future)
        except BrokenExecutor as exc:
            self._replace(pool)
            raise UploadWorkerCrashed(str(exc) or "worker died") from None

    def pids(self) -> list[int]:
        """The worker processes' ids (``[]`` for an executor of threads)."""
        with self._lock:
            pool = self._pool
        return [p.pid for p in _worker_processes(pool) if p.pid is not None and p.is_alive()]

    def shutdown(self, timeout_s: float = 1.0) -> None:
        """Cancel what is queued, give the workers ``timeout_s`` to exit, then terminate the
        processes among them (at shutdown no request is in flight: uvicorn has finished them;
        threads are not waited for)."""
        with self._lock:
            pool = self._pool
        procs = _worker_processes(pool)
        pool.shutdown(wait=False, cancel_futures=True)
        deadline = time.monotonic() + timeout_s
        for p in procs:
            p.join(timeout=max(0.0, deadline - time.monotonic()))
        for p in procs:
            if p.is_alive():  # still importing, or a job that does not end
                p.terminate()
                p.join(timeout=2.0)
