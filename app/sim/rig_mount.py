"""The stereo rig's mounting on the receiver as the docking simulation flies it (body frame, m).

One place for the left camera's pose on the airframe (its position and the toe-in that aims it
at a point ``camera_aim_ahead_m`` ahead of the probe tip: :func:`app.geometry.rotations.look_at_camera`)
for the adapters that need it without a simulation: the 3-D view and the MAVLink output.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.geometry.rotations import look_at_camera
from app.sim.docking import DockingConfig
from app.types import FloatArray


@dataclass(frozen=True)
class CameraMount:
    """The left camera's axes (``r_bc``: camera → body) and origin, the nose and the probe tip
    in the body frame (x forward, y right, z down; m)."""

    r_bc: FloatArray
    camera_b: FloatArray
    nose_b: FloatArray
    probe_tip_b: FloatArray


def camera_mount(config: DockingConfig) -> CameraMount:
    """The mounting of ``config`` (its airframe's geometry unless overridden)."""
    g = config.geometry()
    cam = np.asarray(g.camera_body_m, float)
    tip = np.asarray(g.probe_tip_body_m, float)
    aim = tip + np.array([config.camera_aim_ahead_m, 0.0, 0.0])
    return CameraMount(look_at_camera(cam, aim), cam, np.asarray(g.nose_body_m, float), tip)
