"""The stereo rig's mounting on the receiver as the docking simulation flies it (body frame, m).

The one place the adapters get the left camera's pose on the airframe (its position and the
toe-in that aims it at a point ``camera_aim_ahead_m`` ahead of the probe tip:
:func:`app.geometry.rotations.look_at_camera`) without a simulation: the 3-D view, the MCAP
logs' ``/tf``, Foxglove and the MAVLink output. The record is :class:`app.model.mount.CameraMount`.
"""

from __future__ import annotations

from app.model.mount import CameraMount
from app.sim.docking import DockingConfig


def camera_mount(config: DockingConfig) -> CameraMount:
    """The mounting of ``config`` (its airframe's geometry unless overridden)."""
    return config.camera_mount()


def default_mount(plant: str | None = None) -> CameraMount:
    """The rig's mount on ``plant``'s airframe with the simulation's defaults (the default
    plant's airframe if None)."""
    return camera_mount(DockingConfig() if plant is None else DockingConfig(plant=plant))
