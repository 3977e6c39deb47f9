"""Service settings (pydantic-settings; environment variables prefixed ``AAR_``).

``AAR_HOST``, ``AAR_PORT``, ``AAR_VISER_PORT``, ``AAR_TICK_HZ``, ``AAR_TOKEN``,
``AAR_CALIBRATION``, ``AAR_MAX_UPLOAD_MB``, ``AAR_RECORDINGS_DIR`` ... (see the fields).
The ``aar-dock serve`` flags override the environment.

Hardening (see ``app/server/security.py``): ``AAR_TRUSTED_HOSTS`` and ``AAR_ALLOWED_ORIGINS``
(comma-separated or JSON lists), request-size limits (``AAR_MAX_REQUEST_MB``,
``AAR_MAX_JSON_KB``, ``AAR_MAX_CHECKERBOARD_MB``), image limits (``AAR_MAX_IMAGE_PIXELS``,
``AAR_MAX_CALIBRATION_PIXELS``, ``AAR_MAX_CHECKERBOARD_MPX``) and concurrency
(``AAR_MAX_CONCURRENT_UPLOADS``, ``AAR_MAX_CONCURRENT_CALIBRATIONS``, ``AAR_RETRY_AFTER_S``).

Stream supervision and connection limits (docs/service.md): stream supervision (``AAR_STREAM_FAILURE_STREAK``,
``AAR_STREAM_RESTART_BACKOFF_S``, ``AAR_STREAM_RESTART_BACKOFF_MAX_S``, ``AAR_STREAM_STALL_S``,
``AAR_PUSH_MAX_CLIENTS``) and connection limits (``AAR_MAX_CONNECTIONS``,
``AAR_FD_RESERVE``, ``AAR_KEEP_ALIVE_S``, ``AAR_PUSH_PORT``, ``AAR_HEADER_TIMEOUT_S`` (the Foxglove
gate's), ``AAR_MAX_WEBSOCKETS``, ``AAR_MAX_WEBSOCKETS_PER_CLIENT``,
``AAR_WS_MAX_MESSAGE_KB``, ``AAR_WS_MAX_MESSAGES_PER_S``, ``AAR_WS_MESSAGE_BURST``,
``AAR_PUSH_MAX_MESSAGES_PER_S``, ``AAR_WS_ABUSE_PENALTY_S``).

Where the CPU work runs: the simulation always steps in a worker process
(``app.service.sim_worker``; ``AAR_SIM_STEP_TIMEOUT_S``), the uploads in a process pool
(``app.service.upload_pool``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from app import resources as paths
from app.calibration.plausibility import DEFAULT_MAX_PIXELS as DEFAULT_MAX_CALIBRATION_PIXELS
from app.sim.plant import DEFAULT_PLANT
from app.sim.sim_config import Plant

if TYPE_CHECKING:
    from app.vision.drogue import DrogueProfile

LOCAL_HOSTS = ("localhost", "127.0.0.1", "::1")
WILDCARD_BIND = ("0.0.0.0", "::", "")

# shipped inside the package (app/resources.py): found from a wheel as from the checkout
DEFAULT_CALIBRATION = paths.sample_data_dir() / "calibration.json"
DEFAULT_STATIC = paths.static_dir()


def default_recordings_dir() -> Path:
    """``$XDG_DATA_HOME/aar-dock/recordings`` (``~/.local/share/...``): never the working tree."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "aar-dock" / "recordings"


class Settings(BaseSettings):
    """Everything the service needs to start; validated at start-up."""

    model_config = SettingsConfigDict(env_prefix="AAR_", extra="ignore")

    host: str = Field("127.0.0.1", description="FastAPI bind address")
    port: int = Field(8000, ge=0, le=65535, description="FastAPI port")
    push_port: int | None = Field(
        None,
        ge=0,
        le=65535,
        description="a listener of its own for the push WebSocket (the proxy routes "
        "/api/v1/stream/push there); set, the main port takes WebSocket messages of "
        "AAR_WS_MAX_MESSAGE_KB only",
    )
    viser_host: str | None = Field(None, description="viser bind address (default: host)")
    viser_port: int = Field(
        8080, ge=0, le=65535, description="viser port, pinned (0 = any free port)"
    )
    viser_enabled: bool = Field(True, description="start the viser 3D scene server")
    public_viser_url: str | None = Field(
        None, description="viser URL the page embeds (default: same host as the page, viser port)"
    )
    tick_hz: float = Field(30.0, gt=0.0, le=200.0, description="tick loop rate (Hz)")
    token: str | None = Field(None, description="bearer token for mutating endpoints")
    calibration: Path = Field(DEFAULT_CALIBRATION, description="stereo calibration JSON")
    max_upload_mb: float = Field(20.0, gt=0.0, description="largest accepted upload (MB)")
    recordings_dir: Path = Field(
        default_factory=default_recordings_dir, description="where recordings are written"
    )
    recording_max_s: float = Field(
        900.0, gt=0.0, description="a recording stops after this (s; 15 min)"
    )
    recording_max_mb: float = Field(200.0, gt=0.0, description="size bound of one recording")
    history_s: float = Field(60.0, gt=0.0, le=3600.0, description="ring buffer length (s)")
    telemetry_queue: int = Field(64, ge=1, le=10000, description="per-client WebSocket queue")
    sim_autostart: bool = Field(True, description="start the simulated stream at start-up")
    sim_plant: Plant = Field(
        DEFAULT_PLANT,
        description="receiver plant of the simulated stream: jsbsim (the A-4 on JSBSim) or "
        "linear (the controller's design model)",
    )
    sim_auto_restart_s: float | None = Field(
        3.0, description="restart a finished run (next seed) after this many seconds; None = no"
    )
    scene_hz: float = Field(15.0, gt=0.0, le=60.0, description="3D scene update rate (Hz)")
    image_hz: float = Field(5.0, gt=0.0, le=30.0, description="camera image update rate (Hz)")
    static_dir: Path = Field(DEFAULT_STATIC, description="operators' page assets")
    sim_step_timeout_s: float = Field(
        5.0,
        gt=0.0,
        le=600.0,
        description="a simulation worker that does not answer a step "
        "within this is killed and replaced",
    )
    log_level: str = Field("info")

    # ---- live stereo streams (app.streams; app/service/stream_service.py) -------------
    source: str = Field(
        "sim",
        description="frame source at start-up: sim, push, video:LEFT,RIGHT, video:DIR "
        "(a frame recording), camera:I,J or camera:I (side-by-side)",
    )
    stream_max_skew_ms: float = Field(
        10.0, ge=0.0, le=1000.0, description="left/right pairing tolerance (ms)"
    )
    stream_realtime: bool = Field(
        True, description="pace video sources at their own frame times (false: as fast as possible)"
    )
    stream_loop: bool = Field(False, description="restart a video source at its end")
    stream_fps: float = Field(
        30.0, gt=0.0, le=1000.0, description="frame rate of image folders without timestamps"
    )
    stream_roots: Annotated[list[Path] | None, NoDecode] = Field(
        None,
        description="folders a video source switched through the API may read from "
        "(default: the recordings directory); the --source flag is not restricted",
    )
    recording_frames_max_mb: float = Field(
        24000.0,
        gt=0.0,
        description="size bound of the raw frames of one recording (MB): ≈ 13 min of the "
        "lossless default at 30 Hz on 1280×1024 (docs/ecosystem.md); the MCAP log holds them "
        "again, so the free-space floor is checked against both",
    )
    recording_min_free_mb: float = Field(
        512.0,
        ge=0.0,
        description="free space (MB) a frame recording needs to start (else 507), and below "
        "which a running one stops; 0: no floor",
    )
    push_max_mb: float | None = Field(
        None,
        gt=0.0,
        description="largest pushed WebSocket message (MB); default AAR_MAX_REQUEST_MB",
    )

    # ---- stream supervision (app/service/stream_service.py) ---------------------------
    stream_failure_streak: int = Field(
        20, ge=1, le=100_000, description="failed pairs in a row that restart a frame source"
    )
    stream_restart_backoff_s: float = Field(
        0.5, gt=0.0, le=600.0, description="first wait before a failed source is reopened (s)"
    )
    stream_restart_backoff_max_s: float = Field(
        30.0, gt=0.0, le=3600.0, description="longest wait between reopening attempts (s)"
    )
    stream_stall_s: float = Field(
        5.0,
        gt=0.0,
        le=3600.0,
        description="a camera/video source without a frame, or a pushed pair unread, this "
        "long is stalled (degraded, restarted)",
    )
    push_max_clients: int = Field(
        1, ge=1, le=64, description="pushers connected at once; one more is refused (1008)"
    )

    # ---- connections (uvicorn's limits: app/server/server_limits.py; the ASGI guards) ---
    max_connections: int = Field(
        1024,
        ge=8,
        le=1_000_000,
        description="open connections (HTTP and WebSocket); also capped at the file-descriptor "
        "limit minus AAR_FD_RESERVE",
    )
    fd_reserve: int = Field(
        128, ge=16, le=100_000, description="file descriptors kept free for everything else"
    )
    header_timeout_s: float = Field(
        10.0,
        gt=0.0,
        le=600.0,
        description="time to send the handshake's head on the Foxglove "
        "gate (s); on the HTTP port it is the proxy's client_header_timeout",
    )
    keep_alive_s: float = Field(5.0, gt=0.0, le=600.0, description="idle keep-alive timeout (s)")
    max_websockets: int = Field(
        256, ge=1, le=100_000, description="WebSocket connections at once (else 503)"
    )
    max_websockets_per_client: int = Field(
        64, ge=1, le=100_000, description="WebSocket connections from one address (else 429)"
    )
    ws_max_message_kb: float = Field(
        4.0,
        gt=0.0,
        le=1_000_000.0,
        description="largest message on WebSockets other than the push route (kB)",
    )
    ws_max_messages_per_s: float = Field(
        10.0,
        gt=0.0,
        le=1e6,
        description="sustained messages a second a client may send on a WebSocket other than "
        "the push route (the telemetry socket needs none)",
    )
    ws_message_burst: int = Field(
        20, ge=1, le=1_000_000, description="messages a WebSocket client may send in a burst"
    )
    push_max_messages_per_s: float = Field(
        1000.0,
        gt=0.0,
        le=1e6,
        description="sustained messages a second on the push WebSocket (burst: a fifth of it)",
    )
    ws_abuse_penalty_s: float = Field(
        10.0,
        ge=0.0,
        le=3600.0,
        description="after a WebSocket client is closed for its message rate or size, new "
        "WebSocket handshakes from its address are refused (429) this long",
    )

    # ---- hardening -------------------------------------------------------------------
    trusted_hosts: Annotated[list[str] | None, NoDecode] = Field(
        None,
        description=(
            "Host header values accepted (DNS-rebinding guard); default: localhost, 127.0.0.1, "
            "::1 and the bind host. Entries: names, IPs, '*.example.org', or '*' (any; only "
            "sensible behind a proxy that checks Host). Binding 0.0.0.0 needs this set."
        ),
    )
    allowed_origins: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description=(
            "extra browser origins (scheme://host[:port]) allowed to send mutating requests and "
            "open the telemetry WebSocket; same-origin is always allowed, '*' allows any"
        ),
    )
    max_request_mb: float | None = Field(
        None,
        gt=0.0,
        description="largest POST /stereo request body (MB); default 2 × max_upload_mb + 1",
    )
    max_json_kb: float = Field(
        256.0, gt=0.0, description="largest body of every other request (kB)"
    )
    max_checkerboard_mb: float = Field(
        256.0, gt=0.0, description="largest POST /calibration/checkerboard request body (MB)"
    )
    max_image_pixels: int = Field(
        40_000_000,
        ge=1,
        description="largest uploaded image (width × height), checked on the header",
    )
    max_calibration_pixels: int = Field(
        DEFAULT_MAX_CALIBRATION_PIXELS,
        ge=1,
        description="largest calibration image_size (width × height) PUT /calibration accepts",
    )
    max_checkerboard_mpx: float = Field(
        400.0, gt=0.0, description="total megapixels of one checkerboard set"
    )
    max_concurrent_uploads: int = Field(
        2, ge=1, le=64, description="POST /stereo requests processed at once (else 429)"
    )
    max_concurrent_calibrations: int = Field(
        1, ge=1, le=16, description="checkerboard calibrations run at once (else 429)"
    )
    retry_after_s: int = Field(2, ge=1, le=3600, description="Retry-After of a 429 (s)")
    mavlink: str | None = Field(
        None,
        description="MAVLink 2 output of the navigation result (udpout:HOST:PORT): HEARTBEAT at "
        "1 Hz and LANDING_TARGET per navigation record (docs/ecosystem.md); None: off",
    )
    mavlink_sim: bool = Field(
        False,
        description="also send the simulated stream's targets on MAVLink (SITL), marked "
        "target_num 255; off: only a camera, video, push or MCAP source's",
    )
    mavlink_max_age_s: float = Field(
        0.25,
        gt=0.0,
        le=10.0,
        description="a fix older than this (s) goes out on MAVLink as not valid, and a valid "
        "one not followed by another within it is withdrawn (position_valid 0)",
    )

    foxglove_port: int | None = Field(
        None,
        ge=0,
        le=65535,
        description="live Foxglove WebSocket server on this port (the MCAP log's channels, "
        "images at foxglove_image_hz; behind the service's Host, Origin and token checks: "
        "docs/service.md); None: off",
    )
    foxglove_host: str = Field(
        "127.0.0.1", description="interface of the Foxglove server (loopback unless told)"
    )
    foxglove_max_clients: int = Field(
        32,
        ge=1,
        le=10_000,
        description="Foxglove connections at once (handshakes included); also capped at a sixth "
        "of the file-descriptor limit minus AAR_FD_RESERVE (each costs three descriptors)",
    )
    foxglove_max_clients_per_address: int = Field(
        8, ge=1, le=10_000, description="Foxglove connections from one client address"
    )
    foxglove_allowed_origins: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="browser origins (scheme://host[:port]) allowed to open the Foxglove port "
        "besides AAR_ALLOWED_ORIGINS and the service's own pages, e.g. https://app.foxglove.dev",
    )
    foxglove_image_hz: float = Field(
        5.0, ge=0, le=60, description="stereo pairs per second sent to Foxglove (JPEG)"
    )

    drogue: Path | None = Field(
        None,
        description="the drogue's profile, one JSON file (app/vision/drogue.py): ring radius, "
        "LED count and angles, LED diameter, colour; None: the paper's 75 mm ring for camera, "
        "video, push and upload frames, and a 24-inch basket for the simulated stream",
    )
    ring_radius_mm: float | None = Field(
        None,
        gt=0.0,
        le=10_000.0,
        description="the drogue's ring radius (mm), replacing the profile's",
    )

    def drogue_profile(self) -> DrogueProfile:
        """The drogue camera, video, pushed and uploaded frames are searched for: the profile
        file (else the paper's ring), its radius replaced by ``ring_radius_mm``
        (``DrogueProfileError`` for a bad file)."""
        from app.vision.drogue import PAPER_DROGUE, resolve_drogue

        return resolve_drogue(self.drogue, self.ring_radius_mm, PAPER_DROGUE)

    def sim_drogue_profile(self) -> DrogueProfile:
        """The drogue the simulated stream flies: the configured one if any, else its 24-inch
        basket."""
        from app.vision.drogue import BASKET_24IN

        if self.drogue is None and self.ring_radius_mm is None:
            return BASKET_24IN
        return self.drogue_profile()

    @field_validator("mavlink")
    @classmethod
    def _check_mavlink(cls, v: str | None) -> str | None:
        if v is None or not v.strip():
            return None
        from app.streams.mavlink_link import check_url

        return check_url(v.strip())

    @field_validator(
        "trusted_hosts",
        "allowed_origins",
        "foxglove_allowed_origins",
        "stream_roots",
        mode="before",
    )
    @classmethod
    def _split_list(cls, v: object) -> object:
        if isinstance(v, str):
            text = v.strip()
            if text.startswith("["):
                return json.loads(text)
            return [part.strip() for part in text.split(",") if part.strip()]
        return v

    @property
    def effective_trusted_hosts(self) -> list[str]:
        if self.trusted_hosts is not None:
            return [h.strip().lower().rstrip(".") for h in self.trusted_hosts if h.strip()]
        hosts = list(LOCAL_HOSTS)
        bind = self.host.strip().lower().strip("[]")
        if bind not in WILDCARD_BIND and bind not in hosts:
            hosts.append(bind)
        return hosts

    @property
    def stereo_request_limit_bytes(self) -> int:
        if self.max_request_mb is not None:
            return int(self.max_request_mb * 1e6)
        return int((2 * self.max_upload_mb + 1) * 1e6)

    @property
    def push_limit_bytes(self) -> int:
        if self.push_max_mb is not None:
            return int(self.push_max_mb * 1e6)
        return self.stereo_request_limit_bytes

    @property
    def ws_message_limit_bytes(self) -> int:
        return int(self.ws_max_message_kb * 1e3)

    @property
    def json_limit_bytes(self) -> int:
        return int(self.max_json_kb * 1e3)

    @property
    def checkerboard_limit_bytes(self) -> int:
        return int(self.max_checkerboard_mb * 1e6)

    @property
    def viser_bind_host(self) -> str:
        return self.viser_host or self.host
