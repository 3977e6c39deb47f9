"""The service's start-up and shutdown: what ``create_app``'s lifespan builds, starts and stops.

Start-up, in order: the threads' CPU priority, the calibration, warnings about the set-up,
then the runtime (:mod:`app.service.runtime`): the simulation's backend, the service's state,
the outputs and the threads. Shutdown stops them in reverse.
"""

from __future__ import annotations

import gc
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import AbstractAsyncContextManager, asynccontextmanager

from fastapi import FastAPI

from app.geometry.calibration import StereoCalibration
from app.service.clock import Clock
from app.service.runtime import (
    build_state,
    release_workers,
    sim_backend,
    start_services,
    stop_services,
    warn_about_setup,
)
from app.service.settings import Settings
from app.service.sim_worker.priority import raise_thread_priority
from app.service.sim_worker.proxy import ProcessSourceFactory
from app.service.upload_pool import ExecutorFactory

log = logging.getLogger(__name__)
SERVICE_NICE = -5  # the web server's threads, where permitted (the tick thread: −10)


def make_lifespan(
    settings: Settings,
    clock: Clock | None,
    source_factory: ProcessSourceFactory | None,
    upload_executor: ExecutorFactory | None = None,
) -> Callable[[FastAPI], AbstractAsyncContextManager[None]]:
    """The app's lifespan: start-up, ``app.state.aar`` while it runs, shutdown
    (``upload_executor``: what runs the uploads, ``None``: worker processes)."""

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # this thread (the event loop) and the threads started from it (viser, the scene,
        # request workers) before a browser and other jobs on the same machine, where
        # permitted; the tick thread higher still, the upload workers lower (nice +10)
        raise_thread_priority(SERVICE_NICE)
        calib = StereoCalibration.load(settings.calibration)
        warn_about_setup(settings)
        backend = sim_backend(settings, source_factory)
        st = build_state(settings, calib, backend, clock, upload_executor)
        try:
            start_services(st, settings, warm=backend.deployed)
        except BaseException:
            st.streams.close()
            if st.viz is not None:
                st.viz.stop()
            release_workers(st, backend)
            raise
        app.state.aar = st
        # the objects made at start-up (modules, viser, the first runs) out of the cyclic
        # collector's sight: a full collection, which stops every thread of this process (the
        # tick thread's relay included), then only walks what was made since
        gc.collect()
        gc.freeze()
        log.info(
            "aar-dock service: tick loop at %.1f Hz (simulation %s), viser on port %s",
            settings.tick_hz,
            "in a worker process" if backend.deployed else "in an injected worker",
            st.viser_port,
        )
        try:
            yield
        finally:
            app.state.aar = None
            stop_services(st, backend)

    return lifespan
