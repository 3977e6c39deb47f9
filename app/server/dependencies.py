"""Shared state and request dependencies (token check)."""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from app.geometry.calibration import StereoCalibration
from app.server.camera_view import CameraView
from app.server.mavlink_output import MavlinkOutput
from app.server.recording import Recorder
from app.server.schemas import SimConfig
from app.server.settings import Settings
from app.server.telemetry import TelemetryHub
from app.server.telemetry_bus import TelemetryBus
from app.server.tick_loop import TickLoop
from app.vision.drogue import PAPER_DROGUE, DrogueProfile

if TYPE_CHECKING:  # each imported where it runs (viser, the worker pools: optional parts)
    from app.server.foxglove_output import FoxgloveOutput
    from app.server.sim_worker.proxy import SimWorker
    from app.server.stream_service import StreamService
    from app.server.upload_pool import UploadPool
    from app.vision.pipeline import NavigationPipeline
    from app.viz.service import VizService


class CalibrationStore:
    """The active calibration plus the previous one (for ``POST /calibration/rollback``)."""

    def __init__(self, calibration: StereoCalibration) -> None:
        self.current = calibration
        self.previous: StereoCalibration | None = None
        self._lock = threading.Lock()

    def replace(self, calibration: StereoCalibration) -> None:
        with self._lock:
            self.previous = self.current
            self.current = calibration

    def rollback(self) -> StereoCalibration | None:
        with self._lock:
            if self.previous is None:
                return None
            self.current, self.previous = self.previous, self.current
            return self.current


class UploadProcessor:
    """Navigation pipelines for uploaded pairs.

    Every upload gets a fresh pipeline (0.02 ms to build): uploaded pairs are independent
    frames, so no track (LED-id continuity, 3-LED prior) carries from one to the next, and
    concurrent requests share no state.
    """

    def __init__(
        self, calibration: StereoCalibration, drogue: DrogueProfile = PAPER_DROGUE
    ) -> None:
        self._calibration = calibration
        self.drogue = drogue  # the configured drogue (AAR_DROGUE, AAR_RING_RADIUS_MM)
        self._lock = threading.Lock()
        self.count = 0
        self._last_images: float | None = None

    def images_due(self, period_s: float) -> bool:
        """Whether an upload's images go to the dashboard: at most one upload per
        ``period_s`` (``1 / AAR_IMAGE_HZ``); the others are published without them."""
        now = time.monotonic()
        with self._lock:
            if self._last_images is not None and now - self._last_images < period_s:
                return False
            self._last_images = now
            return True

    def set_calibration(self, calibration: StereoCalibration) -> None:
        with self._lock:
            self._calibration = calibration

    @property
    def calibration(self) -> StereoCalibration:
        return self._calibration

    def pipeline(
        self, matcher: str, calibration: StereoCalibration | None = None
    ) -> NavigationPipeline:
        from app.vision.pipeline import NavigationPipeline, PipelineConfig

        if calibration is None:
            with self._lock:
                calibration = self._calibration
        config = PipelineConfig(matcher=matcher)  # type: ignore[arg-type]
        return NavigationPipeline(calibration, self.drogue.pipeline_config(config))


@dataclass
class AppState:
    """The running service: what the routes, the 3-D scene's actions and shutdown reach."""

    settings: Settings
    loop: TickLoop  # the simulation's schedule and lifecycle
    bus: TelemetryBus  # every source's records: seq, history, subscribers, stage statistics
    hub: TelemetryHub
    calibrations: CalibrationStore
    uploads: UploadProcessor
    recorder: Recorder
    streams: StreamService  # the active frame source (the simulation or a camera stream)
    viz: VizService | None = None  # when viser runs
    viser_port: int | None = None
    upload_pool: UploadPool | None = None  # None: uploads in threads of this process
    sim_worker: SimWorker | None = None  # None: the simulation in the tick thread
    mavlink: MavlinkOutput | None = None  # the MAVLink 2 output (settings.mavlink)
    camera_view: CameraView = field(default_factory=CameraView)  # the page's camera images
    foxglove: FoxgloveOutput | None = None  # Foxglove live (settings.foxglove_port)

    def apply_sim_config(self, config: SimConfig) -> None:
        self.loop.set_config(config)
        if self.viz is not None:
            self.viz.on_config(config)

    def apply_calibration(self, calibration: StereoCalibration) -> None:
        self.loop.set_calibration(calibration)
        self.uploads.set_calibration(calibration)
        self.streams.set_calibration(calibration)
        if self.viz is not None:
            self.viz.set_calibration(calibration)


def get_state(request: Request) -> AppState:
    state: AppState | None = getattr(request.app.state, "aar", None)
    if state is None:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, "service is starting")
    return state


_bearer = HTTPBearer(auto_error=False)


def request_settings(request: Request) -> Settings:
    """The app's settings (``create_app`` keeps them in ``app.state``; the service's state has
    them too). An app without either (a bare router in a test) reads the environment."""
    settings: Settings | None = getattr(request.app.state, "settings", None)
    if settings is None:
        state: AppState | None = getattr(request.app.state, "aar", None)
        settings = state.settings if state is not None else Settings()
    return settings


def require_token(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """Mutating endpoints: if ``AAR_TOKEN`` is set, demand ``Authorization: Bearer <token>``.

    ``app.server.security.RequestGuard`` checks the same before the body is read; this
    dependency stays on every mutating route as a second line (and for apps without the
    guard).
    """
    token = request_settings(request).token
    if not token:
        return
    if credentials is None or not secrets.compare_digest(
        credentials.credentials.encode(), token.encode()
    ):
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "missing or wrong bearer token",
            headers={"WWW-Authenticate": "Bearer"},
        )


StateDep = Annotated[AppState, Depends(get_state)]
