from __future__ import annotations

import numpy as np
import pytest

from app.geometry.calibration import StereoCalibration, paper_calibration
from app.resources import REPO_ROOT


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the navigation core's compiled loops once, before any test or any process a
    test spawns (they then load them from numba's on-disk cache)."""
    from app.sim.warmup import compile_kernels

    compile_kernels()


@pytest.fixture(scope="session")
def calib() -> StereoCalibration:
    return paper_calibration()


@pytest.fixture(scope="session")
def repo_root():
    return REPO_ROOT


def angle_deg(a, b) -> float:
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))
