"""Stereo rig calibration model and its JSON file (paper §2–3, eqs. 2–5, Tables 1–2).

Conventions
-----------
* The left camera frame is the world frame (paper §2). Units are millimetres.
* Rig extrinsics: ``X_right = R · X_left + T`` (T in mm).
* Intrinsics ``K = [[fx, γ, u0], [0, fy, v0], [0, 0, 1]]`` in px (eq. 2); distortion in
  OpenCV order ``[k1, k2, p1, p2, k3]`` (the paper estimates k1, k2 only, eq. 7).

File format (read by every tool and test)::

    {"image_size": [w, h],
     "left":  {"K": [[..],[..],[..]], "dist": [k1, k2, p1, p2, k3]},
     "right": {"K": ..., "dist": ...},
     "R": [[..],[..],[..]], "T": [tx, ty, tz], "units": "mm"}
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from app.types import FloatArray

ORTHONORMAL_TOL = 1e-3


class CalibrationError(ValueError):
    """A calibration is malformed; ``field`` names the offending entry (e.g. ``left.K``)."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"calibration field '{field}': {problem}")
        self.field = field
        self.problem = problem


def _as_array(value: Any, shape: tuple[int, ...], field: str) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(field, f"not numeric ({exc})") from None
    if arr.shape != shape:
        raise CalibrationError(field, f"expected shape {list(shape)}, got {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(field, "contains NaN or infinite values")
    return arr


@dataclass(frozen=True)
class CameraIntrinsics:
    """One camera: ``K`` (3×3, px) with skew, and distortion ``[k1, k2, p1, p2, k3]``."""

    K: FloatArray
    dist: FloatArray

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def skew(self) -> float:
        """γ of eq. 2 (px)."""
        return float(self.K[0, 1])

    @property
    def u0(self) -> float:
        return float(self.K[0, 2])

    @property
    def v0(self) -> float:
        return float(self.K[1, 2])

    @cached_property
    def K_inv(self) -> FloatArray:
        """K⁻¹ (read-only, computed once)."""
        inv = np.asarray(np.linalg.inv(self.K), dtype=np.float64)
        inv.setflags(write=False)
        return inv

    @classmethod
    def from_dict(cls, data: Any, name: str) -> CameraIntrinsics:
        if not isinstance(data, dict):
            raise CalibrationError(name, "must be an object with 'K' and 'dist'")
        if "K" not in data:
            raise CalibrationError(f"{name}.K", "missing")
        K = _as_array(data["K"], (3, 3), f"{name}.K")
        dist_raw = data.get("dist", [0.0] * 5)
        try:
            dist_list = list(np.asarray(dist_raw, dtype=np.float64).ravel())
        except (TypeError, ValueError):
            raise CalibrationError(f"{name}.dist", "not numeric") from None
        if not 2 <= len(dist_list) <= 5:
            raise CalibrationError(f"{name}.dist", f"expected 2 to 5 terms, got {len(dist_list)}")
        dist = _as_array(dist_list + [0.0] * (5 - len(dist_list)), (5,), f"{name}.dist")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CalibrationError(f"{name}.K", "focal lengths fx, fy must be positive")
        if (
            abs(K[1, 0]) > 1e-9
            or abs(K[2, 0]) > 1e-9
            or abs(K[2, 1]) > 1e-9
            or abs(K[2, 2] - 1) > 1e-9
        ):
            raise CalibrationError(f"{name}.K", "must be upper triangular with K[2][2] = 1")
        return cls(K=K, dist=dist)

    def to_dict(self) -> dict[str, Any]:
        return {"K": self.K.tolist(), "dist": self.dist.tolist()}


def _frozen(a: FloatArray) -> FloatArray:
    """A read-only array (a cached matrix of the calibration is shared by every caller)."""
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class StereoCalibration:
    """A calibrated convergent stereo rig (paper §2). Left camera frame = world frame (mm)."""

    image_size: tuple[int, int]  # (width, height) px
    left: CameraIntrinsics
    right: CameraIntrinsics
    R: FloatArray  # 3×3, X_right = R · X_left + T
    T: FloatArray  # (3,), mm

    # ---- construction / validation -------------------------------------------------
    @classmethod
    def from_dict(cls, data: Any) -> StereoCalibration:
        if not isinstance(data, dict):
            raise CalibrationError("<root>", "must be a JSON object")
        for key in ("image_size", "left", "right", "R", "T"):
            if key not in data:
                raise CalibrationError(key, "missing")
        units = data.get("units", "mm")
        if units != "mm":
            raise CalibrationError("units", f"must be 'mm', got {units!r}")
        size = _as_array(data["image_size"], (2,), "image_size")
        if np.any(size < 1) or np.any(size != np.round(size)):
            raise CalibrationError("image_size", "must be two positive integers [w, h]")
        left = CameraIntrinsics.from_dict(data["left"], "left")
        right = CameraIntrinsics.from_dict(data["right"], "right")
        R = _as_array(data["R"], (3, 3), "R")
        err = float(np.max(np.abs(R @ R.T - np.eye(3))))
        if err > ORTHONORMAL_TOL:
            raise CalibrationError("R", f"not orthonormal (max |R·Rᵀ − I| = {err:.2e})")
        if np.linalg.det(R) < 0:
            raise CalibrationError("R", "determinant is −1 (a reflection, not a rotation)")
        u, _, vt = np.linalg.svd(R)
        R = u @ vt  # re-orthonormalise
        T = _as_array(data["T"], (3,), "T")
        if float(np.linalg.norm(T)) < 1e-6:
            raise CalibrationError("T", "baseline is zero")
        return cls(image_size=(int(size[0]), int(size[1])), left=left, right=right, R=R, T=T)

    @classmethod
    def load(cls, path: str | Path) -> StereoCalibration:
        try:
            data = json.loads(Path(path).read_text())
        except FileNotFoundError:
            raise CalibrationError("<file>", f"{path} not found") from None
        except json.JSONDecodeError as exc:
            raise CalibrationError("<file>", f"{path} is not valid JSON ({exc})") from None
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        return {
            "image_size": [int(self.image_size[0]), int(self.image_size[1])],
            "left": self.left.to_dict(),
            "right": self.right.to_dict(),
            "R": self.R.tolist(),
            "T": self.T.tolist(),
            "units": "mm",
        }

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    # ---- derived quantities ----------------------------------------------------------
    @property
    def baseline_mm(self) -> float:
        return float(np.linalg.norm(self.T))

    @property
    def convergence_deg(self) -> float:
        """Angle between the two optical axes (deg)."""
        z_right_in_left = self.R.T @ np.array([0.0, 0.0, 1.0])
        return float(np.degrees(np.arccos(np.clip(z_right_in_left[2], -1.0, 1.0))))

    @property
    def right_center_mm(self) -> FloatArray:
        """Right camera optical centre in the left (world) frame, mm."""
        return -self.R.T @ self.T

    @cached_property
    def P_left(self) -> FloatArray:
        """H_l = A_l · M_l of eq. 4 (3×4), for undistorted pixel coordinates."""
        return _frozen(self.left.K @ np.hstack([np.eye(3), np.zeros((3, 1))]))

    @cached_property
    def P_right(self) -> FloatArray:
        """H_r = A_r · M_r of eq. 5 (3×4), for undistorted pixel coordinates."""
        return _frozen(self.right.K @ np.hstack([self.R, self.T.reshape(3, 1)]))

    @cached_property
    def kernel_arrays(
        self,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """(K, distortion, P) of the left then the right camera as C-contiguous float64 arrays,
        as the compiled loops take them (prepared once)."""
        return (
            np.ascontiguousarray(self.left.K, dtype=np.float64),
            np.ascontiguousarray(self.left.dist, dtype=np.float64),
            np.ascontiguousarray(self.P_left, dtype=np.float64),
            np.ascontiguousarray(self.right.K, dtype=np.float64),
            np.ascontiguousarray(self.right.dist, dtype=np.float64),
            np.ascontiguousarray(self.P_right, dtype=np.float64),
        )

    @cached_property
    def fundamental(self) -> FloatArray:
        """F with x_rᵀ F x_l = 0 for undistorted pixel coordinates."""
        t = self.T
        tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
        E = tx @ self.R
        F = np.linalg.inv(self.right.K).T @ E @ np.linalg.inv(self.left.K)
        return _frozen(np.asarray(F / np.linalg.norm(F), dtype=np.float64))


def paper_calibration() -> StereoCalibration:
    """The paper's rig: Tables 1–2 at 1280×1024, T fitted from Tables 5–6 (see README)."""
    left_K = np.array([[2394.3558, -4.5025, 692.7227], [0, 2393.9677, 590.8281], [0, 0, 1]])
    right_K = np.array([[2325.5075, -0.4948, 628.8684], [0, 2325.2000, 555.3041], [0, 0, 1]])
    R = np.array(
        [[0.9986, 0.0006, 0.0525], [-0.0006, 1.0000, -0.0002], [-0.0525, 0.0002, 0.9986]]
    )  # Table 2 as printed (the transpose mark ignored: only this reading fits Tables 5–6)
    return StereoCalibration.from_dict(
        {
            "image_size": [1280, 1024],
            "left": {"K": left_K.tolist(), "dist": [0.0708, -0.1293, 0.0, 0.0, 0.0]},
            "right": {"K": right_K.tolist(), "dist": [0.0661, 0.0147, 0.0, 0.0, 0.0]},
            "R": R.tolist(),
            "T": [-111.4, 0.0, -28.3],
            "units": "mm",
        }
    )
