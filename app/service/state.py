"""The running service's state: the active calibration (and the one before it), what the
uploads are processed with, and :class:`AppState`, what the routes, the 3-D scene's actions and
shutdown reach."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from app.geometry.calibration import StereoCalibration
from app.service.camera_view import CameraView
from app.service.mavlink_output import MavlinkOutput
from app.service.recording import Recorder
from app.service.settings import Settings
from app.service.telemetry import TelemetryHub
from app.service.telemetry_bus import TelemetryBus
from app.service.tick_loop import TickLoop
from app.sim.sim_config import SimConfig
from app.vision.drogue import PAPER_DROGUE, DrogueProfile

if TYPE_CHECKING:  # each imported where it runs (viser, the worker pools: optional parts)
    from app.service.foxglove_output import FoxgloveOutput
    from app.service.sim_worker.proxy import SimWorker
    from app.service.stream_service import StreamService
    from app.service.upload_pool import UploadPool
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
    """What uploaded pairs are processed with: the calibration, the configured drogue, the
    count and the image rate to the dashboard.

    Every upload gets a fresh pipeline (0.02 ms to build; built by
    :func:`app.service.upload_pool.process_upload`): uploaded pairs are independent frames, so
    no track (LED-id continuity, 3-LED prior) carries from one to the next, and concurrent
    requests share no state.
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
    upload_pool: UploadPool  # where POST /stereo decodes and processes (worker processes)
    viz: VizService | None = None  # when viser runs
    viser_port: int | None = None
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
