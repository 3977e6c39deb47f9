"""Pydantic records of the service: sim config updates, health, the page's configuration
(the tick record itself: :mod:`app.model.tick`; a recording's: :mod:`app.service.recording.meta`)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

# the simulation's configuration lives in the core (the 3-D view uses it without the web layer)
from app.sim.sim_config import STRICT, HoseModel, SimConfig, Turbulence
from app.vision.drogue import DrogueProfile


class SimConfigUpdate(BaseModel):
    """Partial update of :class:`SimConfig` (omitted fields keep their value)."""

    model_config = STRICT

    turbulence: Turbulence | None = None
    seed: int | None = None
    closure_speed_mps: float | None = None
    noise_sigma: float | None = None
    clutter: int | None = None
    led_dropout: list[int] | None = Field(None, max_length=5)
    tick_hz: float | None = None
    matcher: Literal["epipolar", "paper"] | None = None
    vision: bool | None = None
    hose_model: HoseModel | None = None


class PlantInfo(BaseModel):
    """The simulated receiver: plant, airframe and its trim at the flight condition."""

    plant: str
    airframe: str
    trim: dict[str, float] = Field(
        description="altitude_ft, kcas, tas_mps, alpha_deg, theta_deg, throttle, weight_lbs, "
        "air_density_kgm3, mach"
    )


class SimStatus(BaseModel):
    running: bool
    run: int
    done: bool
    config: SimConfig
    plant: PlantInfo | None = Field(
        None, description="the configured plant (None when it cannot be built here)"
    )


class HealthComponent(BaseModel):
    """One part of the service that can fail on its own (``tick_loop``, ``stream``)."""

    name: str
    status: Literal["ok", "degraded"]
    reason: str | None = None


class DrogueInfo(BaseModel):
    """A drogue profile (app/vision/drogue.py) as ``/healthz`` and the page show it."""

    label: str
    name: str
    ring_radius_mm: float
    led_count: int
    led_diameter_mm: float
    colour: str
    led_angles_deg: list[float] | None = None

    @classmethod
    def of(cls, drogue: DrogueProfile) -> DrogueInfo:
        angles = None if drogue.led_angles_deg is None else list(drogue.led_angles_deg)
        return cls(
            label=drogue.label,
            name=drogue.name,
            ring_radius_mm=drogue.ring_radius_mm,
            led_count=drogue.led_count,
            led_diameter_mm=drogue.led_diameter_mm,
            colour=drogue.colour,
            led_angles_deg=angles,
        )


class FoxgloveHealth(BaseModel):
    """The Foxglove port (``serve --foxglove-port``): its gate's state and refusals."""

    running: bool
    port: int
    clients: int = Field(description="clients relayed to the Foxglove server now")
    handshakes: int = Field(description="connections still in their handshake")
    served: int = Field(description="clients relayed since start")
    refused: dict[str, int] = Field(
        default_factory=dict,
        description="connections refused, by reason: host, origin, token, not_websocket, "
        "bad_request, handshake_timeout, per_address, total, accept_failed, upstream",
    )


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    source: str = Field("sim", description="the active source: sim, push, video:..., camera:...")
    components: list[HealthComponent] = Field(
        default_factory=list, description="what is degraded and why (each part, ok or not)"
    )
    loop_alive: bool
    sim_running: bool
    tick_hz_target: float
    tick_rate_hz: float = Field(
        description="records a second of the active source (the simulation's ticks, or the "
        "stream's pairs) over the last 2 s"
    )
    last_tick_age_s: float | None
    ticks: int
    dropped_ticks: int
    errors: int = 0
    last_error: str | None = None
    viser: bool
    drogue: DrogueInfo | None = Field(
        None, description="the drogue the active source's navigation looks for"
    )
    configured_drogue: DrogueInfo | None = Field(
        None,
        description="the configured drogue (AAR_DROGUE, AAR_RING_RADIUS_MM; else the paper's "
        "ring): what uploads, cameras and pushed pairs are searched for",
    )
    foxglove: FoxgloveHealth | None = Field(None, description="None: no Foxglove port")


class ServiceConfig(BaseModel):
    """What the operators' page needs to know."""

    viser_port: int | None
    viser_url: str | None
    tick_hz: float
    token_required: bool
    max_upload_mb: float
    image_size: tuple[int, int]


class Message(BaseModel):
    detail: str
