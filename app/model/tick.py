"""The tick record: one published step of any producer (the simulation, a camera, video or
pushed stream, an uploaded pair) — the one shape of the telemetry WebSocket, the history, the
recordings and the MCAP ``/telemetry`` channel — and its parts."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from app.model.pose import PoseResult

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
        "a switch, a restart; app.service.source_epoch); None for uploads",
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
