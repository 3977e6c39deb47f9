"""The viser side of the service: server on a pinned port + a throttled scene publisher thread.

The tick loop hands every record to :meth:`VizService.publish` (cheap: it only stores the
latest); a dedicated thread updates the scene at ``scene_hz`` and the images at ``image_hz``,
so the tick loop never waits on the 3-D scene.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import viser

from app.model.frames import RawFrame
from app.model.mount import CameraMount
from app.model.tick import TickRecord
from app.viz.access import AccessPolicy, handshake_path, install_gate
from app.viz.framing import docking_targets, frame_view
from app.viz.gui import DockingGui
from app.viz.scene import DockingScene

log = logging.getLogger(__name__)
UPLOAD_HOLD_S = 8.0  # an uploaded pair stays on the image panels this long
#: the operators' page embeds the 3-D view as ``<viser URL>/index.html``, so its WebSocket
#: connects to this path: there the control panel starts minimized (it would cover the docking;
#: the page has its own controls). Opened directly (``/``), the panel stays open.
EMBED_PATH = "/index.html"
#: before the first tick: a view from the side and above, between receiver and drogue
DEFAULT_VIEW = ((-15.5, 6.0, 4.5), (-15.0, 1.2, 6.2))
INITIAL_FOV_RAD = float(np.radians(50.0))  # the views' vertical field of view
FRAME_ASPECT = 1.0  # frame for a square view: landscape views (wider) see everything too


def viser_client_dir() -> Path | None:
    """viser's prebuilt web client (served for offline ``.viser`` replay)."""
    path = Path(viser.__file__).resolve().parent / "client" / "build"
    return path if (path / "index.html").is_file() else None


class ViserPortError(RuntimeError):
    pass


def start_viser(host: str, port: int) -> viser.ViserServer:
    """Start viser on exactly ``port`` (0 = any free port); raise if it is taken.

    viser silently moves to the next free port when the requested one is busy: we check
    ``server.get_port()`` and fail loudly instead.
    """
    server = viser.ViserServer(host=host, port=port, verbose=False)
    actual = server.get_port()
    if port != 0 and actual != port:
        server.stop()
        raise ViserPortError(
            f"viser port {port} is already in use (set AAR_VISER_PORT or --viser-port)"
        )
    return server


class VizService:
    def __init__(
        self,
        *,
        host: str,
        port: int,
        calibration: Any,
        actions: Any,
        scene_hz: float = 15.0,
        image_hz: float = 5.0,
        plot_hz: float = 5.0,
        capture_radius_m: float = 0.305,
    ) -> None:
        self.host = host
        self.port = port
        self.calibration = calibration
        self.actions = actions
        self.scene_period = 1.0 / scene_hz
        self.image_period = 1.0 / image_hz
        self.plot_period = 1.0 / plot_hz
        self.capture_radius_m = capture_radius_m
        self.server: viser.ViserServer | None = None
        self.scene: DockingScene | None = None
        self.gui: DockingGui | None = None
        self.policy: AccessPolicy | None = None
        self._latest: tuple[Any, Any, Any] | None = None
        self._prev_sim: Any = None
        self._upload: tuple[Any, Any, float] | None = None
        self._lock = threading.Lock()
        self._event = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._listeners: list[Callable[[float], None]] = []
        self._pending_calibration: Any = None
        self._pending_reset = False
        self._framed_run: int | None = None  # the run viser's initial camera frames
        self._minimized: set[int] = set()  # clients whose control panel was minimized
        self.updates = 0

    # ---- lifecycle --------------------------------------------------------------------
    def start(self) -> int:
        self.server = start_viser(self.host, self.port)
        # the 3-D port is no back door: Origin check, and with AAR_TOKEN set no client drives
        # the simulation before it has entered the token (app.viz.access)
        settings = getattr(self.actions, "settings", None)
        self.policy = AccessPolicy.from_settings(settings, viser_port=self.server.get_port())
        install_gate(self.server, self.policy, self._filter_gui_update)
        self.server.gui.set_panel_label("aar-dock: probe-and-drogue docking")
        # a view from the side and above, between the receiver and the drogue (tanker frame, z
        # down) until the first tick; then each run is framed (_reframe_initial)
        cam = self.server.initial_camera
        cam.position, cam.look_at = DEFAULT_VIEW
        cam.fov = INITIAL_FOV_RAD
        self.server.on_client_connect(self._on_client_connect)
        from app.sim.rig_mount import default_mount

        try:
            plant = getattr(settings, "sim_plant", None)
            geometry: CameraMount | None = default_mount(plant)
        except ImportError:  # pragma: no cover - the simulation is part of the package
            geometry = None
        self.scene = DockingScene(self.server, self.calibration, geometry)
        self.gui = DockingGui(self.server, self.actions, policy=self.policy)
        self._thread = threading.Thread(target=self._run, name="aar-viz", daemon=True)
        self._thread.start()
        return self.server.get_port()

    def _filter_gui_update(self, client_id: int, message: Any) -> bool:
        if self.gui is not None:
            return self.gui.filter_update(client_id, message)
        return self.policy is not None and self.policy.may_control(client_id)

    def stop(self) -> None:
        self._stop.set()
        self._event.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self.gui is not None:
            self.gui.close()
        if self.server is not None:
            self.server.stop()

    # ---- framing ----------------------------------------------------------------------
    def _on_client_connect(self, client: Any) -> None:
        """The embedded view (WebSocket on :data:`EMBED_PATH`) starts with its panel minimized.

        The camera is not moved here: a client starts from viser's initial camera, which
        :meth:`_reframe_initial` keeps framed on the current run (a camera set per client
        races with the client applying the initial camera and ends up half of each).
        """
        try:
            if self.server is not None and (
                handshake_path(self.server, int(client.client_id)) == EMBED_PATH
            ):
                client.gui.main_panel.minimize()
                self._minimized.add(int(client.client_id))
        except Exception:
            log.exception("viser: minimizing the panel of client %s failed", client.client_id)

    def _reframe_initial(self, record: TickRecord) -> None:
        """A new run: viser's initial camera (where a new view starts, and "Reset View")
        frames its drogue and receiver; views already open keep their camera."""
        if self.server is None or record.run == self._framed_run:
            return
        points = docking_targets(record)
        if len(points) == 0:
            return
        self._framed_run = record.run
        cam = self.server.initial_camera
        position, look_at = frame_view(points, fov_rad=INITIAL_FOV_RAD, aspect=FRAME_ASPECT)
        cam.look_at = look_at
        cam.position = position

    def views(self) -> list[dict[str, Any]]:
        """Each connected client's camera as its browser reports it (the framing test)."""
        out: list[dict[str, Any]] = []
        if self.server is None:
            return out
        for cid, client in self.server.get_clients().items():
            cam = client.camera
            try:
                out.append(
                    {
                        "client_id": int(cid),
                        "position": [float(v) for v in cam.position],
                        "look_at": [float(v) for v in cam.look_at],
                        "up": [float(v) for v in cam.up_direction],
                        "fov_rad": float(cam.fov),
                        "width_px": int(cam.image_width),
                        "height_px": int(cam.image_height),
                        "panel_minimized": int(cid) in self._minimized,
                    }
                )
            except AssertionError:  # no camera message from this client yet
                continue
        return out

    def targets(self) -> list[list[float]]:
        """The points the framing keeps in view (drogue, probe tip, receiver), tanker frame (m)."""
        with self._lock:
            record = self._prev_sim
        return [] if record is None else docking_targets(record).tolist()

    # ---- inputs -----------------------------------------------------------------------
    def publish(self, record: TickRecord, raw: RawFrame | None) -> None:
        """Tick-loop subscriber: keep only the latest; the viz thread picks it up."""
        with self._lock:
            if record.source == "upload":
                self._upload = (record, raw, time.monotonic())
            else:
                prev = self._prev_sim
                frame_uav = prev.uav_state if prev is not None and prev.run == record.run else None
                self._latest = (record, raw, frame_uav)
                self._prev_sim = record
        if self.gui is not None:
            self.gui.record(record)
        self._event.set()

    def add_scene_listener(self, fn: Callable[[float], None]) -> None:
        """``fn(dt_s)`` after each scene update (the recorder's ``insert_sleep``)."""
        self._listeners.append(fn)

    def scene_serializer(self) -> Any:
        assert self.server is not None
        return self.server.get_scene_serializer()

    def set_calibration(self, calibration: Any) -> None:
        with self._lock:
            self._pending_calibration = calibration

    def on_config(self, config: Any) -> None:
        if self.gui is not None:
            self.gui.sync_config(config)
            self.gui.clear()

    def on_reset(self) -> None:
        with self._lock:
            self._pending_reset = True

    # ---- the publisher thread --------------------------------------------------------
    def _run(self) -> None:
        last_scene = last_image = last_plot = 0.0
        last_t = time.monotonic()
        shown_upload = None
        shown_seq = -1
        while not self._stop.is_set():
            self._event.wait(timeout=0.5)
            self._event.clear()
            if self._stop.is_set():
                break
            loop = getattr(self.actions, "loop", None)
            if loop is not None and not getattr(loop, "running", True) and self.gui is not None:
                self.gui.set_stopped()  # no tick arrives to say so
            now = time.monotonic()
            wait = last_scene + self.scene_period - now
            if wait > 0:
                time.sleep(wait)
                now = time.monotonic()
            with self._lock:
                latest = self._latest
                upload = self._upload
                calib, self._pending_calibration = self._pending_calibration, None
                reset, self._pending_reset = self._pending_reset, False
            assert self.scene is not None and self.gui is not None
            try:
                if calib is not None:
                    self.scene.set_calibration(calib)
                if reset:
                    self.scene.reset_trails()
                    self.gui.clear()
                images_due = now - last_image >= self.image_period
                upload_live = upload is not None and now - upload[2] < UPLOAD_HOLD_S
                if upload_live and upload is not None and upload[2] != shown_upload:
                    self.scene.update(upload[0], upload[1], images=True)
                    self.gui.set_images(upload[0], upload[1])
                    self.gui.set_status(upload[0], self._rate(), self._dropped())
                    shown_upload = upload[2]
                    last_image = now
                elif latest is not None and latest[0].seq != shown_seq:
                    record, raw, frame_uav = latest
                    shown_seq = record.seq
                    self._reframe_initial(record)
                    self.scene.update(
                        record, raw, images=images_due and not upload_live, frame_uav=frame_uav
                    )
                    if images_due and not upload_live:
                        self.gui.set_images(record, raw)
                        last_image = now
                    if not upload_live:
                        self.gui.set_status(record, self._rate(), self._dropped())
                if now - last_plot >= self.plot_period:
                    self.gui.refresh_plots(self.capture_radius_m)
                    last_plot = now
                self.updates += 1
            except Exception:
                log.exception("scene update failed")
            last_scene = now
            dt = now - last_t
            last_t = now
            for fn in self._listeners:
                try:
                    fn(dt)
                except Exception:
                    log.exception("scene listener failed")

    def _rate(self) -> float:
        loop = getattr(self.actions, "loop", None)
        return float(loop.tick_rate_hz()) if loop is not None else 0.0

    def _dropped(self) -> int:
        loop = getattr(self.actions, "loop", None)
        return int(loop.dropped) if loop is not None else 0
