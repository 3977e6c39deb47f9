"""The stereo rig's mounting on the receiver (body frame: x forward, y right, z down; m).

The record only: :func:`app.sim.rig_mount.default_mount` computes it from an airframe's geometry
(the one place it is computed for the adapters: the 3-D view, the MCAP logs' ``/tf``, Foxglove
and MAVLink).
"""

from __future__ import annotations

from dataclasses import dataclass

from app.types import FloatArray


@dataclass(frozen=True)
class CameraMount:
    """The left camera's axes (``r_bc``: camera → body, ``p_B = r_bc · p_C + camera_b``) and
    origin, the nose and the probe tip in the body frame (m)."""

    r_bc: FloatArray
    camera_b: FloatArray
    nose_b: FloatArray
    probe_tip_b: FloatArray
