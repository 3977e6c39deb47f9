"""FastAPI app factory: ``create_app(settings, clock=...)``.

The lifespan (:mod:`app.server.lifespan`) loads the calibration, starts the viser scene
server (pinned port) and the tick loop (its own thread), and stops them on shutdown. Routes
live under ``/api/v1``; the operators' page is served at ``/``; OpenAPI at ``/docs``.

Hardening (``app.server.security``): every request passes a pure-ASGI guard (Host, Origin,
token, body size, upload concurrency) before its body is read; 422 bodies are always valid
JSON (``app.server.errors``).
"""

from __future__ import annotations

from pathlib import Path

# sets OPENCV_IO_MAX_IMAGE_PIXELS; first, before anything imports cv2
from app.service import image_guard  # noqa: F401  # isort: skip

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from app.server import security
from app.server.errors import validation_exception_handler
from app.server.lifespan import make_lifespan
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
from app.server.ws_guard import WebSocketGuard
from app.service.clock import Clock
from app.service.settings import Settings
from app.service.sim_source import SourceUnavailable
from app.service.sim_worker.proxy import ProcessSourceFactory
from app.service.upload_pool import ExecutorFactory

API_PREFIX = "/api/v1"
PUSH_PATH = f"{API_PREFIX}/stream/push"
ROUTERS = (state, sim, stereo, calibration, checkerboard, recording, telemetry, stream, camera)


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


def _mount_swagger(app: FastAPI, swagger_dir: Path) -> None:
    """Swagger UI from local files (FastAPI's default loads it from a CDN)."""
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


def _install_error_handlers(app: FastAPI, settings: Settings) -> None:
    """422 bodies as valid JSON; a simulation that cannot be built: 503 with Retry-After."""
    app.add_exception_handler(RequestValidationError, validation_exception_handler)

    async def source_unavailable(request: Request, exc: Exception) -> JSONResponse:
        # the simulation worker could not build (did not start, crashed): nothing changed
        return JSONResponse(
            status_code=503,
            content={"detail": f"simulation unavailable: {exc}"},
            headers={"Retry-After": str(settings.retry_after_s)},
        )

    app.add_exception_handler(SourceUnavailable, source_unavailable)


def _mount_pages(app: FastAPI, static_dir: Path) -> None:
    """The operators' page at ``/`` (or a note that its folder is missing) and, when viser
    is installed, its prebuilt client for offline replay."""
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


def create_app(
    settings: Settings | None = None,
    clock: Clock | None = None,
    *,
    source_factory: ProcessSourceFactory | None = None,
    upload_executor: ExecutorFactory | None = None,
) -> FastAPI:
    """Build the service. ``clock``, ``source_factory`` (the simulation's worker: ``None``,
    a worker process) and ``upload_executor`` (what runs ``POST /stereo``'s work:
    ``max_workers`` → an executor; ``None``: worker processes) are injection points for tests."""
    settings = settings or Settings()
    swagger_dir = _swagger_static_dir()
    app = FastAPI(
        title="aar-dock",
        version="0.1.0",
        description="Vision-based probe-and-drogue docking (Luo et al. 2019): live service",
        lifespan=make_lifespan(settings, clock, source_factory, upload_executor),
        docs_url=None if swagger_dir is not None else "/docs",
        redoc_url=None,
    )
    if swagger_dir is not None:
        _mount_swagger(app, swagger_dir)
    app.state.aar = None
    app.state.settings = settings
    app.state.server_limits = None  # set by `aar-dock serve` (server_limits.mark_guarded)
    _install_error_handlers(app, settings)
    # WebSocket caps and per-route message sizes, inside the request guard (Host/Origin first)
    app.add_middleware(WebSocketGuard, settings=settings, push_path=PUSH_PATH)
    security.install(app, settings, API_PREFIX)
    for module in ROUTERS:
        app.include_router(module.router, prefix=API_PREFIX)
    _mount_pages(app, settings.static_dir)
    return app
