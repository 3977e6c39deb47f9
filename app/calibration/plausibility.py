"""Physical plausibility of a calibration before it is used: ``PUT /calibration`` and the
calibration stored in an MCAP log (:func:`app.streams.mcap_source.mcap_calibration`) pass the
same checks and fail with the same message.

``StereoCalibration.from_dict`` checks the *form* (shapes, finite numbers, a rotation, a
non-zero baseline). A calibration can be well-formed and still break the service: fx = 1e-320
makes every simulated step fail, |T| = 1e300 or k1 = 1e200 overflow the projection, and an
8000 × 6000 image makes each tick render 48 Mpx. The bounds below are generous for any real
camera of this project (the paper's rig: fx ≈ 2400 px, |T| ≈ 115 mm, |k| < 0.2):

* image size: each side in [16, 16384] px and width × height ≤ ``AAR_MAX_CALIBRATION_PIXELS``
  (:data:`DEFAULT_MAX_PIXELS`);
* fx, fy in [50, 1e5] px (a 1 px sensor at 1e5 px focal length is a 0.0006° field of view);
* principal point inside the image; |skew γ| < 0.1 · fx;
* |T| in [1, 10000] mm;
* every distortion term |k1|, |k2|, |p1|, |p2|, |k3| ≤ 10, and the radial model monotonic
  within the image (otherwise it folds: two rays land on one pixel and undistortion has no
  unique answer).

Each failure is a :class:`CalibrationError` naming the field (the service answers 422
``{"detail", "field"}``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.geometry.calibration import CalibrationError, CameraIntrinsics, StereoCalibration

TOP_LEVEL_KEYS = frozenset({"image_size", "left", "right", "R", "T", "units"})
CAMERA_KEYS = frozenset({"K", "dist"})
SIDE_RANGE = (16, 16384)
FOCAL_RANGE = (50.0, 1e5)
SKEW_FRACTION = 0.1
BASELINE_RANGE_MM = (1.0, 10000.0)
DIST_MAX = 10.0
DEFAULT_MAX_PIXELS = 4096 * 4096  # AAR_MAX_CALIBRATION_PIXELS


def check_keys(data: Any) -> None:
    """Unknown fields are refused (a typo such as ``"unit"`` must not be ignored)."""
    if not isinstance(data, dict):
        return  # from_dict reports it
    for key in data:
        if key not in TOP_LEVEL_KEYS:
            raise CalibrationError(str(key)[:64], "unknown field")
    for side in ("left", "right"):
        cam = data.get(side)
        if isinstance(cam, dict):
            for key in cam:
                if key not in CAMERA_KEYS:
                    raise CalibrationError(f"{side}.{str(key)[:64]}", "unknown field")


def _check_camera(cam: CameraIntrinsics, side: str, width: int, height: int) -> None:
    lo, hi = FOCAL_RANGE
    for name, f in (("fx", cam.fx), ("fy", cam.fy)):
        if not lo <= f <= hi:
            raise CalibrationError(
                f"{side}.K", f"{name} = {f:.6g} px is outside [{lo:g}, {hi:g}] px"
            )
    if not (0.0 <= cam.u0 <= width and 0.0 <= cam.v0 <= height):
        raise CalibrationError(
            f"{side}.K",
            f"principal point ({cam.u0:.6g}, {cam.v0:.6g}) px is outside the "
            f"{width}x{height} image",
        )
    if abs(cam.skew) >= SKEW_FRACTION * cam.fx:
        raise CalibrationError(
            f"{side}.K", f"|skew| = {abs(cam.skew):.6g} px is not below {SKEW_FRACTION:g}·fx"
        )
    worst = float(np.max(np.abs(cam.dist)))
    if worst > DIST_MAX:
        raise CalibrationError(
            f"{side}.dist", f"a distortion term is {worst:.6g}, beyond ±{DIST_MAX:g}"
        )
    # radial model r_d = r (1 + k1 r² + k2 r⁴ + k3 r⁶) must increase up to the image corners
    k1, k2, _, _, k3 = (float(x) for x in cam.dist)
    corners = np.array([[0, 0], [width, 0], [0, height], [width, height]], dtype=np.float64)
    xn = (corners[:, 0] - cam.u0 - cam.skew * (corners[:, 1] - cam.v0) / cam.fy) / cam.fx
    yn = (corners[:, 1] - cam.v0) / cam.fy
    r_max = float(np.max(np.hypot(xn, yn)))
    r2 = np.linspace(0.0, r_max, 256) ** 2
    slope = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 + 7 * k3 * r2**3
    if np.any(slope <= 0):
        r_fold = float(np.sqrt(r2[int(np.argmax(slope <= 0))]))
        raise CalibrationError(
            f"{side}.dist",
            f"radial distortion folds over inside the image (at normalised radius "
            f"{r_fold:.3g} of {r_max:.3g})",
        )


def check_plausible(calib: StereoCalibration, max_pixels: int) -> None:
    """Raise :class:`CalibrationError` (naming the field) for an implausible calibration."""
    width, height = calib.image_size
    lo, hi = SIDE_RANGE
    if not (lo <= width <= hi and lo <= height <= hi):
        raise CalibrationError("image_size", f"each side must be in [{lo}, {hi}] px")
    if width * height > max_pixels:
        raise CalibrationError(
            "image_size",
            f"{width}x{height} = {width * height / 1e6:.3g} Mpx exceeds "
            f"{max_pixels / 1e6:.3g} Mpx (AAR_MAX_CALIBRATION_PIXELS)",
        )
    _check_camera(calib.left, "left", width, height)
    _check_camera(calib.right, "right", width, height)
    with np.errstate(over="ignore"):
        baseline = calib.baseline_mm  # inf for |T| = 1e300
    blo, bhi = BASELINE_RANGE_MM
    if not blo <= baseline <= bhi:
        raise CalibrationError("T", f"|T| = {baseline:.6g} mm is outside [{blo:g}, {bhi:g}] mm")


def validated(data: Any, max_pixels: int) -> StereoCalibration:
    """Form (``from_dict``), unknown fields and plausibility, in that order."""
    check_keys(data)
    with np.errstate(over="ignore", invalid="ignore"):  # |T| = 1e300: refused below
        calib = StereoCalibration.from_dict(data)
    check_plausible(calib, max_pixels)
    return calib
