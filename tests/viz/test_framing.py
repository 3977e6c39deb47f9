"""The 3-D view's framing (pure geometry) and its charts across runs (a real ViserServer)."""

from __future__ import annotations

import math
import socket
from types import SimpleNamespace

import numpy as np
import pytest

from app.model.tick import Control, TickRecord
from app.sim.sim_config import SimConfig
from app.viz.framing import docking_targets, frame_view, project
from app.viz.gui import DockingGui
from app.viz.service import start_viser


def _record(run: int, t_s: float, *, miss: float | None = None, x_uav: float = -14.0) -> TickRecord:
    return TickRecord(
        seq=int(t_s * 100) + 1000 * run,
        source="sim",
        t_s=t_s,
        clock_s=0.0,
        wall_time=0.0,
        run=run,
        drogue_truth_m=(-15.0, 0.3, 6.5),
        drogue_normal=(-1.0, 0.0, 0.0),
        probe_tip_m=(x_uav + 3.0, 0.0, 6.2),
        uav_state=[0.0] * 6 + [0.05, 0.02, 0.1] + [x_uav, 0.1, 6.4],
        control=Control(throttle=0.5, aileron=0.0, elevator=0.0, rudder=0.0),
        rel_position_m=(-1.0, 0.3, 0.3),
        captured=False if miss is None else miss < 0.305,
        miss_m=miss,
    )


def test_targets_cover_drogue_rim_probe_and_receiver() -> None:
    rec = _record(1, 0.0, x_uav=-20.0)
    pts = docking_targets(rec)
    # drogue centre + 4 rim extremes, probe tip, receiver CG + nose/tail + 2 wing tips
    assert pts.shape == (11, 3)
    assert np.allclose(pts[0], rec.drogue_truth_m)
    assert np.isclose(np.ptp(pts[:5, 1]), 2 * 0.305) and np.isclose(np.ptp(pts[:5, 2]), 0.61)
    wing = pts[-2:]
    assert math.isclose(float(np.linalg.norm(wing[0] - wing[1])), 2.9, rel_tol=1e-9)
    assert docking_targets(SimpleNamespace()).shape == (0, 3)


@pytest.mark.parametrize("aspect", [0.6, 1.0, 1.6, 2.4])
@pytest.mark.parametrize("x_uav", [-40.0, -20.0, -16.0])
def test_frame_view_keeps_every_target_inside_the_viewport(aspect: float, x_uav: float) -> None:
    pts = docking_targets(_record(1, 0.0, x_uav=x_uav))
    fov = math.radians(50.0)
    height = 600.0
    width = aspect * height
    position, look_at = frame_view(pts, fov_rad=fov, aspect=aspect, fill=0.8)
    uv = project(
        pts,
        position=position,
        look_at=look_at,
        up=(0.0, 0.0, -1.0),
        fov_rad=fov,
        width_px=width,
        height_px=height,
    )
    assert np.isfinite(uv).all()
    # inside, with the margin the 0.8 fill leaves (≥ 5 % of the narrower side on every edge)
    margin = 0.05 * min(width, height)
    assert (uv[:, 0] > margin).all() and (uv[:, 0] < width - margin).all(), uv
    assert (uv[:, 1] > margin).all() and (uv[:, 1] < height - margin).all(), uv
    # and not a distant speck: the targets span at least a quarter of the narrower side
    span = np.ptp(uv, axis=0)
    assert span.max() > 0.25 * min(width, height)


def test_project_matches_a_hand_computed_pinhole() -> None:
    # camera at the origin looking along +x, up = -z (tanker frame): +y is right, -z is up
    fov = math.radians(60.0)
    focal = 0.5 * 400 / math.tan(fov / 2)
    uv = project(
        np.array([[10.0, 1.0, -2.0], [-1.0, 0.0, 0.0]]),
        position=(0.0, 0.0, 0.0),
        look_at=(1.0, 0.0, 0.0),
        up=(0.0, 0.0, -1.0),
        fov_rad=fov,
        width_px=600,
        height_px=400,
    )
    assert np.allclose(uv[0], [300 + focal * 0.1, 200 - focal * 0.2])
    assert np.isnan(uv[1]).all()  # behind the camera


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_charts_hold_one_run_and_status_keeps_the_last_miss() -> None:
    server = start_viser("127.0.0.1", _free_port())
    try:
        actions = SimpleNamespace(loop=SimpleNamespace(config=SimConfig()), settings=None)
        gui = DockingGui(server, actions)
        for i in range(20):
            gui.record(_record(1, 0.1 * i, miss=0.12 if i == 19 else None))
        gui.record(_record(2, 0.0))
        gui.record(_record(2, 0.1))
        t = gui._arr("t")
        assert list(t) == [0.0, 0.1]  # run 1 is gone: no line from its end back to t = 0
        assert np.all(np.diff(t) > 0)
        gui.set_status(_record(2, 0.1), 30.0, 0)
        assert "miss 0.120 m (run 1, captured)" in gui.status.content
        gui.set_stopped()
        gui.set_stopped()  # once, however often the publisher notices
        assert gui.status.content.count("**STOPPED**") == 1
        assert gui.status.content.startswith("**STOPPED**")
        gui.set_status(_record(2, 0.2), 30.0, 0)  # running again: the note goes
        assert "STOPPED" not in gui.status.content
        gui.refresh_plots(0.305)
        assert np.array_equal(np.asarray(gui.plot_miss.data[0]), t)
        gui.close()
    finally:
        server.stop()
