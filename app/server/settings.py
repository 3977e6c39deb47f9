"""Service settings (pydantic-settings; environment variables prefixed ``AAR_``).

``AAR_HOST``, ``AAR_PORT``, ``AAR_VISER_PORT``, ``AAR_TICK_HZ``, ``AAR_TOKEN``,
``AAR_CALIBRATION``, ``AAR_MAX_UPLOAD_MB``, ``AAR_RECORDINGS_DIR`` ... (see the fields).
The ``aar-dock serve`` flags override the environment.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_CALIBRATION = REPO_ROOT / "sample_data" / "calibration.json"
DEFAULT_STATIC = REPO_ROOT / "static"


class Settings(BaseSettings):
    """Everything the service needs to start; validated at start-up."""

    model_config = SettingsConfigDict(env_prefix="AAR_", extra="ignore")

    host: str = Field("127.0.0.1", description="FastAPI bind address")
    port: int = Field(8000, ge=0, le=65535, description="FastAPI port")
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
    recordings_dir: Path = Field(Path("recordings"), description="where recordings are written")
    recording_max_s: float = Field(300.0, gt=0.0, description="a recording stops after this")
    recording_max_mb: float = Field(200.0, gt=0.0, description="size bound of one recording")
    history_s: float = Field(60.0, gt=0.0, le=3600.0, description="ring buffer length (s)")
    telemetry_queue: int = Field(64, ge=1, le=10000, description="per-client WebSocket queue")
    sim_autostart: bool = Field(True, description="start the simulated stream at start-up")
    sim_auto_restart_s: float | None = Field(
        3.0, description="restart a finished run (next seed) after this many seconds; None = no"
    )
    scene_hz: float = Field(15.0, gt=0.0, le=60.0, description="3D scene update rate (Hz)")
    image_hz: float = Field(5.0, gt=0.0, le=30.0, description="camera image update rate (Hz)")
    static_dir: Path = Field(DEFAULT_STATIC, description="operators' page assets")
    log_level: str = Field("info")

    @property
    def viser_bind_host(self) -> str:
        return self.viser_host or self.host
