"""FastAPI app factory: ``create_app(settings, clock=...)``.

The ``lifespan`` loads the calibration, starts the viser scene server (pinned port) and the
tick loop (its own thread), and stops them on shutdown. Routes live under ``/api/v1``; the
operators' page is served at ``/``; OpenAPI at ``/docs``.

Hardening (``app.server.security``): every request passes a pure-ASGI guard (Host, Origin,
token, body size, upload concurrency) before its body is read; 422 bodies are always valid
JSON (``app.server.errors``).
"""

from __future__ import annotations

import asyncio
import gc
import logging
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

# sets OPENCV_IO_MAX_IMAGE_PIXELS; first, before anything imports cv2
from app.server import image_guard  # isort: skip

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from app.geometry.calibration import StereoCalibration
from app.server import security
from app.server.camera_view import CameraView
from app.server.dependencies import AppState, CalibrationStore, UploadProcessor
from app.server.errors import validation_exception_handler
from app.server.recording import Recorder
from app.server.routers import (
    calibration,
    camera,
    checkerboard,
    recording,
    sim,
    state,
    stereo,
    stream,
    telemetry,
)
from app.server.schemas import SimConfig
from app.server.settings import WILDCARD_BIND, Settings
from app.server.stream_service import StreamService
from app.server.telemetry import TelemetryHub
from app.server.tick_loop import (
    SERVICE_NICE,
    Clock,
    SourceFactory,
    SourceUnavailable,
    TickLoop,
    default_source_factory,
    raise_thread_priority,
)
from app.server.ws_guard import WebSocketGuard

log = logging.getLogger(__name__)
API_PREFIX = "/api/v1"
PUSH_PATH = f"{API_PREFIX}/stream/push"
GIL_SWITCH_S = 0.0005  # sys.setswitchinterval with the worker process (Python's default: 5 ms)
_warned_opencv: list[bool] = []  # warn once per process


def _viser_client_dir() -> Path | None:
    try:
        from app.viz.service import viser_client_dir
    except ImportError:
        return None
    return viser_client_dir()


def _swagger_static_dir() -> Path | None:
    try:
        import swagger_ui
    except ImportError:
        return None
    path = Path(swagger_ui.__file__).resolve().parent / "static"
    return path if (path / "swagger-ui-bundle.js").is_file() else None


def create_app(
    settings: Settings | None = None,
    clock: Clock | None = None,
    *,
    source_factory: SourceFactory | None = None,
) -> FastAPI:
    """Build the service. ``clock`` and ``source_factory`` are injection points for tests."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # this thread (the event loop) and the threads started from it (viser, the scene,
        # request workers) before a browser and other jobs on the same machine, where
        # permitted; the tick thread higher still, the upload workers lower (nice +10)
        raise_thread_priority(SERVICE_NICE)
        calib = StereoCalibration.load(settings.calibration)
        if settings.trusted_hosts is None and settings.host.strip("[]") in WILDCARD_BIND:
            log.warning(
                "bound to %s but AAR_TRUSTED_HOSTS is not set: only requests with Host %s are "
                "answered (others get 400); set AAR_TRUSTED_HOSTS to this machine's names",
                settings.host,
                ", ".join(settings.effective_trusted_hosts),
            )
        if not image_guard.OPENCV_LIMIT_ACTIVE and not _warned_opencv:
            _warned_opencv.append(True)
            log.warning(
                "cv2 was imported before app.server.main: OpenCV's own pixel limit (%s) "
                "is not in force; uploads are still checked on their headers",
                image_guard.OPENCV_ENV,
            )
        factory: SourceFactory
        process_factory: Any = None
        switch_interval = sys.getswitchinterval()  # restored at shutdown
        if source_factory is not None:  # injected (tests): as given, in this process
            factory = source_factory
        elif settings.sim_in_process:
            factory = default_source_factory
        else:  # the simulation in a worker process, off this process's GIL
            from app.server.sim_process import process_source_factory

            # the tick thread relays each tick through a few system calls, each of which gives
            # the GIL away; with the event loop busy (50 WebSocket clients) taking it back cost
            # up to the switch interval each time (5 ms by default): the relay fell behind
            sys.setswitchinterval(min(sys.getswitchinterval(), GIL_SWITCH_S))

            factory = process_factory = process_source_factory(
                image_hz=settings.image_hz, step_timeout_s=settings.sim_step_timeout_s
            )
        upload_pool: Any = None
        if not settings.uploads_in_process:
            from app.server.upload_pool import UploadPool

            upload_pool = UploadPool(settings.max_concurrent_uploads)
        loop = TickLoop(
            SimConfig(tick_hz=settings.tick_hz, plant=settings.sim_plant),
            calib,
            source_factory=factory,
            clock=clock,
            history_s=settings.history_s,
            auto_restart_s=settings.sim_auto_restart_s,
            realtime=process_factory is not None,  # its tick thread only relays the worker's
        )
        hub = TelemetryHub(settings.telemetry_queue)
        hub.bind_loop(asyncio.get_running_loop())
        recorder = Recorder(
            settings.recordings_dir,
            max_s=settings.recording_max_s,
            max_mb=settings.recording_max_mb,
            max_frames_mb=settings.recording_frames_max_mb,
            min_free_mb=settings.recording_min_free_mb,
            mcap_plant=settings.sim_plant,  # the rig mount of the MCAP log's /tf
        )
        st = AppState(
            settings=settings,
            loop=loop,
            hub=hub,
            calibrations=CalibrationStore(calib),
            uploads=UploadProcessor(calib),
            recorder=recorder,
            upload_pool=upload_pool,
            sim_worker=None if process_factory is None else process_factory.worker,
            camera_view=CameraView(image_hz=settings.image_hz),
        )
        st.streams = StreamService(loop, calib, settings)

        def release_workers() -> None:
            sys.setswitchinterval(switch_interval)
            if process_factory is not None:
                process_factory.close()
            if upload_pool is not None:
                upload_pool.shutdown()

        try:
            _start_services(st, settings, warm=source_factory is None)
            if settings.source.strip() not in ("", "sim"):
                st.streams.switch(settings.source)  # SourceError: the service does not start
        except BaseException:
            st.streams.close()
            if st.viz is not None:
                st.viz.stop()
            release_workers()
            raise
        app.state.aar = st
        # the objects made at start-up (modules, viser, the first runs) out of the cyclic
        # collector's sight: a full collection then takes ≈ 1 ms instead of 70–140 ms, which
        # stopped every thread of this process, the tick thread's relay included
        gc.collect()
        gc.freeze()
        log.info(
            "aar-dock service: tick loop at %.1f Hz (simulation %s), viser on port %s",
            settings.tick_hz,
            "in a worker process" if process_factory is not None else "in this process",
            st.viser_port,
        )
        try:
            yield
        finally:
            app.state.aar = None
            st.streams.close()
            recorder.close()
            loop.stop()
            if st.mavlink is not None:
                st.mavlink.close()
            if st.foxglove is not None:
                st.foxglove.close()
            if st.viz is not None:
                st.viz.stop()
            release_workers()

    def _start_services(st: AppState, settings: Settings, *, warm: bool) -> None:
        loop, hub, recorder, calib = st.loop, st.hub, st.recorder, st.calibrations.current
        if settings.viser_enabled:
            from app.viz.service import VizService

            viz = VizService(
                host=settings.viser_bind_host,
                port=settings.viser_port,
                calibration=calib,
                actions=st,
                scene_hz=settings.scene_hz,
                image_hz=settings.image_hz,
            )
            st.viser_port = viz.start()  # raises if the pinned port is taken
            st.viz = viz
            loop.subscribe(viz.publish)
            recorder.scene_serializer_factory = viz.scene_serializer
            viz.add_scene_listener(recorder.on_scene_update)
        loop.subscribe(hub.publish)
        loop.subscribe(recorder.on_tick)
        loop.subscribe(st.camera_view.on_tick)
        if settings.mavlink is not None:
            from app.server.mavlink_output import MavlinkOutput, default_mount

            st.mavlink = MavlinkOutput(settings.mavlink, default_mount(settings.sim_plant))
            loop.subscribe(st.mavlink.on_tick)
            log.info("MAVLink 2 output to %s", settings.mavlink)
        if settings.foxglove_port is not None:
            from app.server.foxglove_output import FoxgloveOutput

            st.foxglove = FoxgloveOutput(
                settings.foxglove_host,
                settings.foxglove_port,
                calib,
                plant=settings.sim_plant,
                image_hz=settings.foxglove_image_hz,
            )
            loop.subscribe(st.foxglove.on_tick)
            log.info("Foxglove live on ws://%s:%d", settings.foxglove_host, st.foxglove.port)
        if settings.sim_autostart:
            loop.start_sim()  # with a worker process: spawned and the simulation built here
        loop.start()
        if warm and st.upload_pool is not None:
            # the app as deployed: the upload workers start now, not with the first upload
            # (apps with an injected source, i.e. tests, start them on demand)
            st.upload_pool.warm()

    swagger_dir = _swagger_static_dir()
    app = FastAPI(
        title="aar-dock",
        version="0.1.0",
        description="Vision-based probe-and-drogue docking (Luo et al. 2019): live service",
        lifespan=lifespan,
        docs_url=None if swagger_dir is not None else "/docs",
        redoc_url=None,
    )
    if swagger_dir is not None:
        # Swagger UI from local files (FastAPI's default loads it from a CDN)
        app.mount("/docs-static", StaticFiles(directory=swagger_dir), name="docs-static")

        @app.get("/docs", include_in_schema=False)
        def swagger_docs() -> HTMLResponse:
            return get_swagger_ui_html(
                openapi_url=app.openapi_url or "/openapi.json",
                title="aar-dock API",
                swagger_js_url="/docs-static/swagger-ui-bundle.js",
                swagger_css_url="/docs-static/swagger-ui.css",
                swagger_favicon_url="/docs-static/favicon-32x32.png",
            )

    app.state.aar = None
    app.state.settings = settings
    app.add_exception_handler(RequestValidationError, validation_exception_handler)

    async def source_unavailable(request: Request, exc: Exception) -> JSONResponse:
        # the simulation worker could not build (did not start, crashed): nothing changed
        return JSONResponse(
            status_code=503,
            content={"detail": f"simulation unavailable: {exc}"},
            headers={"Retry-After": str(settings.retry_after_s)},
        )

    app.add_exception_handler(SourceUnavailable, source_unavailable)
    # WebSocket caps and per-route message sizes, inside the request guard (Host/Origin first)
    app.add_middleware(WebSocketGuard, settings=settings, push_path=PUSH_PATH)
    security.install(app, settings, API_PREFIX)
    for module in (
        state,
        sim,
        stereo,
        calibration,
        checkerboard,
        recording,
        telemetry,
        stream,
        camera,
    ):
        app.include_router(module.router, prefix=API_PREFIX)

    static_dir = settings.static_dir
    if static_dir.is_dir():
        app.mount("/static", StaticFiles(directory=static_dir), name="static")

        @app.get("/", include_in_schema=False)
        def index() -> FileResponse:
            return FileResponse(static_dir / "index.html")

        @app.get("/favicon.ico", include_in_schema=False)
        def favicon() -> FileResponse:
            return FileResponse(static_dir / "favicon.svg", media_type="image/svg+xml")

    else:

        @app.get("/", include_in_schema=False)
        def index_missing() -> JSONResponse:
            return JSONResponse({"detail": f"static dir {static_dir} missing", "docs": "/docs"})

    client_dir = _viser_client_dir()
    if client_dir is not None:
        # viser's prebuilt client, for offline replay: /viser-client/?playbackPath=<.viser URL>
        app.mount("/viser-client", StaticFiles(directory=client_dir, html=True), name="viser")
    return app
