"""The docking scenario's configuration: :class:`DockingConfig` (scenario, sensing, guidance;
SI units unless stated), the guidance each plant flies by default (:data:`PLANT_GUIDANCE`) and
where the probe, nose and cameras sit on each airframe (:data:`AIRFRAME_GEOMETRY`).

Frames and units: see :mod:`app.sim.docking.simulation` (tanker frame, metres; body frame of
the receiver, metres from the CG).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from app.control.envelope import EnvelopeBounds
from app.control.recovery import RecoveryGains
from app.geometry.rotations import look_at_camera
from app.model.mount import CameraMount
from app.sim.camera_sensor import RENDER_MODES
from app.sim.imperfections import Imperfections, resolve
from app.sim.jsbsim_plant import JsbsimCondition
from app.sim.plant import DEFAULT_PLANT, PLANTS
from app.sim.turbulence import LEVELS

#: the hose and drogue models the loop can fly (DockingConfig.hose_model)
HOSE_MODELS = ("reduced", "multibody")


# guidance per plant. The Aerosonde design model follows the drogue's swing (its modes are
# 10–30× faster); the A-4 cannot (lateral position bandwidth ≈ 0.5 rad/s against a 1.6 rad/s
# swing at ζ ≈ 0.08): it holds the swing's mean and judges each approach by where the swing
# will be, breaks away only at a wider margin (it cannot stop inside the last metre: a
# break-away there rarely avoids the crossing and costs an abort) and leads the probe, inside
# 3 m, to the swing predicted at the arrival. The timed closure (hold at a standoff, commit by
# the swing's predicted phase) is off: the fore-aft loop's lag makes the commit's horizon
# ≈ 2.3 s. The measured capture rates of each choice: docs/control.md, docs/models.md.
class PlantGuidance(NamedTuple):
    """The guidance a plant flies by default (each overridable in :class:`DockingConfig`)."""

    smoothing_s: float  # reference smoothing (s; 0: chase the drogue)
    swing_abort: bool  # break-away judged by the swing model
    bow_feedforward: bool  # aim where the bow wave will push the drogue
    timed_closure: bool  # hold at a standoff, commit by the swing's predicted phase
    closure_feedforward: bool  # the closure's steady state and commands fed forward
    abort_margin: float  # break away when the predicted miss exceeds this × capture radius
    swing_lead: float  # lead the probe to this fraction of the swing predicted at the arrival
    # the closure speed's rate of change (m/s²; None: a step): the A-4's engine spools at a
    # limited rate (≈ 0.35 throttle/s, measured on its FDM: app.sim.jsbsim_plant)
    closure_accel_mps2: float | None
    # the first approach as after a break-away: close to the pre-contact position, stabilise
    # there (GuidanceConfig.rejoin_dwell_s) while the swing's mean is identified, then close
    # (field practice: stabilise 3–4.5 m behind the drogue, ../shared/notes/gnc.md)
    stabilise_first: bool


PLANT_GUIDANCE = {
    "linear": PlantGuidance(
        smoothing_s=0.0,
        swing_abort=False,
        bow_feedforward=False,
        timed_closure=False,
        closure_feedforward=False,
        abort_margin=1.5,
        swing_lead=0.0,
        closure_accel_mps2=None,
        stabilise_first=False,
    ),
    "jsbsim": PlantGuidance(
        smoothing_s=8.0,
        swing_abort=True,
        bow_feedforward=True,
        timed_closure=False,
        closure_feedforward=True,
        abort_margin=3.0,
        swing_lead=1.0,
        closure_accel_mps2=0.4,
        stabilise_first=True,
    ),
}

# the monitor's envelope per plant: the A-4's defaults (app.control.envelope); the Aerosonde
# design model (an 11 kg UAV, short period ≈ 44 rad/s) trims at α −2.3° and its
# small-perturbation α and load factor are rough, so its monitor keeps only wide bounds (a
# small UAV's structural limits; it is not an aircraft anyone flies)
PLANT_ENVELOPE = {
    "jsbsim": EnvelopeBounds(),
    "linear": EnvelopeBounds(
        alpha_min_deg=-12.0,
        alpha_max_deg=10.0,
        load_factor_min_g=-5.0,
        load_factor_max_g=7.0,
        kcas_min=100.0,
        kcas_max=400.0,
    ),
}


@dataclass(frozen=True)
class AirframeGeometry:
    """Where the probe tip, the nose (bow wave) and the stereo rig's left camera sit (body
    frame, m from the CG)."""

    probe_tip_body_m: tuple[float, float, float]
    nose_body_m: tuple[float, float, float]
    camera_body_m: tuple[float, float, float]


AIRFRAME_GEOMETRY = {
    # the Aerosonde design model: a probe 3 m ahead of the CG on a 2.9 m span airframe
    "linear": AirframeGeometry((3.0, 0.0, -0.3), (1.0, 0.0, 0.0), (0.0, -0.35, -0.35)),
    # the A-4 (JSBSim's A4: CG 300.3 in aft of the nose, 41.7 ft long): estimates — the probe on
    # the right of the nose, its tip ≈ 0.6 m ahead of it; the nose 7.6 m ahead of the CG; the
    # camera on top of the nose 3 m behind the tip (as on the Aerosonde: the ring stays in view
    # down to contact)
    "jsbsim": AirframeGeometry((8.2, 0.5, -0.3), (7.6, 0.0, 0.0), (5.2, 0.2, -0.6)),
}


@dataclass(frozen=True)
class DockingConfig:
    """Scenario, sensing and guidance parameters (SI units unless stated)."""

    turbulence: str = "light"  # none | light | moderate | severe
    seed: int = 0
    # the commanded closure (m/s): inside the latch window 1.0–2.6 m/s (min/max_closure_mps)
    # with room for the receiver's lag either way
    closure_speed_mps: float = 1.6
    tick_hz: float = 50.0
    vision: bool = True  # False: the true drogue centre is the measurement
    matcher: str = "epipolar"  # "epipolar" | "paper"
    noise_sigma: float = 2.0  # DN, sensor noise of the rendered frames
    clutter: int = 0  # clutter glints per frame
    led_dropout: tuple[int, ...] = ()  # LED ids hidden in every frame
    start_gap_m: float = 10.0
    capture_radius_m: float = 0.305  # the drogue's rim (m)
    # the probe head's radius (m; an estimate for the A-4's nozzle, ≈ 3.5 in across): a
    # capture needs the head inside the rim less this, a head across the rim is a rim strike
    probe_head_radius_m: float = 0.045
    camera_hz: float | None = None  # None: a frame every tick
    # --- beyond the brief's list
    # the receiver plant (app.sim.plant): "jsbsim" — the A-4 on JSBSim's nonlinear FDM at
    # jsbsim_altitude_ft / jsbsim_kcas; "linear" — the Aerosonde design model at airspeed_mps,
    # altitude_m, air_density (the controller's own linear model: fast tests, secondary rows)
    plant: str = DEFAULT_PLANT
    jsbsim_altitude_ft: float = 15000.0
    jsbsim_kcas: float = 230.0
    airspeed_mps: float = 120.0
    altitude_m: float = 3000.0
    air_density: float = 0.909
    start_offset_sigma_m: float = 0.3  # random lateral/vertical start offset (1σ, m)
    station_keep_s: float = 12.0  # refuelling stage after contact (paper: 8–20 s)
    # a break-away flies out to the safe standoff (≈ 6 s) and back (≈ 10 s) before the next
    # attempt: four attempts need ≈ 90 s
    max_time_s: float = 90.0
    max_aborts: int = 3
    coast_limit_s: float = 0.5  # coast on the drogue filter this long, then back off
    bow_wave_force_n: float = 60.0
    led_count: int = 5
    ring_radius_m: float = 0.305
    led_diameter_mm: float = 20.0
    ins_noise: bool = True
    # the coupling latches at a closure of 1.0–2.6 m/s (≤ 5 kt; slower does not latch):
    # docs/control.md, ../shared/notes/gnc.md
    min_closure_mps: float = 1.0
    max_closure_mps: float = 2.6
    # break away when closing faster than max_closure_mps inside this gap (m; 0: never): the
    # receiver cannot shed the excess before the plane (app.control.abort)
    overspeed_gap_m: float = 2.0
    # break away when the probe is predicted to pass high_pass_m above the drogue's centre
    # inside high_gap_m (m; 0: never): the hose rises forward from the drogue
    # (app.control.abort)
    high_gap_m: float = 1.5
    high_pass_m: float = 0.5
    # mounting on the airframe (body frame, m from the CG); None: the plant's airframe's
    # (AIRFRAME_GEOMETRY)
    probe_tip_body_m: tuple[float, float, float] | None = None
    nose_body_m: tuple[float, float, float] | None = None
    camera_body_m: tuple[float, float, float] | None = None
    camera_aim_ahead_m: float = 0.0
    # break away in the last metre when the predicted miss exceeds abort_margin × capture
    # radius (the linear plant: 1.5, not 1.0 — the prediction extrapolates noisy velocities,
    # and under the imperfections 1.0 broke away from approaches that would have captured)
    abort_margin: float | None = None  # None: the plant's (PLANT_GUIDANCE; linear 1.5)
    # "full": render whole frames; "windows": render only the tracker's windows while it
    # tracks (bit-identical there; full frames to acquire) — the fast closed loop
    render_mode: str = "full"
    roi_tracking: bool = False  # deprecated alias of render_mode="windows"
    # flight imperfections (app.sim.imperfections): a preset name or an Imperfections
    imperfections: str | Imperfections = "none"
    # fuse delayed camera measurements at their exposure time (False: as if current; ablation)
    latency_compensation: bool = True
    # weigh each camera fix in the drogue filter by the navigation's own centre covariance
    # (``DrogueFit.center_cov_mm2``: the fit's noise and the calibration's doubt, which grows
    # as Z²) — False: a stereo-geometry model of the noise alone (ablation)
    nav_covariance: bool = True
    # camera fixes knowing the drogue's fore-aft position worse than this (σ, m: far fixes,
    # whose depth error is a calibration bias ∝ Z²) update the drogue filter's cross-stream
    # axes only (app.control.drogue_filter; inf: every fix updates all three)
    fore_aft_fix_sigma_max_m: float = 1.0
    # a lock lost before the last metre (coast limit passed): True — hold the gap (the guidance
    # closes only while the drogue is tracked) and resume when it is re-acquired; False — break
    # away (counts as an abort). Inside the last metre a lost lock always breaks away
    hold_gap_on_lost_lock: bool = True
    roi_margin_px: int = 48  # unused (the tracker sizes its windows)
    # lateral/vertical drogue estimate seen by the guidance through a first-order low-pass of
    # this time constant (s; 0: none; None: the plant's, PLANT_GUIDANCE): a receiver slower
    # than the drogue's swing follows its mean instead of chasing the swing with a lag
    reference_smoothing_s: float | None = None
    # the break-away's predicted miss from the drogue's swing about its smoothed mean
    # (app.control.drogue_swing; needs reference_smoothing_s > 0) instead of a straight-line
    # extrapolation of the relative velocity, which a swinging drogue makes large
    swing_model_abort: bool | None = None  # None: the plant's (PLANT_GUIDANCE)
    # the first approach stabilises at the pre-contact position first (PlantGuidance)
    stabilise_first: bool | None = None  # None: the plant's (PLANT_GUIDANCE)
    # aim where the bow wave will have pushed the drogue at the arrival (app.control.bow_wave,
    # the model's nominal force; needs reference_smoothing_s > 0): None — the plant's
    bow_feedforward: bool | None = None
    # timed closure (needs reference_smoothing_s > 0): hold at ``standoff_gap_m`` and commit to
    # the final closure when the drogue's predicted position at the arrival (swing + bow wave)
    # is within ``commit_radius_m`` of the probe's; None — the plant's (PLANT_GUIDANCE)
    timed_closure: bool | None = None
    # lead the probe, inside ``swing_lead_gap_m``, to this fraction of the drogue's swing
    # predicted for the arrival (app.control.drogue_swing): None — the plant's
    swing_lead: float | None = None
    swing_lead_gap_m: float = 3.0
    standoff_gap_m: float = 1.5
    commit_radius_m: float = 0.12
    # the run-time assurance's envelope (app.control.envelope.EnvelopeBounds; None: the
    # plant's, PLANT_ENVELOPE — the A-4's defaults and sources)
    envelope: EnvelopeBounds | None = None
    # the recovery law's gains (app.control.recovery.RecoveryGains; None: its A-4 defaults)
    recovery: RecoveryGains | None = None
    # the flown hose and drogue (HOSE_MODELS): "reduced" — the reduced-order swing on a static
    # hose shape, welded to the probe at contact (app.sim.hose_drogue); "multibody" — the
    # lumped-mass hose with its reel and coupling (app.sim.hose, through
    # app.sim.docking.multibody_drogue). The guidance's model is the nominal one either way
    hose_model: str = "reduced"

    def jsbsim_condition(self, fuel_lbs: float | None = None) -> JsbsimCondition:
        """The A-4's condition (``fuel_lbs`` None: the aircraft file's load)."""
        return JsbsimCondition(
            altitude_ft=self.jsbsim_altitude_ft, kcas=self.jsbsim_kcas, fuel_lbs=fuel_lbs
        )

    def geometry(self) -> AirframeGeometry:
        """The probe tip, nose and camera mounting (the airframe's unless overridden)."""
        base = AIRFRAME_GEOMETRY[self.plant]
        return AirframeGeometry(
            probe_tip_body_m=self.probe_tip_body_m or base.probe_tip_body_m,
            nose_body_m=self.nose_body_m or base.nose_body_m,
            camera_body_m=self.camera_body_m or base.camera_body_m,
        )

    def camera_mount(self) -> CameraMount:
        """The stereo rig's mount (body frame, m): the left camera at the airframe's camera
        position, aimed (:func:`~app.geometry.rotations.look_at_camera`) at a point
        ``camera_aim_ahead_m`` ahead of the probe tip; the nose and the probe tip. The one
        computation of it (the simulation's and the adapters', through
        :mod:`app.sim.rig_mount`)."""
        g = self.geometry()
        cam = np.asarray(g.camera_body_m, float)
        tip = np.asarray(g.probe_tip_body_m, float)
        aim = tip + np.array([self.camera_aim_ahead_m, 0.0, 0.0])
        return CameraMount(look_at_camera(cam, aim), cam, np.asarray(g.nose_body_m, float), tip)

    def validate(self) -> None:
        if self.plant not in PLANTS:
            raise ValueError(f"plant must be one of {PLANTS}, got {self.plant!r}")
        if self.turbulence not in LEVELS:
            raise ValueError(f"turbulence must be one of {LEVELS}, got {self.turbulence!r}")
        resolve(self.imperfections)
        if self.hose_model not in HOSE_MODELS:
            raise ValueError(f"hose_model must be one of {HOSE_MODELS}, got {self.hose_model!r}")
        if self.render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {self.render_mode!r}")
        if self.matcher not in ("epipolar", "paper"):
            raise ValueError(f"matcher must be 'epipolar' or 'paper', got {self.matcher!r}")
        positive = (
            "closure_speed_mps",
            "tick_hz",
            "start_gap_m",
            "capture_radius_m",
            "airspeed_mps",
        )
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        for gap in ("overspeed_gap_m", "high_gap_m", "high_pass_m"):
            v = getattr(self, gap)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{gap} must be ≥ 0 m, got {v!r}")
        if self.camera_hz is not None and not (0 < self.camera_hz <= self.tick_hz):
            raise ValueError(f"camera_hz must be in (0, tick_hz], got {self.camera_hz!r}")
        if self.noise_sigma < 0 or self.clutter < 0:
            raise ValueError("noise_sigma and clutter must be >= 0")
        if self.envelope is not None:
            self.envelope.validate()
        bad = [i for i in self.led_dropout if not 1 <= int(i) <= self.led_count]
        if bad:
            raise ValueError(f"led_dropout ids must be in 1..{self.led_count}, got {bad}")
