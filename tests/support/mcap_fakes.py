"""Telemetry records and raw frames made up for the recording tests (a child process's
writer uses them too)."""

from __future__ import annotations

import numpy as np

from app.model.pose import DrogueResult, LedResult, PoseResult
from app.model.tick import TickRecord
from tests.support.raw_frames import RawPair


def fake_record(i: int) -> TickRecord:
    return TickRecord(
        seq=i,
        source="sim",
        t_s=0.1 * i + 1 / 3,
        clock_s=0.1 * i,
        wall_time=1.7e9 + 0.1 * i,
        phase="approach",
        pose=fake_pose(i),
        lock=True,
        drogue_truth_m=(10.0, 0.5 + 0.01 * i, 2.0),
        drogue_normal=(-1.0, 0.0, 0.0),
        probe_tip_m=(5.0 + 0.1 * i, 0.4, 2.1),
        uav_state=[100.0, 0, 0, 0, 0, 0, 0.01, 0.02, -0.01, 5.0 + 0.1 * i, 0.3, 2.5],
    )


class FakeRaw(RawPair):
    """A raw sim tick: a stereo pair (noise: PNG cannot cheat) and the tracker's windows."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.left_image = rng.integers(0, 256, (120, 160), dtype=np.uint8)
        self.right_image = rng.integers(0, 256, (120, 160), dtype=np.uint8)
        self.image_windows_px = ([(10, 20, 50, 60)], [(5, 20, 45, 60), (70, 70, 90, 90)])


def fake_pose(i: int) -> PoseResult:
    leds = [
        LedResult(
            id=k + 1,
            left_px=(100.0 + 10 * k + 0.125 * i, 200.5),
            right_px=(80.0 + 10 * k, 200.25),
            xyz_mm=(10.0 * k, -5.0, 3000.0 - i),
            descriptor_distance=0.0,
            epipolar_px=0.1,
            reprojection_px=0.2,
        )
        for k in range(5)
    ]
    drogue = DrogueResult(
        center_mm=(12.345678901 + i, -23.456789012, 3000.123456789 - i),
        normal=(0.1, -0.05, -0.99373),
        radius_mm=305.0,
        rms_mm=0.4,
    )
    return PoseResult(lock=True, leds=leds, drogue=drogue)
