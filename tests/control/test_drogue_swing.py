"""app.control.drogue_swing against the hose–drogue model it stands for (app.sim.hose_drogue:
its free lateral swing integrated by its own stepper)."""

from __future__ import annotations

import numpy as np
import pytest

from app.control.drogue_swing import predict_swing_offset
from app.sim.hose_drogue import HoseDrogue, HoseDrogueParams


@pytest.mark.parametrize("airspeed", [120.0, 147.5])
def test_prediction_follows_the_free_swing_of_the_hose_drogue_model(airspeed):
    p = HoseDrogueParams(airspeed_mps=airspeed, air_density=0.771, bow_force_n=0.0)
    d = HoseDrogue(p)
    d.reset(np.array([0.0, 0.25, -0.15]))
    d.v = np.array([0.0, -0.2, 0.3])
    x0, v0 = d.d.copy(), d.v.copy()
    dt = 0.02
    for k in range(1, 101):
        d.step(dt, np.zeros(3))
        if k % 25 == 0:
            got = predict_swing_offset(x0[1:], v0[1:], p.omega_rad_s, p.damping_ratio, k * dt)
            np.testing.assert_allclose(got, d.d[1:], atol=0.01)  # m, over up to 2 s


def test_zero_horizon_and_decay():
    x = predict_swing_offset(np.array([0.3, -0.1]), np.array([0.0, 0.0]), 1.6, 0.08, 0.0)
    np.testing.assert_allclose(x, [0.3, -0.1])
    far = predict_swing_offset(np.array([0.3, -0.1]), np.array([0.0, 0.0]), 1.6, 0.5, 30.0)
    assert np.max(np.abs(far)) < 1e-6
