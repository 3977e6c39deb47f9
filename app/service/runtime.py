"""The service's runtime, built, started and stopped: what the web adapter's lifespan
(:mod:`app.server.lifespan`) calls, with no web framework.

Start-up, in order: the simulation's backend (:func:`sim_backend`: a worker process), the
service's state (:func:`build_state`: tick loop, telemetry bus, WebSocket hub,
recorder, stream service), then the outputs subscribed to the bus and the threads started
(:func:`start_services`). Shutdown (:func:`stop_services`) stops them in reverse.
"""

from __future__ import annotations

import asyncio
import logging
import sys
from dataclasses import dataclass

# sets OPENCV_IO_MAX_IMAGE_PIXELS; first, before anything imports cv2
from app.service import image_guard  # isort: skip

from app.geometry.calibration import StereoCalibration
from app.service.camera_view import CameraView
from app.service.clock import Clock
from app.service.recording import Recorder
from app.service.settings import WILDCARD_BIND, Settings
from app.service.sim_worker.proxy import ProcessSourceFactory, process_source_factory
from app.service.state import AppState, CalibrationStore, UploadProcessor
from app.service.stream_service import StreamService
from app.service.telemetry import TelemetryHub
from app.service.tick_loop import TickLoop
from app.service.upload_pool import ExecutorFactory, UploadPool
from app.sim.sim_config import SimConfig

log = logging.getLogger(__name__)
GIL_SWITCH_S = 0.0005  # sys.setswitchinterval with the worker process (Python's default: 5 ms)
_warned_opencv: list[bool] = []  # warn once per process


@dataclass
class SimBackend:
    """The simulation's worker: ``factory`` for the tick loop (it owns the worker);
    ``deployed``: the service's own worker process (``False``: a factory the caller
    injected, e.g. the tests' worker in their process); ``switch_interval_s``: the
    interpreter's GIL switch interval before start-up (restored at shutdown)."""

    factory: ProcessSourceFactory
    deployed: bool
    switch_interval_s: float


def warn_about_setup(settings: Settings) -> None:
    """Log what a deployment should know: an open bind without trusted hosts, OpenCV loaded
    before its pixel limit was set."""
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


def sim_backend(settings: Settings, injected: ProcessSourceFactory | None) -> SimBackend:
    """The simulation's worker: the injected factory (tests: a worker loop in their process)
    or, by default, a worker process off this GIL."""
    switch_interval = sys.getswitchinterval()
    if injected is not None:
        return SimBackend(injected, False, switch_interval)
    # the tick thread relays each tick through a few system calls, each of which gives the
    # GIL away; while the event loop is busy, taking it back can cost up to the switch
    # interval each time (5 ms by default): a shorter one keeps the relay on time
    sys.setswitchinterval(min(switch_interval, GIL_SWITCH_S))
    worker = process_source_factory(
        image_hz=settings.image_hz, step_timeout_s=settings.sim_step_timeout_s
    )
    return SimBackend(worker, True, switch_interval)


def build_state(
    settings: Settings,
    calib: StereoCalibration,
    backend: SimBackend,
    clock: Clock | None,
    upload_executor: ExecutorFactory | None = None,
) -> AppState:
    """The service's parts, built but not started (no thread runs yet). ``upload_executor``:
    what runs the uploads (``None``: the default process pool, :class:`UploadPool`)."""
    upload_pool = UploadPool(settings.max_concurrent_uploads, executor_factory=upload_executor)
    loop = TickLoop(
        SimConfig(
            tick_hz=settings.tick_hz,
            plant=settings.sim_plant,
            drogue=settings.sim_drogue_profile(),
        ),
        calib,
        source_factory=backend.factory,
        clock=clock,
        history_s=settings.history_s,
        auto_restart_s=settings.sim_auto_restart_s,
        realtime=backend.deployed,  # its tick thread only relays the worker's
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
    return AppState(
        settings=settings,
        loop=loop,
        bus=loop.bus,
        hub=hub,
        calibrations=CalibrationStore(calib),
        uploads=UploadProcessor(calib, settings.drogue_profile()),
        recorder=recorder,
        streams=StreamService(loop, calib, settings, loop.bus),
        upload_pool=upload_pool,
        sim_worker=backend.factory.worker,
        camera_view=CameraView(image_hz=settings.image_hz),
    )


def start_viz(st: AppState, settings: Settings) -> None:
    """The viser scene server on its pinned port (raises if the port is taken)."""
    from app.viz.service import VizService

    viz = VizService(
        host=settings.viser_bind_host,
        port=settings.viser_port,
        calibration=st.calibrations.current,
        actions=st,
        scene_hz=settings.scene_hz,
        image_hz=settings.image_hz,
    )
    st.viser_port = viz.start()
    st.viz = viz
    st.bus.subscribe(viz.publish)
    st.recorder.scene_serializer_factory = viz.scene_serializer
    viz.add_scene_listener(st.recorder.on_scene_update)


def start_outputs(st: AppState, settings: Settings) -> None:
    """The bus's subscribers besides the scene: hub, recorder, camera view, MAVLink, Foxglove."""
    bus = st.bus
    bus.subscribe(st.hub.publish)
    bus.subscribe(st.recorder.on_tick)
    bus.subscribe(st.camera_view.on_tick)
    if settings.mavlink is not None:
        from app.service.mavlink_output import MavlinkOutput
        from app.sim.rig_mount import default_mount
        from app.streams.landing_target import RigMount

        st.mavlink = MavlinkOutput(
            settings.mavlink,
            RigMount.on_airframe(default_mount(settings.sim_plant)),
            bus.sources,
            simulated=settings.mavlink_sim,
            max_age_s=settings.mavlink_max_age_s,
            clock=bus.clock,
        )
        bus.subscribe(st.mavlink.on_tick, first=True)  # the wire before the page, recorder
        log.info("MAVLink 2 output to %s", settings.mavlink)
    if settings.foxglove_port is not None:
        from app.service.foxglove_gate import GatePolicy
        from app.service.foxglove_output import FoxgloveOutput

        st.foxglove = FoxgloveOutput(
            settings.foxglove_host,
            settings.foxglove_port,
            st.calibrations.current,
            policy=GatePolicy.from_settings(settings),
            plant=settings.sim_plant,
            image_hz=settings.foxglove_image_hz,
        )
        bus.subscribe(st.foxglove.on_tick)
        log.info("Foxglove live on ws://%s:%d", settings.foxglove_host, st.foxglove.port)


def start_services(st: AppState, settings: Settings, *, warm: bool) -> None:
    """Subscribe the outputs, start the simulation, the tick thread and the configured frame
    source; ``warm``: start the upload workers now (the app as deployed, its simulation in a
    worker process; otherwise they start with the first upload)."""
    if settings.viser_enabled:
        start_viz(st, settings)
    start_outputs(st, settings)
    stream_configured = settings.source.strip() not in ("", "sim")
    if settings.sim_autostart and not stream_configured:  # one source: the configured one
        st.loop.start_sim()  # with a worker process: spawned and the simulation built here
    st.loop.start()
    if warm:
        # the app as deployed: the upload workers start now, not with the first upload
        # (apps with an injected source or the simulation in process start them on demand)
        st.upload_pool.warm()
    if stream_configured:
        st.streams.switch(settings.source)  # SourceError: the service does not start


def release_workers(st: AppState, backend: SimBackend) -> None:
    """Stop the worker processes and restore the GIL switch interval."""
    sys.setswitchinterval(backend.switch_interval_s)
    backend.factory.close()
    st.upload_pool.shutdown()


def stop_services(st: AppState, backend: SimBackend) -> None:
    """Shutdown: the stream, the recorder, the tick thread, the outputs, the workers."""
    st.streams.close()
    st.recorder.close()
    st.loop.stop()
    if st.mavlink is not None:
        st.mavlink.close()
    if st.foxglove is not None:
        st.foxglove.close()
    if st.viz is not None:
        st.viz.stop()
    release_workers(st, backend)
