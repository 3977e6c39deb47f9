"""The typed record flow: what a producer hands over (:class:`Tick`) and the published record.

Three producers publish to the :class:`~app.service.telemetry_bus.TelemetryBus`, each through
one builder here:

* the simulation (``TickLoop``: in-process or the worker process) → :func:`from_sim`, from a
  :class:`SimState` (:class:`app.sim.docking.DockingTick` satisfies it);
* a camera stream (video, camera, push: ``StreamService``) → :func:`from_stream`, from the
  :class:`~app.streams.processor.StreamTick` of :class:`~app.streams.processor.StreamProcessor`;
* an uploaded pair (``POST /stereo``) → :func:`from_upload`, from the pipeline's
  :class:`~app.model.pose.PoseResult`.

The bus stamps a :class:`Tick` (publication counter, loop clock, run) and turns it into the
:class:`~app.model.tick.TickRecord` with :func:`to_record`; its ``raw`` side (the images,
read lazily, and whatever a subscriber may read of the producer's tick) goes to the
subscribers with the record. Positions ``*_m`` are in the tanker-fixed frame (simulation) or
the left camera's approach frame (streams), in metres; ``pose`` is in the left-camera frame
(mm); timings in ms.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, Protocol

import numpy as np
import numpy.typing as npt

from app.model.frames import RawFrame
from app.model.pose import PoseResult
from app.model.tick import Control, Guidance, HoseInfo, StreamInfo, TickRecord
from app.types import FloatArray

if TYPE_CHECKING:
    from app.streams.guidance import GuidanceState
    from app.streams.processor import StreamTick


Source = Literal["sim", "upload", "video", "camera", "push"]
Vec3 = tuple[float, float, float]


class HoseView(Protocol):
    """The flown hose of a simulated tick (:class:`app.sim.docking.HoseState`)."""

    @property
    def nodes_m(self) -> FloatArray: ...
    @property
    def tension_n(self) -> float | None: ...
    @property
    def payout_m(self) -> float | None: ...
    @property
    def contact_peak_tension_n(self) -> float | None: ...


class SimState(RawFrame, Protocol):
    """One simulated tick as the record reads it (:class:`app.sim.docking.DockingTick`).

    Tanker frame, m; ``control``: the 4 deflections from trim; ``uav_state``: the receiver's
    12 states; ``led_truth_cam_mm``: the LEDs' true positions in the left-camera frame (mm);
    ``rta_reason``: why the run-time assurance's recovery law flies this tick (None: the normal
    controller flies); ``run_outcome``: the run's outcome class on its last tick (else None);
    its camera images are the subscribers' raw side of an in-process tick."""

    @property
    def t_s(self) -> float: ...
    @property
    def phase(self) -> str | None: ...
    @property
    def pose(self) -> PoseResult | None: ...
    @property
    def lock(self) -> bool: ...
    @property
    def lock_reason(self) -> str | None: ...
    @property
    def drogue_truth_m(self) -> FloatArray | None: ...
    @property
    def drogue_normal(self) -> FloatArray | None: ...
    @property
    def drogue_measured_m(self) -> FloatArray | None: ...
    @property
    def drogue_estimate_m(self) -> FloatArray | None: ...
    @property
    def probe_tip_m(self) -> FloatArray | None: ...
    @property
    def rel_position_m(self) -> FloatArray | None: ...
    @property
    def reference_m(self) -> FloatArray | None: ...
    @property
    def uav_state(self) -> FloatArray | None: ...
    @property
    def control(self) -> FloatArray | None: ...
    @property
    def captured(self) -> bool | None: ...
    @property
    def miss_m(self) -> float | None: ...
    @property
    def led_truth_cam_mm(self) -> FloatArray | None: ...
    @property
    def rta_reason(self) -> str | None: ...
    @property
    def run_outcome(self) -> str | None: ...
    @property
    def hose(self) -> HoseView | None: ...


@dataclass(frozen=True)
class PacedTiming:
    """A paced source's schedule for one tick, on the machine's monotonic clock (s): the
    deadline it serves, when the worker released it and when this process had read it."""

    deadline_s: float
    released_s: float
    received_s: float | None = None


@dataclass(frozen=True)
class Tick:
    """What a producer hands the telemetry bus for one frame.

    ``sim``: the simulation's state (controller, receiver, truth) when the producer is the
    simulation; ``guidance`` / ``stream``: a camera stream's guidance and source counters;
    ``step_ms``: the producer's step latency (the record's ``timings_ms["step"]``; ``None``
    for an upload, which is not on a schedule), followed by the pose's stage timings and
    ``extra_timings_ms``; ``paced``: the worker's schedule
    (the record gets ``relay``: deadline → record built, and ``recv``: release → read here).
    """

    source: Source
    t_s: float
    pose: PoseResult | None
    lock: bool
    lock_reason: str | None
    step_ms: float | None = None
    sim: SimState | None = None
    guidance: Guidance | None = None
    stream: StreamInfo | None = None
    drogue_measured_m: Vec3 | None = None
    drogue_estimate_m: Vec3 | None = None
    probe_tip_m: Vec3 | None = None
    rel_position_m: Vec3 | None = None
    extra_timings_ms: Mapping[str, float] = field(default_factory=dict)
    paced: PacedTiming | None = None
    raw: RawFrame | None = field(default=None, repr=False)


def _vec(value: npt.ArrayLike | None) -> Vec3 | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float).ravel()
    if arr.size != 3 or not np.all(np.isfinite(arr)):
        return None
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _finite(value: float | None) -> float | None:
    if value is None:
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def from_sim(
    state: SimState,
    *,
    step_ms: float,
    extra_timings_ms: Mapping[str, float] | None = None,
    paced: PacedTiming | None = None,
    raw: RawFrame | None = None,
) -> Tick:
    """A simulated tick (``raw``: what the subscribers read, by default ``state`` itself)."""
    return Tick(
        source="sim",
        t_s=float(state.t_s),
        pose=state.pose,
        lock=bool(state.lock),
        lock_reason=state.lock_reason,
        step_ms=step_ms,
        sim=state,
        drogue_measured_m=_vec(state.drogue_measured_m),
        drogue_estimate_m=_vec(state.drogue_estimate_m),
        probe_tip_m=_vec(state.probe_tip_m),
        rel_position_m=_vec(state.rel_position_m),
        extra_timings_ms=extra_timings_ms or {},
        paced=paced,
        raw=state if raw is None else raw,
    )


def stream_guidance(g: GuidanceState) -> Guidance:
    """The record's :class:`Guidance` of a stream's guidance state (non-finite → ``None``)."""
    return Guidance(
        closure_speed_mps=_finite(g.closure_speed_mps),
        predicted_miss_m=_finite(g.predicted_miss_m),
        time_to_contact_s=_finite(g.time_to_contact_s),
        drogue_velocity_mps=_vec(g.drogue_velocity_mps),
        coast_s=float(g.coast_s) if math.isfinite(g.coast_s) else 0.0,
    )


def from_stream(
    tick: StreamTick,
    info: StreamInfo | None,
    *,
    step_ms: float,
    extra_timings_ms: Mapping[str, float] | None = None,
) -> Tick:
    """A camera stream's pair: the tracker's pose and the drogue filter's guidance (approach
    frame); ``info``: the source's counters."""
    g = tick.guidance
    return Tick(
        source=tick.source,
        t_s=float(tick.t_s),
        pose=tick.pose,
        lock=tick.lock,
        lock_reason=tick.lock_reason,
        step_ms=step_ms,
        guidance=stream_guidance(g),
        stream=info,
        drogue_measured_m=_vec(g.drogue_measured_m),
        drogue_estimate_m=_vec(g.drogue_estimate_m),
        probe_tip_m=_vec(g.probe_tip_m),
        rel_position_m=_vec(g.rel_position_m),
        extra_timings_ms=tick.extra_timings_ms if extra_timings_ms is None else extra_timings_ms,
        raw=tick,
    )


def from_upload(result: PoseResult, raw: RawFrame | None = None) -> Tick:
    """An uploaded pair: the pipeline's result; its stage timings are the record's timings."""
    return Tick(
        source="upload",
        t_s=0.0,
        pose=result,
        lock=result.lock,
        lock_reason=result.reason,
        raw=raw,
    )


def _timings(tick: Tick) -> dict[str, float]:
    timings: dict[str, float] = {} if tick.step_ms is None else {"step": tick.step_ms}
    if tick.pose is not None:
        for name, value in tick.pose.timing_ms.model_dump().items():
            timings[name] = float(value)
    for name, value in tick.extra_timings_ms.items():
        timings[name] = float(value)
    return timings


def _control(c: FloatArray | None) -> Control | None:
    if c is None:
        return None
    c = np.asarray(c, dtype=float).ravel()
    if c.size < 4:
        return None
    return Control(
        throttle=float(c[0]), aileron=float(c[1]), elevator=float(c[2]), rudder=float(c[3])
    )


def _miss(miss: float | None) -> float | None:
    return None if miss is None or not math.isfinite(float(miss)) else float(miss)


def _points(points: FloatArray | None) -> list[Vec3] | None:
    if points is None:
        return None
    return [(float(p[0]), float(p[1]), float(p[2])) for p in np.asarray(points)]


def _hose(hose: HoseView | None) -> HoseInfo | None:
    if hose is None:
        return None
    return HoseInfo(
        nodes_m=_points(hose.nodes_m) or [],
        tension_n=_finite(hose.tension_n),
        payout_m=_finite(hose.payout_m),
        contact_peak_tension_n=_finite(hose.contact_peak_tension_n),
    )


def to_record(
    tick: Tick, *, seq: int, clock_s: float, run: int, source_epoch: int | None = None
) -> TickRecord:
    """The published record of ``tick`` (``seq`` and ``clock_s``: the bus's stamp; ``run``:
    the simulation's run counter; ``source_epoch``: its producer's, see
    :mod:`app.service.source_epoch`)."""
    sim = tick.sim
    record = TickRecord(
        seq=seq,
        source=tick.source,
        t_s=tick.t_s,
        clock_s=clock_s,
        wall_time=time.time(),
        run=run,
        source_epoch=source_epoch,
        phase=None if sim is None else sim.phase,
        rta_reason=None if sim is None else sim.rta_reason,
        run_outcome=None if sim is None else sim.run_outcome,
        pose=tick.pose,
        lock=tick.lock,
        lock_reason=tick.lock_reason,
        drogue_truth_m=None if sim is None else _vec(sim.drogue_truth_m),
        drogue_normal=None if sim is None else _vec(sim.drogue_normal),
        drogue_measured_m=tick.drogue_measured_m,
        drogue_estimate_m=tick.drogue_estimate_m,
        probe_tip_m=tick.probe_tip_m,
        rel_position_m=tick.rel_position_m,
        reference_m=None if sim is None else _vec(sim.reference_m),
        uav_state=(
            None
            if sim is None or sim.uav_state is None
            else [float(x) for x in np.asarray(sim.uav_state).ravel()]
        ),
        control=None if sim is None else _control(sim.control),
        captured=None if sim is None or sim.captured is None else bool(sim.captured),
        miss_m=None if sim is None else _miss(sim.miss_m),
        led_truth_cam_mm=None if sim is None else _points(sim.led_truth_cam_mm),
        timings_ms=_timings(tick),
        guidance=tick.guidance,
        stream=tick.stream,
        hose=None if sim is None else _hose(sim.hose),
    )
    paced = tick.paced
    if paced is not None:  # the worker's deadline is on the monotonic clock
        record.timings_ms["relay"] = (time.monotonic() - paced.deadline_s) * 1e3
        if paced.received_s is not None:  # released → read here (pipe, wake-up, GIL)
            record.timings_ms["recv"] = (paced.received_s - paced.released_s) * 1e3
    return record
