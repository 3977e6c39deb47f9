"""What each phase of a docking tick hands to the next (:meth:`DockingSimulation.step`,
PX4's ``PositionControl`` shape: sense → estimate → guide → control → propagate → contact).

Tanker frame, metres and seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.model.pose import PoseResult
from app.types import FloatArray


@dataclass(frozen=True)
class Sensing:
    """Sense + estimate: this tick's camera frame (if one was due) and the drogue filter's
    state after fusing the measurements whose latency has passed."""

    frame_status: str | None  # "ok", "drop", "duplicate" or None (no frame due)
    pose: PoseResult | None  # the pipeline's answer on the frame (camera frame, mm)
    left: NDArray[np.uint8] | None
    right: NDArray[np.uint8] | None
    led_truth_cam_mm: FloatArray | None
    measurement_m: FloatArray | None  # the last drogue measurement fused this tick
    exposure_t_s: float | None  # its exposure time
    lock: bool
    lock_reason: str | None


@dataclass(frozen=True)
class Aim:
    """Guide: where the probe tip is, where the drogue is (raw estimate and the one the
    reference follows: smoothed, led to the swing, with the bow wave's push), and whether to
    close now."""

    tip_m: FloatArray  # estimated probe tip
    tip_vel_mps: FloatArray
    drogue_raw_m: FloatArray  # the filter's drogue (without the bow wave's modelled push)
    drogue_m: FloatArray  # the drogue the reference follows
    drogue_vel_mps: FloatArray
    closing: bool  # the drogue is tracked, or searched for at its a-priori rest position
    commit: bool  # at the standoff (timed closure): close now
