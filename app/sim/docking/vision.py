"""Vision in the loop of a docking run (paper §3–5 inside the closed loop of §6): the stereo
camera built from the scenario (:func:`camera_sensor`), the frame it takes of the drogue at its
true pose (:func:`take_frame`: the LED ring rendered by :func:`app.sim.stereo_render.render_pair`
and tracked by the navigation) and that measurement in the tanker frame with its covariance
(:func:`drogue_in_tanker`).

Units: the camera frame of the navigation is in millimetres (:class:`PoseResult`); everything
here converts to metres at its edge (m ↔ mm happens only in this module).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import StereoCalibration
from app.model.pose import PoseResult
from app.sim.camera_sensor import StereoCameraSensor
from app.sim.docking.config import DockingConfig
from app.sim.imperfections import resolve
from app.sim.led_ring import LedRing
from app.sim.stereo_render import RenderSettings
from app.types import FloatArray, Rect
from app.vision.error_bound import ErrorBoundConfig
from app.vision.pipeline import PipelineConfig

DISPARITY_PER_EXTRA_PX = 0.02  # ring-fit tolerance (disparity σ) per px of calibration doubt
DISPARITY_SIGMA_PX = 0.15  # effective disparity noise of the ring-centre fit (conservative)


def camera_sensor(
    config: DockingConfig, calibration: StereoCalibration, render_mode: str
) -> StereoCameraSensor:
    """The run's stereo camera: the renderer's settings and LED ring from ``config``, and a
    navigation that knows how uncertain its calibration is — the epipolar gate and the
    reprojection bound widen by 1.5 × (f·rotation error + 2 × principal-point error) of the
    configured imperfections."""
    cfg = config
    imp = resolve(cfg.imperfections)
    f_px = float(calibration.left.fx)
    extra_px = 1.5 * (f_px * math.radians(imp.calib_rot_deg) + 2.0 * imp.calib_pp_px)
    return StereoCameraSensor(
        calibration,
        RenderSettings(
            noise_sigma=cfg.noise_sigma,
            clutter=cfg.clutter,
            occluded=tuple(int(i) for i in cfg.led_dropout),
            fast_noise=True,
            supersample=4,
        ),
        LedRing(
            radius_mm=cfg.ring_radius_m * 1000.0,
            count=cfg.led_count,
            led_diameter_mm=cfg.led_diameter_mm,
        ),
        PipelineConfig(
            ring_radius_mm=cfg.ring_radius_m * 1000.0,
            led_count=cfg.led_count,
            led_diameter_mm=cfg.led_diameter_mm,
            matcher=cfg.matcher,  # type: ignore[arg-type]
            epipolar_tol_px=2.0 + extra_px,
            max_reprojection_px=1.5 + 0.5 * extra_px,
            disparity_sigma_px=0.05 + DISPARITY_PER_EXTRA_PX * extra_px,
            # the error bound knows the calibration's doubt too (1σ: a third of the gate's)
            error_bound=ErrorBoundConfig(calibration_px=extra_px / 3.0),
        ),
        mode=render_mode,
    )


@dataclass(frozen=True)
class DrogueFrame:
    """The last frame the camera delivered: the drogue centre it measured in the camera frame
    (m; None without a lock), the navigation's pose, the images and the LEDs' truth (camera
    frame, mm). Without vision (the truth as the measurement) only ``measurement_m``."""

    measurement_m: FloatArray | None
    pose: PoseResult | None = None
    left: NDArray[np.uint8] | None = None
    right: NDArray[np.uint8] | None = None
    led_truth_cam_mm: FloatArray | None = None
    # the navigation's covariance of ``measurement_m`` (camera frame, m²), when it gave one
    measurement_cov_m2: FloatArray | None = None


def take_frame(
    sensor: StereoCameraSensor,
    r_tc: FloatArray,
    camera_m: FloatArray,
    drogue_m: FloatArray,
    drogue_normal: FloatArray,
    seed: int,
) -> tuple[DrogueFrame, tuple[list[Rect], list[Rect]] | None]:
    """Render the drogue at its true pose (tanker frame, m) into the camera at ``r_tc``,
    ``camera_m`` (R_TC, origin in the tanker frame, m) and track it; the frame and the
    rectangles rendered (None for a full render)."""
    c_cam_m = r_tc.T @ (drogue_m - camera_m)
    n_cam = r_tc.T @ drogue_normal
    frame = sensor.capture(c_cam_m * 1000.0, n_cam, seed=seed)
    pose = frame.pose
    meas = cov = None
    if pose.lock and pose.drogue is not None:
        meas = np.asarray(pose.drogue.center_mm, float) / 1000.0
        if pose.drogue.center_cov_mm2 is not None:
            cov = np.asarray(pose.drogue.center_cov_mm2, float) / 1e6
    leds = np.asarray(frame.led_truth_cam_mm, float)
    shot = DrogueFrame(
        meas,
        pose=pose,
        left=frame.left,
        right=frame.right,
        led_truth_cam_mm=leds,
        measurement_cov_m2=cov,
    )
    return shot, frame.windows


def drogue_in_tanker(
    measurement_m: FloatArray,
    r_tc_hat: FloatArray,
    camera_hat_m: FloatArray,
    nav_calibration: StereoCalibration,
    nav_cov_m2: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The drogue centre measured in the camera frame (m) in the tanker frame, converted with
    the *estimated* camera pose (R_TC, origin m), and its covariance (m²), plus 1 cm for the
    own-pose error: the navigation's own ``nav_cov_m2`` (camera frame) where given — it knows
    the calibration's doubt, a disparity bias whose depth error grows as Z² (harsh: a fix of a
    drogue 21.7 m away read 56.7 m, centre σ 36 m) —, never below a model of the stereo fit's
    noise (lateral, and depth ∝ Z² / (f·B))."""
    z_t = camera_hat_m + r_tc_hat @ measurement_m
    depth = max(float(measurement_m[2]), 0.5)
    f_px = float(nav_calibration.left.fx)
    base_m = float(nav_calibration.baseline_mm) / 1000.0
    sig_d = DISPARITY_SIGMA_PX
    sig_lat = 0.003 + depth * 0.1 / f_px
    sig_z = 0.005 + depth**2 * sig_d / (f_px * base_m)
    r_cam = np.diag([sig_lat**2, sig_lat**2, sig_z**2])
    if nav_cov_m2 is not None:
        r_cam = r_cam + np.asarray(nav_cov_m2, float)
    r_t = r_tc_hat @ r_cam @ r_tc_hat.T + np.eye(3) * 0.01**2
    return np.asarray(z_t), np.asarray(r_t)
