"""Rotations and the frame conventions of the simulation, the controller and the outputs (m, rad).

Tanker frame ``T`` (the simulation's inertial frame): origin at the hose exit on the tanker, moving
with the tanker in steady straight-and-level flight; x forward (direction of flight), y right,
z down (NED-like). The air flows past it at ``-V`` along x.

Body frame ``B`` of the receiver: x forward (nose), y right wing, z down; Euler angles φ, θ, ψ
(roll, pitch, yaw; 3-2-1 sequence) give ``R_TB`` with ``p_T = R_TB · p_B``.

Camera frame ``C`` (the navigation pipeline's left camera): x right, y down, z forward; the pipeline
works in millimetres, everything here in metres: convert once at the boundary.
"""

from __future__ import annotations

import numpy as np

from app.types import FloatArray


def euler_to_matrix(phi: float, theta: float, psi: float) -> FloatArray:
    """``R_TB`` (body → tanker) for 3-2-1 Euler angles (rad)."""
    cf, sf = np.cos(phi), np.sin(phi)
    ct, st = np.cos(theta), np.sin(theta)
    cp, sp = np.cos(psi), np.sin(psi)
    return np.array(
        [
            [ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
            [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
            [-st, sf * ct, cf * ct],
        ]
    )


def look_at_camera(cam_pos_b: FloatArray, target_b: FloatArray) -> FloatArray:
    """``R_BC`` (camera → body) for a camera at ``cam_pos_b`` whose optical axis (+z_C) points at
    ``target_b``, with image x (right) kept in the body x–y plane (no camera roll)."""
    z_c = np.asarray(target_b, float) - np.asarray(cam_pos_b, float)
    z_c = z_c / np.linalg.norm(z_c)
    x_c = np.cross(np.array([0.0, 0.0, 1.0]), z_c)  # body "down" × forward = right
    x_c = x_c / np.linalg.norm(x_c)
    y_c = np.cross(z_c, x_c)
    return np.column_stack([x_c, y_c, z_c])


def unit(v: FloatArray) -> FloatArray:
    n = float(np.linalg.norm(v))
    if n == 0.0:
        raise ValueError("zero-length vector has no direction")
    return np.asarray(v, float) / n
