"""What a docking run produces: :class:`DockingTick` (one tick, tanker frame), the run's
:class:`DockingOutcome` and :class:`TickLog`, a compact per-tick history for plots."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from app.control.envelope import EnvelopeExtremes
from app.model.pose import PoseResult
from app.sim.receiver import INPUT_NAMES, STATE_NAMES
from app.types import FloatArray, Rect

if TYPE_CHECKING:
    from app.model.frames import StereoFrame


@dataclass(frozen=True)
class HoseState:
    """The flown hose this tick (tanker frame, m; N): its nodes from the reel exit (first) to
    the drogue (last); with the multi-body hose also the tick's highest segment tension, the
    reel's payout and the latched contact's peak tension so far (None where the model has none:
    the reduced model has no tension or reel, and before a latch no contact peak)."""

    nodes_m: FloatArray
    tension_n: float | None = None
    payout_m: float | None = None
    contact_peak_tension_n: float | None = None


@dataclass
class DockingTick:
    """Everything one tick produced (tanker frame, m/rad/s unless stated)."""

    t_s: float
    phase: str
    drogue_truth_m: FloatArray
    drogue_normal: FloatArray
    drogue_measured_m: FloatArray | None
    drogue_estimate_m: FloatArray
    probe_tip_m: FloatArray
    uav_state: FloatArray  # 12, absolute: trim + perturbation, position in the tanker frame
    reference_m: FloatArray
    control: FloatArray  # 4, deviation from trim (throttle fraction, rad, rad, rad)
    lock: bool
    lock_reason: str | None
    pose: PoseResult | None  # camera frame, mm
    left_image: NDArray[np.uint8] | None
    right_image: NDArray[np.uint8] | None
    led_truth_cam_mm: FloatArray | None
    captured: bool
    miss_m: float | None  # radial miss at a plane crossing this tick
    rel_position_m: FloatArray  # drogue minus probe tip
    uav_state_names: tuple[str, ...] = STATE_NAMES
    control_names: tuple[str, ...] = INPUT_NAMES
    # unused since the tracker (images are always full-size); kept for compatibility
    image_offsets_px: tuple[tuple[int, int], tuple[int, int]] | None = None
    # render_mode="windows": the rectangles (x0, y0, x1, y1) rendered in the left/right image
    # (pixels elsewhere are 0); None for a full render
    image_windows_px: tuple[list[Rect], list[Rect]] | None = None
    # the camera frame this tick: "ok", "drop", "duplicate" (imperfections) or None (no frame)
    frame_status: str | None = None
    # exposure time (s) of the drogue measurement fused this tick (latency: earlier than t_s)
    measurement_exposure_t_s: float | None = None
    # the left camera's true pose in the tanker frame (R_TC, origin m) when this tick's frame
    # was taken (before the dynamics step): the 3-D view draws the cameras from it, whatever
    # the airframe's mounting
    camera_pose_T: tuple[FloatArray, FloatArray] | None = None
    # run-time assurance (app.control.envelope): why the recovery law flies this tick (a
    # break-away or an envelope recovery; None: the LQR flies)
    rta_reason: str | None = None
    # the run's outcome class (app.sim.docking.outcomes.OUTCOMES) on its last tick; else None
    run_outcome: str | None = None
    # the flown hose (its nodes; the multi-body hose's tension, payout, contact peak)
    hose: HoseState | None = None

    @property
    def stereo_frame(self) -> StereoFrame | None:
        """A simulated tick has no camera stream's frame (its images are the fields)."""
        return None


@dataclass
class DockingOutcome:
    """How a run ended (:mod:`app.sim.docking.outcomes`) and what it measured."""

    outcome: str  # one of app.sim.docking.outcomes.OUTCOMES
    reason: str | None
    envelope: EnvelopeExtremes  # the flown state's extremes (the plant's own values)
    lateral_speed_mps: float  # probe − drogue across the drogue's axis at capture; NaN if none
    hose_whip_risk: bool  # a crossing above 2.6 m/s closure
    recoveries: int  # run-time assurance take-overs (break-aways and recoveries)
    captured: bool
    miss_distance_m: float  # radial miss at the capture (or last) crossing; NaN if never crossed
    closure_speed_mps: float  # at that crossing; NaN if never crossed
    time_to_capture_s: float  # NaN if not captured
    aborts: int
    max_control_saturation: float  # max over the run of |δ − δ_trim| / travel (0..1)
    # the multi-body hose's contact (hose_model="multibody"; NaN / False otherwise or without
    # a latch): the hose's peak tension while latched (N), a whip (slack, then snapped taut
    # above the whip factor × the trail tension), the coupling pulled off the probe
    peak_hose_tension_n: float = math.nan
    hose_whip: bool = False
    hose_released: bool = False

    def to_dict(self) -> dict[str, Any]:
        def f(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        return {
            "outcome": self.outcome,
            "reason": self.reason,
            "envelope": self.envelope.to_dict(),
            "lateral_speed_mps": f(self.lateral_speed_mps),
            "hose_whip_risk": bool(self.hose_whip_risk),
            "recoveries": int(self.recoveries),
            "captured": bool(self.captured),
            "miss_distance_m": f(self.miss_distance_m),
            "closure_speed_mps": f(self.closure_speed_mps),
            "time_to_capture_s": f(self.time_to_capture_s),
            "aborts": int(self.aborts),
            "max_control_saturation": float(self.max_control_saturation),
            "peak_hose_tension_n": f(self.peak_hose_tension_n),
            "hose_whip": bool(self.hose_whip),
            "hose_released": bool(self.hose_released),
        }


@dataclass
class TickLog:
    """Compact per-tick history for plots (optional helper)."""

    t: list[float] = field(default_factory=list)
    rel: list[FloatArray] = field(default_factory=list)
    ref_rel: list[FloatArray] = field(default_factory=list)
    att: list[FloatArray] = field(default_factory=list)
    ctrl: list[FloatArray] = field(default_factory=list)
    phase: list[str] = field(default_factory=list)

    def add(self, tick: DockingTick) -> None:
        self.t.append(tick.t_s)
        self.rel.append(tick.probe_tip_m - tick.drogue_truth_m)
        self.ref_rel.append(tick.reference_m - tick.drogue_truth_m)
        self.att.append(tick.uav_state[6:9].copy())
        self.ctrl.append(tick.control.copy())
        self.phase.append(tick.phase)
