"""Smoke tests of the viser scene: a real ViserServer on a free port, named nodes, updates."""

from __future__ import annotations

import socket
import time
from types import SimpleNamespace

import numpy as np
import pytest

from app.geometry.calibration import paper_calibration
from app.model.pose import DrogueResult, LedResult, PoseResult
from app.model.tick import Control, TickRecord
from app.viz.scene import NODE_NAMES, CameraPose, DockingScene
from app.viz.service import ViserPortError, start_viser
from tests.support.raw_frames import RawPair


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _record(seq: int, pose: PoseResult | None) -> TickRecord:
    return TickRecord(
        seq=seq,
        source="sim",
        t_s=0.1 * seq,
        clock_s=0.0,
        wall_time=0.0,
        run=1,
        pose=pose,
        lock=pose is not None,
        drogue_truth_m=(-8.0, 0.2, 1.0),
        drogue_normal=(-1.0, 0.0, 0.0),
        probe_tip_m=(-2.0 + 0.1 * seq, 0.0, 1.0),
        reference_m=(-2.0, 0.1, 1.0),
        uav_state=[0.0] * 9 + [-3.0, 0.0, 1.0],
        control=Control(throttle=0.5, aileron=0.0, elevator=0.0, rudder=0.0),
        rel_position_m=(-6.0, 0.2, 0.0),
    )


@pytest.fixture(scope="module")
def server():
    srv = start_viser("127.0.0.1", _free_port())
    yield srv
    srv.stop()


def test_scene_has_named_nodes_and_updates_in_place(server) -> None:
    calib = paper_calibration()
    scene = DockingScene(server, calib)
    for name in NODE_NAMES:
        assert server.scene.get_handle_by_name(name) is not None, name
    # camera axes in the tanker frame: x_C = y_T (right), y_C = z_T (down), z_C = x_T (forward)
    R_TC = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    cam = CameraPose(R_TC, np.array([-3.0, 0.0, 1.0]))
    leds = [
        LedResult(
            id=i + 1,
            left_px=(600.0 + i, 500.0),
            right_px=(500.0 + i, 500.0),
            xyz_mm=(100.0 * i, 0.0, 5000.0),
            descriptor_distance=0.1,
            epipolar_px=0.1,
            reprojection_px=0.1,
        )
        for i in range(5)
    ]
    pose = PoseResult(
        lock=True,
        leds=leds,
        drogue=DrogueResult(
            center_mm=(200.0, 0.0, 5000.0), normal=(0.0, 0.0, -1.0), radius_mm=75.0, rms_mm=0.1
        ),
    )
    raw = RawPair(
        camera_pose_T=(cam.R_TC, cam.t_TC),
        left_image=np.zeros((1024, 1280), np.uint8),
        right_image=np.zeros((1024, 1280), np.uint8),
    )
    basket = server.scene.get_handle_by_name("/drogue/basket")
    handles_before = {name: server.scene.get_handle_by_name(name) for name in NODE_NAMES}
    for k in range(5):
        scene.update(_record(k, pose), raw, images=(k == 0))
    # same handle objects (never re-added), positions follow the record
    for name in NODE_NAMES:
        assert server.scene.get_handle_by_name(name) is handles_before[name], name
    assert server.scene.get_handle_by_name("/drogue/basket") is basket
    np.testing.assert_allclose(scene.drogue.position, (-8.0, 0.2, 1.0))
    np.testing.assert_allclose(scene.probe_tip.position, (-1.6, 0.0, 1.0), atol=1e-9)
    # measured LEDs: camera (x right, y down, z forward) → tanker
    expected = cam.to_tanker(np.array([led.xyz_mm for led in leds]))
    np.testing.assert_allclose(scene.measured_leds.points, expected, atol=1e-5)
    assert scene.measured_leds.points.dtype == np.float32
    assert scene.match_lines.points.shape == (10, 2, 3)  # 5 LEDs × 2 cameras, one batch
    np.testing.assert_allclose(scene.match_lines.points[0, 0], cam.t_TC, atol=1e-6)
    assert scene.trail.points.shape == (4, 2, 3)  # 5 tip positions → 4 segments
    np.testing.assert_allclose(scene.frustums["left"].position, cam.t_TC)
    # right camera centre = −Rᵀ·T (mm) from the left one, in the tanker frame
    c_r = -calib.R.T @ calib.T / 1000.0
    np.testing.assert_allclose(scene.frustums["right"].position, cam.t_TC + R_TC @ c_r, atol=1e-9)


def test_pinned_port_taken_fails_loudly() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = int(s.getsockname()[1])
        t0 = time.time()
        with pytest.raises(ViserPortError, match=str(port)):
            start_viser("127.0.0.1", port)
        assert time.time() - t0 < 30


@pytest.mark.parametrize("plant", ["linear", "jsbsim"])
def test_the_ticks_own_camera_pose_puts_leds_on_the_drogue_rim(plant: str) -> None:
    """Whatever the airframe's mounting: the pose each tick carries (its frame's) maps the
    simulator's LED truth onto the rim of the drogue the frame saw."""
    from app.sim.docking import DockingConfig, DockingSimulation
    from app.viz.scene import camera_pose_from_tick

    cfg = DockingConfig(plant=plant, tick_hz=30.0, turbulence="light", seed=1)
    sim = DockingSimulation(cfg)
    prev = sim.step()
    tick = sim.step()
    cam = camera_pose_from_tick(SimpleNamespace(uav_state=None), tick, None)
    assert cam is not None and tick.led_truth_cam_mm is not None
    world = cam.to_tanker(np.asarray(tick.led_truth_cam_mm))
    dist = np.linalg.norm(world - np.asarray(prev.drogue_truth_m), axis=1)
    np.testing.assert_allclose(dist, cfg.ring_radius_m, atol=0.002)


def test_camera_pose_from_real_sim_tick_puts_leds_on_the_drogue_rim() -> None:
    """Independent check of the camera mounting: the simulator's LED truth (camera frame, mm)
    mapped to the tanker frame must lie on the drogue rim around ``drogue_truth_m``."""
    from app.sim.docking import DockingConfig, DockingSimulation
    from app.sim.rig_mount import default_mount
    from app.viz.scene import camera_pose_from_tick

    cfg = DockingConfig(tick_hz=30.0, turbulence="light", seed=1)
    sim = DockingSimulation(cfg)
    prev = sim.step()
    tick = sim.step()
    assert tick.led_truth_cam_mm is not None
    # the frame of tick k is rendered before the dynamics step: receiver state and drogue of
    # tick k−1 (what the scene gets as ``frame_uav``)
    rec = SimpleNamespace(uav_state=list(prev.uav_state))
    cam = camera_pose_from_tick(rec, None, default_mount())
    assert cam is not None
    world = cam.to_tanker(np.asarray(tick.led_truth_cam_mm))
    dist = np.linalg.norm(world - np.asarray(prev.drogue_truth_m), axis=1)
    np.testing.assert_allclose(dist, cfg.ring_radius_m, atol=0.002)
    # and in the rim plane (normal ⟂ LED offsets)
    off = world - np.asarray(prev.drogue_truth_m)
    assert np.max(np.abs(off @ np.asarray(prev.drogue_normal))) < 0.002


def test_scene_draws_the_flown_hose_and_its_readout(server) -> None:
    from app.model.tick import HoseInfo
    from app.viz.scene import hose_readout

    scene = DockingScene(server, paper_calibration())
    nodes = [(-0.75 * i, 0.01 * i, 0.15 * i) for i in range(21)]
    hose = HoseInfo(nodes_m=nodes, tension_n=2210.4, payout_m=14.62, contact_peak_tension_n=2290.0)
    scene.update(_record(0, None).model_copy(update={"hose": hose}), None, images=False)
    segs = np.asarray(scene.hose.points)
    assert segs.shape == (20, 2, 3)  # one segment per pair of the record's nodes
    np.testing.assert_allclose(segs[:, 0], nodes[:-1], atol=1e-6)
    np.testing.assert_allclose(segs[-1, 1], nodes[-1], atol=1e-6)
    assert scene.hose_readout.visible
    assert scene.hose_readout.text == "hose 2210 N · reel payout 14.62 m · contact peak 2290 N"
    # the reduced model: nodes without a tension → the line, no readout
    scene.update(
        _record(1, None).model_copy(update={"hose": HoseInfo(nodes_m=nodes)}), None, images=False
    )
    assert not scene.hose_readout.visible
    assert hose_readout(None) is None
