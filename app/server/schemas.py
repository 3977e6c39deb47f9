"""Pydantic records of the service: the tick record (both sources), sim config, health, etc."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

# the simulation's configuration lives in the core (the 3-D view uses it without the web layer)
from app.sim.sim_config import STRICT, HoseModel, SimConfig, Turbulence
from app.vision.drogue import DrogueProfile
from app.vision.result import PoseResult

Vec3 = tuple[float, float, float]
#: a docking run's outcome class: ``app.sim.docking.outcomes.OUTCOMES`` (kept equal by a test;
#: not imported here, ``app.sim.docking`` builds the simulation on import)
RunOutcome = Literal[
    "captured", "rim_strike", "missed", "aborted", "departure", "keep_out", "error"
]


class Control(BaseModel):
    """Normalised control deflections of the receiver (−1..1, throttle 0..1)."""

    throttle: float
    aileron: float
    elevator: float
    rudder: float


class Guidance(BaseModel):
    """Guidance of a camera stream (``app.streams.guidance``): approach frame of the left
    camera (x forward, y right, z down; m), from the drogue filter's estimate."""

    closure_speed_mps: float | None = None
    predicted_miss_m: float | None = None
    time_to_contact_s: float | None = None
    drogue_velocity_mps: Vec3 | None = None
    coast_s: float = Field(0.0, description="time since the filter last accepted a lock (s)")


class StreamInfo(BaseModel):
    """The frame source behind a stream record (video, camera, push)."""

    spec: str
    frame: int = Field(description="the source's frame number (pushed: the pusher's seq)")
    frame_t_s: float = Field(description="capture time on the source's clock (s)")
    mode: str = Field(description="tracker: acquired / tracked / lost / error")
    fps: float
    pairs: int
    dropped_skew: int
    dropped_backpressure: int
    skew_ms: float | None = None


class HoseInfo(BaseModel):
    """The flown hose of a simulated tick (tanker frame, m; N)."""

    nodes_m: list[Vec3] = Field(
        description="the hose's nodes, reel exit first, drogue last (tanker frame, m)"
    )
    tension_n: float | None = Field(
        None, description="the tick's highest segment tension (N; multi-body hose only)"
    )
    payout_m: float | None = Field(
        None, description="the reel's payout (m; the full trail length when not taken up)"
    )
    contact_peak_tension_n: float | None = Field(
        None, description="the latched contact's peak hose tension so far (N; else None)"
    )


class TickRecord(BaseModel):
    """One published step: a simulated tick or an uploaded stereo pair.

    Positions ``*_m`` are in the tanker-fixed inertial frame (m); ``pose`` is the pipeline's
    result in the left-camera frame (mm).
    """

    seq: int = Field(description="publication counter (monotonic within a server run)")
    source: Literal["sim", "upload", "video", "camera", "push"]
    t_s: float = Field(description="simulation time of this run (s); 0 for uploads")
    clock_s: float = Field(description="server loop clock when published (s)")
    wall_time: float = Field(description="UNIX time when published (s)")
    run: int = Field(0, description="simulation run counter (increments on reset)")
    source_epoch: int | None = Field(
        None,
        description="the epoch of the source that made this tick (one per start of a source: "
        "a switch, a restart; app.server.source_epoch); None for uploads",
    )
    phase: str | None = None
    # run-time assurance (simplex): why the recovery law flies this tick, "break-away: …" or
    # "envelope: …" (app.control.envelope); None while the normal controller (LQR) flies
    rta_reason: str | None = Field(
        None,
        description="why the run-time assurance's recovery law flies this tick "
        "('break-away: …' or 'envelope: …'); None while the normal controller flies",
    )
    # the run's outcome class, on the last tick of a simulated run only (None on the others)
    run_outcome: RunOutcome | None = Field(
        None, description="the run's outcome class, on its last tick only (else None)"
    )
    pose: PoseResult | None = None
    lock: bool = False
    lock_reason: str | None = None
    drogue_truth_m: Vec3 | None = None
    drogue_normal: Vec3 | None = None
    drogue_measured_m: Vec3 | None = None
    drogue_estimate_m: Vec3 | None = None
    probe_tip_m: Vec3 | None = None
    rel_position_m: Vec3 | None = Field(
        None, description="drogue minus probe tip (m), tanker frame"
    )
    reference_m: Vec3 | None = None
    uav_state: list[float] | None = Field(None, description="12-state receiver vector")
    control: Control | None = None
    captured: bool | None = None
    miss_m: float | None = None
    led_truth_cam_mm: list[Vec3] | None = None
    timings_ms: dict[str, float] = Field(
        default_factory=dict, description="per-stage latencies (ms): pipeline stages, step, publish"
    )
    guidance: Guidance | None = None
    stream: StreamInfo | None = None
    hose: HoseInfo | None = Field(None, description="the flown hose (simulated ticks)")


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


class RecordingInfo(BaseModel):
    id: str
    started_wall: float
    stopped_wall: float | None = None
    ticks: int = 0
    active: bool = False
    telemetry_file: str
    scene_file: str | None = None
    telemetry_bytes: int = 0
    scene_bytes: int = 0
    stop_reason: str | None = None


class Message(BaseModel):
    detail: str
