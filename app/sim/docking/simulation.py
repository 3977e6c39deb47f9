"""Closed-loop probe-and-drogue docking (paper §6, Fig. 13, Algorithm 3) as an explicit step function.

Frames and units
----------------
* **Tanker frame** (the simulation's inertial frame; every ``*_m`` quantity here): origin at the
  hose exit on the tanker, moving with the tanker in steady straight-and-level flight at the trim
  airspeed; x forward, y right, z down; metres, radians, seconds. The drogue trails behind and below
  the origin; the receiver approaches from behind (more negative x).
* **Body frame** of the receiver: x nose, y right wing, z down; Euler angles (φ, θ, ψ), 3-2-1.
  Probe tip at ``probe_tip_body_m``; the stereo rig's left camera at ``camera_body_m`` on the nose
  beside and behind the probe, toed in to look at a point ``camera_aim_ahead_m`` ahead of the tip.
* **Camera frame** (measurement frame of the navigation core, :class:`PoseResult`): left camera,
  x right, y down, z forward, **millimetres**. Conversion m ↔ mm happens only in
  :mod:`app.sim.docking.vision`.

One tick (default 50 Hz):

1. own-state sensors (INS-like, with noise) → state observer (eq. 19);
2. a camera frame when due (:mod:`app.sim.docking.vision`): render the LED ring at the true
   drogue pose, run :class:`NavigationPipeline`, the fitted centre to the tanker frame with the
   *estimated* own pose → the drogue filter (``vision=False``: the true centre, an ablation);
3. guidance (:mod:`app.control.reference`, :mod:`app.sim.docking.guidance`: the swing, identified
   online) and the break-away checks (:mod:`app.control.abort`);
4. LQR with integral action (eq. 20), or the run-time assurance's recovery law → actuators;
5. propagate the receiver, the Dryden gusts and the hose–drogue (bow wave included);
6. the plane crossing judged as the field does (:mod:`app.sim.docking.outcomes`: capture inside
   the rim less the probe head's radius at a closure of 1.0–2.6 m/s, rim strike, miss).

Field of view at close range: the cameras sit ``≈ 3 m`` behind the probe tip and are toed in
towards it, so the whole 0.305 m ring stays in both images down to contact (≈ 240 px radius at
3 m on the paper's f ≈ 2350 px rig); inside the last metre the filter still coasts through any
missed frame (bounded by ``coast_limit_s``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from app.control.abort import (
    AlphaBetaTracker,
    describe,
    offset_at_plane_m,
    should_abort,
)
from app.control.bow_wave import BowWaveModel
from app.control.design import closure_feedforward
from app.control.drogue_filter import DrogueFilter
from app.control.envelope import EnvelopeExtremes, EnvelopeMonitor, Separation, separation
from app.control.lqr import IntegralLqr
from app.control.observer import StateObserver
from app.control.recovery import RecoveryLaw
from app.control.reference import GuidanceConfig, ReferenceGenerator
from app.geometry.calibration import StereoCalibration
from app.geometry.rotations import euler_to_matrix
from app.resources import load_default_calibration
from app.sim.camera_sensor import StereoCameraSensor
from app.sim.docking.config import PLANT_ENVELOPE, PLANT_GUIDANCE, DockingConfig
from app.sim.docking.flown_hose import (
    contact_report,
    flown_drogue,
    hose_state,
    nominal_drogue_model,
)
from app.sim.docking.guidance import SwingGuidance
from app.sim.docking.outcomes import (
    ContactReport,
    PlaneCrossing,
    RtaEvent,
    RunClassifier,
    plane_crossing,
)
from app.sim.docking.phases import Aim, Sensing
from app.sim.docking.plant_design import design_for, make_plant
from app.sim.docking.results import DockingOutcome, DockingTick
from app.sim.docking.vision import DrogueFrame, camera_sensor, drogue_in_tanker, take_frame
from app.sim.imperfections import (
    FrameChannel,
    ImperfectionDraw,
    Imperfections,
    InsErrors,
    draw,
    perturbed_calibration,
    resolve,
    wake_downwash,
)
from app.sim.plant import ReceiverPlant
from app.sim.receiver import Actuators
from app.sim.turbulence import DrydenTurbulence
from app.types import FloatArray, Rect

SEARCH_GAP_M = 5.0  # closest gap flown on the a-priori drogue position before acquisition
GUST_HISTORY_TICKS = 64
REARM_GAP_M = 1.5  # gap (m) the probe must open before another break-away counts as an abort


class DockingSimulation:
    """Tick-by-tick closed-loop docking; no threads, all state on the instance."""

    def __init__(self, config: DockingConfig, calibration: StereoCalibration | None = None) -> None:
        config.validate()
        self.config = config
        self.dt = 1.0 / config.tick_hz
        self.plant_design = design_for(config)
        self.models = self.plant_design.design
        self.trim = self.plant_design.trim
        self.airframe = self.plant_design.airframe
        self.airspeed = float(self.models.model.airspeed_mps)  # the tanker's speed (m/s)
        pg = PLANT_GUIDANCE[config.plant]
        smooth, swing, bow_ff, timed = (
            pg.smoothing_s,
            pg.swing_abort,
            pg.bow_feedforward,
            pg.timed_closure,
        )
        closure_ff, margin, lead = pg.closure_feedforward, pg.abort_margin, pg.swing_lead
        self._closure_accel = pg.closure_accel_mps2
        self.smoothing_s = (
            smooth if config.reference_smoothing_s is None else float(config.reference_smoothing_s)
        )
        self.swing_abort = swing if config.swing_model_abort is None else config.swing_model_abort
        self.bow_ff = bow_ff if config.bow_feedforward is None else config.bow_feedforward
        self.timed = timed if config.timed_closure is None else config.timed_closure
        self.closure_ff = closure_ff
        self.swing_lead = lead if config.swing_lead is None else float(config.swing_lead)
        self.abort_margin = margin if config.abort_margin is None else float(config.abort_margin)
        self.stabilise_first = (
            pg.stabilise_first if config.stabilise_first is None else config.stabilise_first
        )
        self._closure_ff = closure_feedforward(self.models.model)
        self._calibration = calibration
        self._camera: StereoCameraSensor | None = None
        if config.vision:
            if self._calibration is None:
                self._calibration = load_default_calibration()
            self._camera = camera_sensor(config, self._calibration, self.effective_render_mode)
        mount = config.camera_mount()  # the rig's mount, computed once
        self.r_probe_b = mount.probe_tip_b
        self.r_nose_b = mount.nose_b
        self.r_cam_b = mount.camera_b
        self.R_bc = mount.r_bc
        self.reset()

    # ------------------------------------------------------------------ set-up
    @property
    def plant(self) -> ReceiverPlant:
        """The plant flown this run (:mod:`app.sim.plant`)."""
        return self._plant

    @property
    def camera(self) -> StereoCameraSensor | None:
        """The stereo camera in the loop (render + tracker; None with ``vision=False``)."""
        return self._camera

    @property
    def frame_channel(self) -> FrameChannel:
        """This run's camera frame channel (:class:`~app.sim.imperfections.FrameChannel`):
        how many frames it dropped and duplicated."""
        return self._channel

    @property
    def effective_render_mode(self) -> str:
        """``render_mode``, or "windows" with the deprecated ``roi_tracking``."""
        return "windows" if self.config.roi_tracking else self.config.render_mode

    def reset(self, seed: int | None = None) -> None:
        """Start a fresh run (same config; ``seed`` overrides the config's seed)."""
        cfg = self.config
        if seed is not None:
            self.config = cfg = replace(cfg, seed=int(seed))
        m = self.models
        if self._camera is not None:
            self._camera.reset()  # a new run: no lock, no LED history from the last
        rng = np.random.default_rng([cfg.seed, 1])
        self._rng_sensor = np.random.default_rng([cfg.seed, 2])
        self._frame_seed = np.random.default_rng([cfg.seed, 3])
        # imperfections: this run's values (own random streams; "none" changes nothing)
        imp = self.imperfections = resolve(cfg.imperfections)
        self.imp_draw: ImperfectionDraw = draw(imp, cfg.seed)
        self._channel = FrameChannel(imp, cfg.seed)
        self._imperfect = imp.active
        self._ins = InsErrors(imp, self.imp_draw, cfg.seed, self.dt) if imp.active else None
        self._latency_ticks = int(round(imp.latency_s / self.dt))
        self._pending: list[tuple[int, int, FloatArray, FloatArray]] = []
        # the last real frame (camera-frame drogue centre m, pose, images, LED truth)
        self._last_cam: DrogueFrame | None = None
        self._plant = make_plant(cfg, self.plant_design, imp, self.imp_draw, self.dt)
        if self._camera is not None:
            self._camera.set_nav_calibration(
                perturbed_calibration(self._camera.render_calibration, imp, self.imp_draw)
            )
        # one flight condition for everything: the plant's trim (altitude, TAS, density)
        trim = self.trim
        self.turb = DrydenTurbulence(
            cfg.turbulence, trim.tas_mps, self.dt, trim.altitude_ft * 0.3048, seed=cfg.seed
        )
        # this run's hose and drogue (the guidance keeps the nominal model: flown_hose)
        self.drogue = flown_drogue(cfg, trim.air_density_kgm3, trim.tas_mps, self.imp_draw, self.dt)
        # receiver at trim, probe tip start_gap behind the drogue's rest position (+ random offset)
        offset = np.concatenate([[0.0], rng.normal(0.0, cfg.start_offset_sigma_m, 2)])
        tip_start = self.drogue.eq_m - np.array([cfg.start_gap_m, 0.0, 0.0]) + offset
        x0 = np.zeros(12)
        x0[9:12] = tip_start - m.tip0_b
        self.x = self._plant.reset(x0)
        self.x_trim = m.model.x_trim.copy()
        self._build_controller(imp)
        self.u_applied = np.zeros(4)
        self.filter = DrogueFilter(
            history=self._latency_ticks + 1,
            hold_after_s=cfg.coast_limit_s,
            fore_aft_fix_sigma_max_m=cfg.fore_aft_fix_sigma_max_m,
        )
        self.tip_tracker = AlphaBetaTracker(self.dt)
        self.drogue_model = nominal_drogue_model(cfg, trim.air_density_kgm3, trim.tas_mps)
        self.bow_model = BowWaveModel(self.drogue_model)
        self.guidance = ReferenceGenerator(
            GuidanceConfig(
                closure_speed_mps=cfg.closure_speed_mps,
                standoff_gap_m=cfg.standoff_gap_m if self.timed else None,
                accel_limit_mps2=self._closure_accel,
            ),
            cfg.start_gap_m,
        )
        if self.stabilise_first and cfg.start_gap_m > self.guidance.cfg.rejoin_gap_m:
            self.guidance.start_stabilise(cfg.start_gap_m)
        if self._imperfect:
            self._settle_on_plant_trim()
        # the gusts the drogue met, newest last: the receiver meets them gap / V later
        self._gust_history: list[FloatArray] = [np.zeros(3)] * GUST_HISTORY_TICKS
        self.swing = SwingGuidance(
            cfg, self.drogue_model, self.bow_model, self.smoothing_s, self.dt
        )
        self._armed = True  # a break-away now counts as an abort (see _abort)
        # run-time assurance: the monitor, the recovery law, the run's extremes and outcome
        self.monitor = EnvelopeMonitor(bounds=cfg.envelope or PLANT_ENVELOPE[cfg.plant])
        self.recovery = RecoveryLaw(m.model, cfg.recovery)
        self.rta_reason: str | None = None  # why the recovery law flies now (None: the LQR)
        self._rta_station_y_m: float | None = None  # its lateral station (tanker frame, m)
        self.rta_events: list[RtaEvent] = []
        self.extremes = EnvelopeExtremes()
        self.start_altitude_m = self._plant.flight_data().altitude_m
        self.classifier = RunClassifier()
        self.contact = ContactReport()
        self.separation_now: Separation | None = None
        self.t = 0.0
        self.k = 0
        self._camera_period = 1.0 / (cfg.camera_hz or cfg.tick_hz)
        self._next_frame_t = 0.0
        self.captured = False
        self.capture_time = math.nan
        self.miss = math.nan
        self.closure = math.nan
        self.aborts = 0
        self.max_sat = 0.0
        self._failed = False
        self._last_lock = False
        self._last_reason: str | None = "no frame yet"
        self._image_windows: tuple[list[Rect], list[Rect]] | None = None
        self._prev_tip = self.probe_tip()
        self._prev_drogue = self.drogue.position_m.copy()
        self._prev_normal = self.drogue.normal()

    def _build_controller(self, imp: Imperfections) -> None:
        """The observer (eq. 19), the LQR (eq. 20) from the design, and the servos with this
        run's imperfections (lag, rate)."""
        m = self.models
        self.obs = StateObserver.__new__(StateObserver)
        self.obs.ad, self.obs.bd, self.obs.c, self.obs.gain = m.ad, m.bd, m.c_meas, m.obs_gain
        self.obs.reset(self.x)
        self.lqr = IntegralLqr(
            kp=m.lqr_kp,
            ki=m.lqr_ki,
            c=m.c_tip,
            dt=self.dt,
            error_clip=m.error_clip,
            output_error_clip=0.3,
            ke=m.lqr_ke,
            design_lag_s=m.lqr_design_lag_s,
            ku=m.lqr_ku,
        )
        self.act = Actuators(
            m.model.u_trim,
            m.model.limits,
            self.dt,
            lag_s=imp.actuator_lag_s,
            rate_scale=imp.actuator_rate_scale,
        )

    def _settle_on_plant_trim(self, seconds: float = 10.0) -> None:
        """A perturbed aircraft does not fly level at the design trim: before the approach it
        holds its start point under the design controller in the steady wake, without gusts
        (true state fed back), until it sits at its own trim — integrators charged — as a
        receiver would on the pre-contact position. Then the observer starts from there."""
        x_ref = np.zeros(12)
        x_ref[9:12] = self.x[9:12]
        for _ in range(int(round(seconds / self.dt))):
            self.lqr.lag_step(self.act.apply(self.lqr.control(self.x, x_ref, x_ref[9:12])))
            air = wake_downwash(self.imp_draw, self.x[9:12])
            self.x = self._plant.step(self.act.effective_dev(), air)
        self.u_applied = self.act.position - self.act.trim
        self.obs.reset(self.x)

    # ------------------------------------------------------------------ geometry
    def _rot(self, x: FloatArray) -> FloatArray:
        return euler_to_matrix(x[6], self.x_trim[7] + x[7], x[8])

    def probe_tip(self, x: FloatArray | None = None) -> FloatArray:
        x = self.x if x is None else x
        return np.asarray(x[9:12] + self._rot(x) @ self.r_probe_b)

    def _camera_pose(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(R_TC, camera origin in the tanker frame, m)."""
        r_tb = self._rot(x)
        return r_tb @ self.R_bc, x[9:12] + r_tb @ self.r_cam_b

    # ------------------------------------------------------------------ sensing
    def _camera_measurement(
        self, x_hat: FloatArray, duplicate: bool = False
    ) -> tuple[FloatArray | None, FloatArray | None, DrogueFrame]:
        """Render + tracker (:mod:`app.sim.docking.vision`). Returns (z_T, R_T, the frame).

        ``duplicate``: the camera delivers its previous frame again (an imperfection): the same
        measurement, taken as new (converted with the current own-pose estimate)."""
        assert self._camera is not None
        if duplicate and self._last_cam is not None:
            shot = self._last_cam
        else:
            r_tc, cam_t = self._camera_pose(self.x)
            shot, self._image_windows = take_frame(
                self._camera,
                r_tc,
                cam_t,
                self.drogue.position_m,
                self.drogue.normal(),
                seed=int(self._frame_seed.integers(2**31)),
            )
            self._last_cam = shot
        if shot.measurement_m is None:
            return None, None, shot
        r_tc_hat, cam_hat = self._camera_pose(x_hat)
        nav_cov = shot.measurement_cov_m2 if self.config.nav_covariance else None
        calib = self._camera.nav_calibration
        z_t, r_t = drogue_in_tanker(shot.measurement_m, r_tc_hat, cam_hat, calib, nav_cov)
        return z_t, r_t, shot

    def _own_measurement(self) -> FloatArray:
        m = self.models
        y = m.c_meas @ self.x
        if self.config.ins_noise:
            y = y + self._rng_sensor.normal(0.0, 1.0, len(y)) * m.meas_sigma
        if self._ins is not None:
            y = y + self._ins.error()
        return np.asarray(y)

    # ------------------------------------------------------------------ step
    @property
    def done(self) -> bool:
        cfg = self.config
        if self.classifier.terminal and self.rta_reason is None:
            return True  # a terminal event, and the receiver back at the safe standoff
        if self.classifier.diverged or self.t >= cfg.max_time_s - 1e-9:
            return True
        return (
            self.captured
            and self.rta_reason is None
            and self.t >= self.capture_time + cfg.station_keep_s - 1e-9
        )

    def step(self) -> DockingTick:
        """One tick: sense → estimate → guide → control → propagate → contact (paper §6,
        Fig. 13), each phase a method handing a small record to the next."""
        if self.classifier.diverged:
            raise RuntimeError(f"the run has ended: {self.classifier.reason}")
        frame_pose = self._camera_pose(self.x)  # the pose this tick's frame is taken from
        # 1. observer on own-state sensors (eq. 19), predicting with the deflection the design
        # model believes acted (the servo position, or its modelled lag: lag-aware design)
        x_hat = self.obs.update(self.lqr.e_hat, self._own_measurement()).copy()
        sensed = self._sense(x_hat)
        aim = self._guide(x_hat, sensed.lock)
        ref = self._control(x_hat, aim)
        return self._propagate_and_check(frame_pose, sensed, aim.drogue_m, ref)

    def _sense(self, x_hat: FloatArray) -> Sensing:
        """Step 2: this tick's frame (if due) through the pipeline, and the drogue filter fed
        the measurements whose latency has passed."""
        cfg, dt = self.config, self.dt
        # 2. drogue measurement
        self.filter.predict(dt)
        z_t = r_t = None
        pose = left = right = leds = None
        self._image_windows = None
        frame_due = self.t + 1e-9 >= self._next_frame_t
        status: str | None = None
        if frame_due:
            self._next_frame_t += self._camera_period
            status = self._channel.next()
            if status == "drop":
                self._last_reason = "frame dropped"
            elif cfg.vision:
                z_t, r_t, shot = self._camera_measurement(x_hat, duplicate=status == "duplicate")
                pose, left, right, leds = shot.pose, shot.left, shot.right, shot.led_truth_cam_mm
                reason = None if pose is None else pose.reason
                self._last_reason = None if z_t is not None else (reason or "no lock")
            else:
                z_t = self.drogue.position_m.copy()
                if status == "duplicate" and self._last_cam is not None:
                    z_t = np.asarray(self._last_cam.measurement_m)
                self._last_cam = DrogueFrame(z_t.copy())
                r_t = np.eye(3) * 1e-6
                self._last_reason = None
            if z_t is not None and r_t is not None:
                # available latency later, stamped with this tick (the exposure)
                self._pending.append((self.k + self._latency_ticks, self.k, z_t, r_t))
        z_t = None
        exposure_t: float | None = None
        while self._pending and self._pending[0][0] <= self.k:
            _, k_exp, z_arr, r_arr = self._pending.pop(0)
            age = self.k - k_exp
            if cfg.latency_compensation:
                ok = self.filter.update_delayed(z_arr, r_arr, age)
            else:
                ok = self.filter.update(z_arr, r_arr)
            z_t, exposure_t = z_arr, k_exp * dt
            if not ok:
                self._last_reason = "gated"
        lock = self.filter.initialised and self.filter.coast_time_s <= cfg.coast_limit_s
        lock_reason = None if lock else (self._last_reason or "coast limit")
        return Sensing(
            frame_status=status,
            pose=pose,
            left=left,
            right=right,
            led_truth_cam_mm=leds,
            measurement_m=z_t,
            exposure_t_s=exposure_t,
            lock=lock,
            lock_reason=lock_reason,
        )

    def _guide(self, x_hat: FloatArray, lock: bool) -> Aim:
        """Step 3: the guidance's view of the drogue (bow wave split off, smoothed, led to the
        swing), the break-away checks, and the timed closure's commit."""
        cfg = self.config
        # 3. guidance + breakaway
        g = self.guidance
        tip_hat = x_hat[9:12] + self._rot(x_hat) @ self.r_probe_b
        tip_vel_hat = self.tip_tracker.update(tip_hat)
        d_hat = (
            self.filter.position
            if self.filter.initialised
            else np.asarray(self.drogue_model.rest_m, float)
        )
        d_vel = self.filter.velocity if self.filter.initialised else np.zeros(3)
        if not self._armed and float((d_hat - tip_hat)[0]) > REARM_GAP_M:
            self._armed = True
        bow_at = np.zeros(2)  # the bow wave's push on the drogue at the arrival (feed-forward)
        if self.bow_ff:
            r_hat = self._rot(x_hat)
            d_hat, d_vel, bow_at = self.swing.bow_split(
                x_hat[9:12] + r_hat @ self.r_nose_b,
                r_hat[:, 0],
                np.asarray(d_hat, float),
                np.asarray(d_vel, float),
                tip_hat,
                g.phase,
                self.filter.ever_initialised,
            )
        if g.phase in ("approach", "final") and self.rta_reason is None:
            rel = d_hat - tip_hat
            if self.swing_abort and self.swing.mean is not None:
                # where the drogue's swing about its mean will be at the plane
                at_plane = self.swing.swing_offset_at_arrival(
                    d_hat, d_vel, self.swing.mean, tip_hat, tip_vel_hat, float(rel[0]), bow_at
                )
                miss_pred, above = float(np.linalg.norm(at_plane)), float(at_plane[1])
            else:
                at_plane = offset_at_plane_m(rel, d_vel - tip_vel_hat)
                miss_pred, above = float(np.linalg.norm(at_plane)), float(at_plane[1])
            reason = should_abort(
                float(rel[0]),
                miss_pred,
                cfg.capture_radius_m,
                not lock,
                final_gap_m=g.cfg.final_gap_m,
                margin=self.abort_margin,
                closure_mps=float((tip_vel_hat - d_vel)[0]),
                max_closure_mps=cfg.max_closure_mps,
                overspeed_gap_m=cfg.overspeed_gap_m,
                above_at_plane_m=above,
                high_gap_m=cfg.high_gap_m,
                high_pass_m=cfg.high_pass_m,
            )
            if (
                reason is None
                and not lock
                and g.phase == "approach"
                and not cfg.hold_gap_on_lost_lock
            ):
                reason = "lock_lost"
            if not self.filter.ever_initialised:
                reason = None  # never acquired: hold the gap (guidance) instead of aborting
            if reason is not None:
                self.break_away(describe(reason, miss_pred, float((tip_vel_hat - d_vel)[0])))
        # never acquired (e.g. a calibration error too large for the ring fit at 13 m): close
        # on the drogue's a-priori rest position to the search gap, where the ring is larger
        # and its depth error ∝ Z² smaller, then hold there until it is acquired
        searching = not self.filter.ever_initialised and g.gap_cmd > SEARCH_GAP_M
        d_raw, d_vel_raw = np.asarray(d_hat, float), np.asarray(d_vel, float)
        if self.smoothing_s > 0:
            d_hat, d_vel = self.swing.smoothed_reference(
                np.asarray(d_hat, float), np.asarray(d_vel, float), lock
            )
        mean_ref = np.asarray(d_hat, float).copy()  # the reference without the bow wave's push
        if (
            self.swing_lead > 0
            and self.swing.mean is not None
            and g.phase in ("approach", "final")
            and float((d_raw - tip_hat)[0]) < cfg.swing_lead_gap_m
        ):
            # lead the probe to where the swing will have the drogue at the arrival
            lead = self.swing.swing_lead(d_raw, d_vel_raw, self.swing.mean, tip_hat)
            d_hat = np.asarray(d_hat, float).copy()
            d_hat[1:] += self.swing_lead * lead
        if self.bow_ff:
            d_hat = np.asarray(d_hat, float).copy()
            d_hat[1:] += bow_at
        commit = True
        if self.timed and g.holding and self.swing.mean is not None:
            commit = self.swing.commit_now(d_raw, d_vel_raw, tip_hat, mean_ref, np.asarray(d_hat))
        return Aim(
            tip_m=tip_hat,
            tip_vel_mps=tip_vel_hat,
            drogue_raw_m=np.asarray(d_raw, float),
            drogue_m=np.asarray(d_hat, float),
            drogue_vel_mps=np.asarray(d_vel, float),
            closing=bool(lock or searching),
            commit=commit,
        )

    def _control(self, x_hat: FloatArray, aim: Aim) -> FloatArray:
        """Step 4: the LQR on the reference (eq. 20) or, while the run-time assurance has
        control, the recovery law; returns the probe tip's reference (m)."""
        m, dt, g = self.models, self.dt, self.guidance
        tip_hat, tip_vel_hat = aim.tip_m, aim.tip_vel_mps
        if self.rta_reason is not None:
            # 4'. run-time assurance: the recovery law flies (wings level, power back, drop
            # aft and below); the LQR's memory follows the servos (bumpless hand-back)
            d_est = aim.drogue_raw_m
            aft, below = float(d_est[0] - tip_hat[0]), float(tip_hat[2] - d_est[2])
            speed, side, sink = (float(v) for v in tip_vel_hat)
            if self._rta_station_y_m is None:  # the lateral station the take-over holds
                self._rta_station_y_m = float(tip_hat[1])
            side_offset = float(tip_hat[1]) - self._rta_station_y_m
            self.u_applied = self.act.apply(
                self.recovery.command(x_hat, speed, sink, aft, below, side, side_offset)
            )
            self._plant.set_speedbrake(self.recovery.speedbrake(speed, aft))
            self.lqr.hand_over(self.u_applied)
            ref, ref_vel = tip_hat.copy(), np.zeros(3)
            fd = self._plant.flight_data()
            if self.recovery.settled(
                x_hat,
                speed,
                sink,
                aft,
                below,
                fd.alpha_deg - self.trim.alpha_deg,
                fd.load_factor_g,
                side,
            ):
                self._end_rta(tip_hat, d_est)
        else:
            ref, ref_vel = g.update(dt, aim.drogue_m, aim.drogue_vel_mps, aim.closing, aim.commit)
            # 4. control (eq. 20)
            x_ref = np.zeros(12)
            x_ref[9:12] = ref - m.tip0_b
            # flight-path feed-forward: ẏ ≈ V ψ + v, ż ≈ −V θ + w at trim
            if self.closure_ff:  # the closure's steady state and commands (closure_feedforward)
                x_ref += self._closure_ff[0] * ref_vel[0]
            else:
                x_ref[0] = ref_vel[0]
            x_ref[8] = ref_vel[1] / self.airspeed
            x_ref[7] += -ref_vel[2] / self.airspeed
            u_ff = self._closure_ff[1] * ref_vel[0] if self.closure_ff else None
            u_cmd = self.lqr.control(x_hat, x_ref, ref - m.tip0_b, u_ff)
            self.u_applied = self.act.apply(u_cmd)  # servo positions (what the observer is told)
            self.lqr.lag_step(self.u_applied)
        return ref

    def _propagate_and_check(
        self,
        frame_pose: tuple[FloatArray, FloatArray],
        sensed: Sensing,
        d_hat: FloatArray,
        ref: FloatArray,
    ) -> DockingTick:
        """Steps 5–7 of the tick: propagate, the contact check, the run-time assurance's
        monitor; then the tick's record."""
        dt, g = self.dt, self.guidance
        self.max_sat = max(self.max_sat, self.act.saturation())
        # 5. propagate plant (the design model, or the perturbed aircraft), gusts, drogue
        # one frozen gust field: the drogue meets it now, the receiver's CG gap / V later
        gust = self.turb.step()
        self._gust_history.append(gust)
        self._gust_history.pop(0)
        gap_m = float(self.drogue.position_m[0] - self.x[9])
        delay = int(round(max(gap_m, 1.0) / self.airspeed / dt))
        gust_rec = self._gust_history[-1 - min(max(delay, 1), GUST_HISTORY_TICKS - 1)]
        if self._imperfect:  # wake, lagged actuators, the perturbed plant
            air = gust_rec + wake_downwash(self.imp_draw, self.x[9:12])
            self.x = self._plant.step(self.act.effective_dev(), air)
        else:
            self.x = self._plant.step(self.u_applied, gust_rec)
        self.t += dt
        self.k += 1
        tip = self.probe_tip()
        if self.captured:
            # probe and drogue are latched: the drogue rides on the probe tip (the reduced
            # model: welded; the multi-body hose: on the coupling, the hose through the reel)
            self.drogue.ride(dt, tip, gust)
        else:
            r_tb = self._rot(self.x)
            nose = self.x[9:12] + r_tb @ self.r_nose_b
            f_bow = self.drogue.bow_wave_force(nose, r_tb[:, 0])
            self.drogue.step(dt, gust, f_bow)
        # 6. capture check at the plane crossing
        captured_now = False
        miss_now: float | None = None
        d_pos, n = self.drogue.position_m.copy(), self.drogue.normal()
        self._monitor(tip, d_pos)
        if self.classifier.diverged:
            tip, d_pos = self._prev_tip, self._prev_drogue  # the last finite values
        elif not self.captured:
            prev = (self._prev_tip, self._prev_drogue, self._prev_normal)
            crossing = plane_crossing(prev, (tip, d_pos, n), dt)
            if crossing is not None:
                attempt = self.rta_reason is None  # (not while breaking away)
                captured_now = self._judge_crossing(tip, crossing)
                miss_now = crossing.miss_m if attempt else None
        self._prev_tip, self._prev_drogue, self._prev_normal = tip, d_pos, n
        phase = "contact" if captured_now else ("breakaway" if self.rta_reason else g.phase)
        state_abs = self.x.copy()
        state_abs[:9] += self.x_trim[:9]
        return DockingTick(
            t_s=self.t,
            phase=phase,
            drogue_truth_m=d_pos,
            drogue_normal=n,
            drogue_measured_m=(
                None if sensed.measurement_m is None else np.asarray(sensed.measurement_m)
            ),
            drogue_estimate_m=np.asarray(d_hat),
            probe_tip_m=tip,
            uav_state=state_abs,
            reference_m=np.asarray(ref),
            control=self.u_applied.copy(),
            lock=bool(sensed.lock),
            lock_reason=sensed.lock_reason,
            pose=sensed.pose,
            left_image=sensed.left,
            right_image=sensed.right,
            led_truth_cam_mm=sensed.led_truth_cam_mm,
            captured=self.captured,
            miss_m=miss_now,
            rel_position_m=d_pos - tip,
            image_windows_px=self._image_windows,
            frame_status=sensed.frame_status,
            measurement_exposure_t_s=sensed.exposure_t_s,
            camera_pose_T=frame_pose,
            rta_reason=self.rta_reason,
            run_outcome=self.outcome().outcome if self.done else None,
            hose=hose_state(self.drogue),
        )

    def _judge_crossing(self, tip: FloatArray, c: PlaneCrossing) -> bool:
        """Step 6: a crossing of the drogue's plane judged as the field does
        (:class:`~app.sim.docking.outcomes.ContactReport`); True on a capture. While breaking
        away the coupling is not flown — no capture and no new break-away — but the probe head
        across the rim is a rim strike all the same."""
        cfg = self.config
        rim, head = cfg.capture_radius_m, cfg.probe_head_radius_m
        if self.rta_reason is not None:
            reason = self.contact.strike_while_breaking_away(c.miss_m, rim, head)
            if reason is not None:
                self.miss, self.closure = c.miss_m, c.closure_mps
                self.classifier.mark("rim_strike", reason)
            return False
        self.miss, self.closure = c.miss_m, c.closure_mps
        window = (cfg.min_closure_mps, cfg.max_closure_mps)
        kind = self.contact.crossing(c.miss_m, c.closure_mps, c.lateral_mps, rim, head, window)
        if kind == "captured":
            self.captured = True
            self.capture_time = self.t
            self.drogue.latch(tip, c.closure_mps)
            self.guidance.mark_contact(tip)
            return True
        if kind == "rim_strike":
            self.classifier.mark("rim_strike", self.contact.last_reason)
        else:
            self.classifier.last_miss = self.contact.last_reason
        self.break_away(self.contact.last_reason)
        return False

    def break_away(self, reason: str = "break-away") -> None:
        """Break away as the field flies it: the recovery law (power back, wings level, drop
        aft and below, stop chasing the drogue) to the safe standoff, then the rejoin. One
        abort per break-away; after ``max_aborts`` the run is over once at the standoff."""
        if self.rta_reason is None:
            self._start_rta(f"break-away: {reason}")
        if not self._armed:
            return
        self._armed = False
        self.aborts += 1
        if self.aborts > self.config.max_aborts:
            self._failed = True
            self.classifier.mark_aborts_used(self.aborts)

    def _start_rta(self, reason: str) -> None:
        self.rta_reason = reason
        self._rta_station_y_m = None  # set from the first estimate the recovery law flies on
        self.recovery.reset(self.dt)
        self.rta_events.append(RtaEvent(self.t, "recovery", reason))

    def _end_rta(self, tip_m: FloatArray, drogue_m: FloatArray) -> None:
        """At the safe standoff: hand back to the LQR and rejoin (or end the run)."""
        reason = self.rta_reason or ""
        self.rta_reason = None
        self._plant.set_speedbrake(0.0)
        self.rta_events.append(RtaEvent(self.t, "hand_back", reason))
        self._armed = True
        self.lqr.hand_over(self.u_applied)
        gap = float(drogue_m[0] - tip_m[0])
        below = float(tip_m[2] - drogue_m[2])
        self.guidance.start_rejoin(gap, below, float(tip_m[1] - drogue_m[1]))

    def _monitor(self, tip: FloatArray, d_pos: FloatArray) -> None:
        """Step 7: the run-time assurance's monitor on the flown state (the plant's own
        values), the separation from the tanker and the hose, and a non-finite state."""
        if not (np.all(np.isfinite(self.x)) and np.all(np.isfinite(tip))):
            self.classifier.mark_diverged("the aircraft's state is not finite (diverged)")
            return
        fd = self._plant.flight_data()
        r_tb = self._rot(self.x)
        nose = self.x[9:12] + r_tb @ self.r_nose_b
        sep = separation(
            nose, tip, d_pos, self.drogue.hose_nodes_m(), self.monitor.separation_bounds
        )
        self.separation_now = sep
        self.extremes.add(fd, self.start_altitude_m, sep)
        why = self.monitor.envelope_violation(fd, self.start_altitude_m)
        if why is not None:
            if not fd.finite():
                self.classifier.mark_diverged(why)
                return
            self.classifier.mark("departure", why)
            if self.rta_reason is None or self.rta_reason.startswith("break-away"):
                self.rta_reason = None
                self._start_rta(f"envelope: {why}")
            return
        keep_out = self.monitor.keep_out_violation(sep)
        if keep_out is not None:
            self.classifier.mark("keep_out", keep_out)
        if self.rta_reason is None and not self.captured:
            clearance = self.monitor.break_away_reason(sep)
            if clearance is not None:
                self.break_away(clearance)

    def outcome(self) -> DockingOutcome:
        cls, reason = self.classifier.classify(
            self.captured, self.t >= self.config.max_time_s - 1e-9
        )
        hose = contact_report(self.drogue)
        return DockingOutcome(
            outcome=cls,
            reason=reason,
            envelope=self.extremes,
            lateral_speed_mps=self.contact.capture_lateral_mps,
            hose_whip_risk=self.contact.whip_risk,
            recoveries=sum(1 for e in self.rta_events if e.kind == "recovery"),
            captured=self.captured,
            miss_distance_m=self.miss,
            closure_speed_mps=self.closure,
            time_to_capture_s=self.capture_time,
            aborts=self.aborts,
            max_control_saturation=self.max_sat,
            peak_hose_tension_n=math.nan if hose is None else hose.peak_tension_n,
            hose_whip=hose is not None and hose.whip,
            hose_released=hose is not None and hose.released,
        )

    def run(self, max_ticks: int | None = None) -> DockingOutcome:
        """Step until done (or ``max_ticks``); return the outcome."""
        n = 0
        while not self.done and (max_ticks is None or n < max_ticks):
            self.step()
            n += 1
        return self.outcome()
