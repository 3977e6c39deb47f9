"""A simulated tick for the tests' stand-in step sources (``app.server.records.SimState``).

Every field the record reads, ``None`` / ``False`` unless given: a fake source that only
cares about its time (or its pose) sets just those.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.vision.result import PoseResult


@dataclass
class FakeSimState:
    t_s: float = 0.0
    phase: str | None = None
    pose: PoseResult | None = None
    lock: bool = False
    lock_reason: str | None = None
    drogue_truth_m: np.ndarray | None = None
    drogue_normal: np.ndarray | None = None
    drogue_measured_m: np.ndarray | None = None
    drogue_estimate_m: np.ndarray | None = None
    probe_tip_m: np.ndarray | None = None
    rel_position_m: np.ndarray | None = None
    reference_m: np.ndarray | None = None
    uav_state: np.ndarray | None = None
    control: np.ndarray | None = None
    captured: bool | None = None
    miss_m: float | None = None
    led_truth_cam_mm: np.ndarray | None = None
    left_image: np.ndarray | None = None
    right_image: np.ndarray | None = None
