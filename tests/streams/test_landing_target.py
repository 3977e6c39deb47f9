"""app.streams.landing_target: the MAVLink LANDING_TARGET mapping against independent math
(OpenCV's projection for the angles, scipy's rotations for the mount and the attitude)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.model.pose import DrogueResult, PoseResult
from app.streams.landing_target import (
    LANDING_TARGET_TYPE_VISION_FIDUCIAL,
    MAV_FRAME_BODY_FRD,
    RigMount,
    landing_target,
    no_target,
)


def _pose(center_mm, normal, lock=True, radius_mm=37.5) -> PoseResult:
    return PoseResult(
        lock=lock,
        drogue=DrogueResult(center_mm=center_mm, normal=normal, radius_mm=radius_mm, rms_mm=0.1),
    )


def test_angles_and_distance_agree_with_opencv_projection() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        c_mm = np.array([rng.uniform(-800, 800), rng.uniform(-600, 600), rng.uniform(1000, 9000)])
        t = landing_target(_pose(tuple(c_mm), (0, 0, -1.0)), 12.5, RigMount.forward_looking())
        # an ideal unit camera: the projection is (x/z, y/z), whose arctangents are the angles
        uv, _ = cv2.projectPoints(c_mm[None], np.zeros(3), np.zeros(3), np.eye(3), None)
        u, v = uv.ravel()
        assert t.angle_x == pytest.approx(math.atan(u), abs=1e-9)
        assert t.angle_y == pytest.approx(math.atan(v), abs=1e-9)
        assert t.distance == pytest.approx(np.linalg.norm(c_mm) / 1000, abs=1e-9)
        assert t.size_x == pytest.approx(2 * math.atan(0.0375 / t.distance), abs=1e-12)
        assert t.time_usec == 12_500_000 and t.position_valid == 1
        assert t.frame == MAV_FRAME_BODY_FRD and t.type == LANDING_TARGET_TYPE_VISION_FIDUCIAL


def test_body_position_relative_to_the_probe_tip_with_a_tilted_mount() -> None:
    # a camera toed in and pitched down, built independently with scipy (camera -> body)
    base = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # optical axis = body x
    tilt = Rotation.from_euler("zy", [-4.0, -6.0], degrees=True).as_matrix()
    r_bc = tilt @ base
    mount = RigMount(camera_body_m=(5.2, 0.2, -0.6), r_bc=r_bc, probe_tip_body_m=(8.2, 0.5, -0.3))
    c_mm = np.array([120.0, -80.0, 4000.0])
    t = landing_target(_pose(tuple(c_mm), (0.0, 0.0, 1.0)), 1.0, mount)
    expected = r_bc @ (c_mm / 1000) + np.array([5.2, 0.2, -0.6]) - np.array([8.2, 0.5, -0.3])
    assert (t.x, t.y, t.z) == pytest.approx(tuple(expected), abs=1e-12)
    # the drogue's attitude: q takes body +x onto the ring's axis (oriented forward)
    n_b = r_bc @ np.array([0.0, 0.0, 1.0])
    w, x, y, z = t.q
    rot = Rotation.from_quat([x, y, z, w])  # scipy: scalar last
    assert rot.apply([1.0, 0.0, 0.0]) == pytest.approx(tuple(n_b / np.linalg.norm(n_b)), abs=1e-9)
    assert math.isclose(w * w + x * x + y * y + z * z, 1.0, rel_tol=1e-12)


def test_square_drogue_has_identity_attitude_either_normal_sign() -> None:
    mount = RigMount.forward_looking()
    for normal in ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0)):
        t = landing_target(_pose((0.0, 0.0, 3000.0), normal), 0.0, mount)
        assert t.q == pytest.approx((1.0, 0.0, 0.0, 0.0), abs=1e-12)
        # no probe in the mount: relative to the camera, straight ahead in body x
        assert (t.x, t.y, t.z) == pytest.approx((3.0, 0.0, 0.0), abs=1e-12)


@pytest.mark.parametrize(
    "pose",
    [
        None,
        _pose((0.0, 0.0, 3000.0), (0, 0, 1.0), lock=False),
        PoseResult(lock=True, drogue=None),
        _pose((float("nan"), 0.0, 3000.0), (0, 0, 1.0)),
        _pose((0.0, 0.0, -3000.0), (0, 0, 1.0)),  # behind the camera
        _pose((0.0, 0.0, 3000.0), (0.0, 0.0, 0.0)),
    ],
)
def test_no_lock_or_nonsense_gives_an_invalid_target_with_no_position(pose) -> None:
    t = landing_target(pose, 2.0, RigMount.forward_looking())
    assert t == no_target(2.0)
    assert t.position_valid == 0 and (t.x, t.y, t.z, t.distance) == (0.0, 0.0, 0.0, 0.0)


def test_bad_mount_and_time_are_refused() -> None:
    with pytest.raises(ValueError, match="rotation"):
        RigMount(r_bc=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="finite"):
        RigMount(camera_body_m=(0.0, float("inf"), 0.0))
    with pytest.raises(ValueError, match="exposure time"):
        no_target(float("nan"))
