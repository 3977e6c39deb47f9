"""The tests' worker (``tests/support/inline_sim.py``: the worker loop in the test's process)
and the service's (a spawned process) give the same ticks for the same config: the tests take
the deployed path, only the launcher differs (issue 34: one execution path per producer)."""

from __future__ import annotations

import numpy as np

from app.geometry.calibration import StereoCalibration
from app.service.settings import DEFAULT_CALIBRATION
from app.service.sim_worker import proxy
from app.sim.sim_config import SimConfig
from tests.support.inline_sim import inline_sim

N_TICKS = 12


Pair = tuple[np.ndarray | None, np.ndarray | None]


def _ticks(factory: proxy.ProcessSourceFactory) -> tuple[list[proxy.ProcessTick], Pair]:
    """``N_TICKS`` ticks of one config, and the last one's images (read before the close)."""
    config = SimConfig(tick_hz=30.0, plant="linear", seed=12345, turbulence="light")
    try:
        src = factory(config, StereoCalibration.load(DEFAULT_CALIBRATION))
        ticks = [src.step() for _ in range(N_TICKS)]
        return ticks, (ticks[-1].left_image, ticks[-1].right_image)
    finally:
        factory.close()


def test_the_inline_worker_and_the_spawned_worker_give_the_same_ticks() -> None:
    spawned, (la, ra) = _ticks(proxy.process_source_factory(image_hz=1000.0))
    inline, (lb, rb) = _ticks(inline_sim())
    assert len(spawned) == len(inline) == N_TICKS
    for a, b in zip(spawned, inline, strict=True):
        sa, sb = a.state, b.state
        assert sa.t_s == sb.t_s and sa.phase == sb.phase and sa.lock == sb.lock
        for name in ("probe_tip_m", "drogue_truth_m", "drogue_estimate_m", "uav_state"):
            np.testing.assert_array_equal(getattr(sa, name), getattr(sb, name), err_msg=name)
        assert sa.pose is not None and sb.pose is not None
        assert sa.pose.lock == sb.pose.lock
        assert (sa.pose.drogue is None) == (sb.pose.drogue is None)
        if sa.pose.drogue is not None and sb.pose.drogue is not None:
            assert sa.pose.drogue.center_mm == sb.pose.drogue.center_mm
    # the images the subscribers read: the same pixels through the ring and inline
    assert la is not None and lb is not None and ra is not None and rb is not None
    assert np.array_equal(la, lb) and np.array_equal(ra, rb)
    assert any(t.state.lock for t in inline), "vision in the loop locked at least once"
