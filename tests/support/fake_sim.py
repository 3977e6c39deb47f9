"""A simulated tick for the tests' stand-in step sources (``app.service.records.SimState``).

Every field the record reads, ``None`` / ``False`` unless given: a fake source that only
cares about its time (or its pose) sets just those.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.model.pose import PoseResult
from app.sim.sim_config import SimConfig


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
    rta_reason: str | None = None
    run_outcome: str | None = None
    hose: None = None
    left_image: np.ndarray | None = None
    right_image: np.ndarray | None = None
    stereo_frame: None = None
    image_windows_px: None = None
    camera_pose_T: None = None


class FakeSim:
    """Moves the probe 1 m/s along x; done after ``steps`` steps (tests only)."""

    def __init__(
        self,
        config: SimConfig,
        calibration: object,
        steps: int = 10**9,
        clock=None,
        step_cost_s: float = 0.0,
    ) -> None:
        self.config = config
        self.dt = 1.0 / config.tick_hz
        self.k = 0
        self.steps = steps
        self.clock = clock
        self.step_cost_s = step_cost_s

    @property
    def done(self) -> bool:
        return self.k >= self.steps

    def step(self) -> FakeSimState:
        self.k += 1
        if self.clock is not None and self.step_cost_s:
            self.clock.advance(self.step_cost_s)
        t = self.k * self.dt
        return FakeSimState(
            t_s=t,
            phase="approach",
            pose=PoseResult(lock=True),
            lock=True,
            drogue_truth_m=np.array([-10.0, 0.0, 1.0]),
            drogue_normal=np.array([-1.0, 0.0, 0.0]),
            drogue_estimate_m=np.array([-10.0, 0.0, 1.0]),
            probe_tip_m=np.array([t * self.config.closure_speed_mps, 0.0, 0.0]),
            rel_position_m=np.array([5.0, 0.0, 0.0]),
            reference_m=np.zeros(3),
            uav_state=np.zeros(12),
            control=np.array([0.5, 0.0, 0.1, 0.0]),
            captured=False,
        )
