"""The synthetic checkerboard renderer: pattern, exact pixel rays (skew included), sample set."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from app.calibration.corners import detect_corners
from app.geometry.calibration import StereoCalibration
from app.geometry.projection import project_camera
from app.sim.checkerboard_render import (
    CheckerboardSpec,
    CheckerRenderSettings,
    board_visible,
    load_truth,
    pixel_rays,
    render_board_view,
    render_checker_set,
)

REPO = Path(__file__).resolve().parents[2]
SET_DIR = REPO / "sample_data" / "checkerboard"


def test_pattern_reflectance():
    spec = CheckerboardSpec(cols=9, rows=6, square_mm=25.0, margin_mm=20.0)
    s = 25.0
    # centres of the 10 x 7 squares: (i - 0.5) s, (j - 0.5) s for i in 0..9, j in 0..6
    i, j = np.meshgrid(np.arange(10), np.arange(7))
    vals = spec.reflectance((i - 0.5) * s, (j - 0.5) * s)
    assert vals[0, 0] == 0.0  # upper-left square black
    assert np.all(vals == ((i + j) % 2 == 1))  # checker alternation
    # margin is white, outside the printed sheet is NaN
    assert spec.reflectance(np.array([-s - 10.0]), np.array([0.0]))[0] == 1.0
    assert np.isnan(spec.reflectance(np.array([-s - 21.0]), np.array([0.0]))[0])
    assert np.isnan(spec.reflectance(np.array([0.0]), np.array([6 * s + 21.0]))[0])
    pts = spec.object_points()
    assert (
        pts.shape == (54, 3) and np.allclose(pts[1], [s, 0, 0]) and np.allclose(pts[9], [0, s, 0])
    )


def test_pixel_rays_invert_the_projection_with_skew():
    """Rays of the most distorted corner of the image re-project onto their own samples."""
    calib = StereoCalibration.load(REPO / "sample_data" / "calibration.json")
    cam = calib.left
    assert cam.skew != 0.0
    rays = pixel_rays(cam, (40, 32), supersample=3)
    offs = (np.arange(3) + 0.5) / 3 - 0.5
    k = 0
    for dv in offs:
        for du in offs:
            xy = rays[k].reshape(-1, 2).astype(np.float64)
            px = project_camera(cam, np.column_stack([xy, np.ones(len(xy))]))
            vv, uu = np.mgrid[0:32, 0:40]
            expected = np.column_stack([uu.ravel() + du, vv.ravel() + dv])
            assert np.abs(px - expected).max() < 2e-3  # float32 rays
            k += 1


def test_skewed_camera_is_rendered_exactly():
    """A view rendered through the paper's left camera (γ = −4.5 px): the detected corners
    sit on the forward projection of the true board corners."""
    calib = StereoCalibration.load(REPO / "sample_data" / "calibration.json")
    _, spec, poses = load_truth(SET_DIR / "truth.json")
    pose = poses[3]
    rays = pixel_rays(calib.left, calib.image_size)
    img = render_board_view(rays, pose.R, pose.t, spec, CheckerRenderSettings())
    det = detect_corners(img, (spec.cols, spec.rows))
    assert det is not None
    truth = project_camera(calib.left, (pose.R @ spec.object_points().T).T + pose.t)
    if np.linalg.norm(det[0] - truth[0]) > np.linalg.norm(det[-1] - truth[0]):
        det = det[::-1]
    err = np.linalg.norm(det - truth, axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.1 and err.max() < 0.35
    # the skew is visible: projecting without it puts the corners off by more than that
    no_skew = project_camera(
        type(calib.left)(
            K=calib.left.K * np.array([[1, 0, 1], [1, 1, 1], [1, 1, 1]]), dist=calib.left.dist
        ),
        (pose.R @ spec.object_points().T).T + pose.t,
    )
    assert np.sqrt(np.mean(np.sum((det - no_skew) ** 2, axis=1))) > 0.3


def test_sample_set_is_reproduced_by_the_renderer():
    """Pair 00 of sample_data/checkerboard is what the code renders from truth.json."""
    calib, spec, poses = load_truth(SET_DIR / "truth.json")
    rs = render_checker_set(calib, spec, seed=7, poses=poses[:1])
    for side, img in (("left", rs.left[0]), ("right", rs.right[0])):
        ref = cv2.imread(str(SET_DIR / f"{side}_00.png"), cv2.IMREAD_GRAYSCALE)
        diff = np.abs(img.astype(int) - ref.astype(int))
        assert diff.mean() < 0.02 and diff.max() <= 2, (side, diff.mean(), diff.max())
    for pose in poses:
        assert board_visible(calib, pose, spec)
