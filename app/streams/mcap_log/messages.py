"""The Foxglove messages of one tick (:mod:`foxglove.messages`): the frame transforms
(tanker → drogue, tanker → receiver → camera_left → camera_right; m), the measured drogue pose
(m, in ``camera_left``), the image annotations, the 3-D scene and each camera's calibration —
what :class:`~app.streams.mcap_log.writer.FoxgloveLogger` logs on the channels of
:mod:`app.streams.mcap_log.channels`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from foxglove import messages as fm
from numpy.typing import NDArray

from app.geometry.calibration import StereoCalibration
from app.geometry.rotations import euler_to_matrix
from app.streams.annotations import REJECTED_RGB, WINDOW_RGB, Side, image_marks, led_color
from app.streams.mcap_log.channels import FRAME_IDS, LED_SPHERE_M, PROBE_SPHERE_M, McapTick, Vec3

if TYPE_CHECKING:
    from app.model.mount import CameraMount

VecLike = Sequence[float] | NDArray[np.float64]


def quat_xyzw(r: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) of a rotation matrix."""
    from scipy.spatial.transform import Rotation  # imported on first use (≈ 0.5 s)

    x, y, z, w = Rotation.from_matrix(np.asarray(r, float)).as_quat()
    return float(x), float(y), float(z), float(w)


def z_to(normal: VecLike) -> NDArray[np.float64]:
    """The smallest rotation taking +z onto ``normal`` (a ring's axis)."""
    from scipy.spatial.transform import Rotation

    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    s, c = float(np.linalg.norm(axis)), float(z @ n)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return np.asarray(Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix(), float)


def right_in_left(
    calibration: StereoCalibration,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The right camera's axes and origin (m) in the left camera's frame
    (``X_right = R · X_left + T`` ⇒ ``X_left = Rᵀ · X_right − Rᵀ · T``)."""
    r = np.asarray(calibration.R, float)
    return r.T, -(r.T @ np.asarray(calibration.T, float)) / 1e3


def ring_points(center_m: VecLike, normal: VecLike, radius_m: float, n: int = 36) -> list[Vec3]:
    """``n`` points (m) on the circle of ``radius_m`` about ``center_m`` normal to ``normal``."""
    r = z_to(normal)
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    local = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1) * radius_m
    pts = local @ r.T + np.asarray(center_m, float)
    return [(float(p[0]), float(p[1]), float(p[2])) for p in pts]


def camera_calibration(
    calibration: StereoCalibration, side: str, ts: fm.Timestamp | None = None
) -> fm.CameraCalibration:
    """One side's ``foxglove.CameraCalibration``: K (px), D (plumb_bob: k1 k2 p1 p2 k3) and, for
    the raw (unrectified) images, R = I and P = [K | 0] in that camera's own frame."""
    cam = calibration.left if side == "left" else calibration.right
    k = np.asarray(cam.K, float)
    w, h = calibration.image_size
    return fm.CameraCalibration(
        timestamp=ts,
        frame_id=FRAME_IDS[side],
        width=int(w),
        height=int(h),
        distortion_model="plumb_bob",
        D=[float(v) for v in cam.dist],
        K=[float(v) for v in k.ravel()],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[float(v) for v in np.hstack([k, np.zeros((3, 1))]).ravel()],
    )


def timestamp(ns: int) -> fm.Timestamp:
    """A log time (ns since the UNIX epoch) as a Foxglove timestamp."""
    return fm.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def vector3(t: VecLike) -> fm.Vector3:
    """A 3-vector as a Foxglove vector."""
    return fm.Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2]))


def quaternion(r: NDArray[np.float64]) -> fm.Quaternion:
    """A rotation matrix as a Foxglove quaternion."""
    x, y, z, w = quat_xyzw(r)
    return fm.Quaternion(x=x, y=y, z=z, w=w)


def image_annotations(tick: McapTick, side: Side, ts: fm.Timestamp) -> fm.ImageAnnotations:
    """The marks the page and the 3-D view draw (:func:`app.streams.annotations.image_marks`)
    as Foxglove annotations: each LED a point and its id in its colour, the windows outlined."""
    from foxglove.messages import (
        Color,
        ImageAnnotations,
        Point2,
        PointsAnnotation,
        PointsAnnotationType,
        TextAnnotation,
    )

    def colour(rgb: tuple[int, int, int]) -> Color:
        return Color(r=rgb[0] / 255, g=rgb[1] / 255, b=rgb[2] / 255, a=1.0)

    windows = None if tick.image_windows_px is None else tick.image_windows_px[side == "right"]
    marks = image_marks(
        tick.pose, side, windows_px=[(w[0], w[1], w[2], w[3]) for w in windows or ()]
    )
    points, texts = [], []
    for m in marks.leds:
        c = colour(led_color(m.led_id))
        points.append(
            PointsAnnotation(
                timestamp=ts,
                type=PointsAnnotationType.Points,
                points=[Point2(x=float(m.u_px), y=float(m.v_px))],
                outline_color=c,
                fill_color=c,
                thickness=6.0,
            )
        )
        texts.append(
            TextAnnotation(
                timestamp=ts,
                position=Point2(x=float(m.u_px) + 6.0, y=float(m.v_px) - 6.0),
                text=str(m.led_id),
                font_size=14.0,
                text_color=c,
                background_color=Color(r=0.0, g=0.0, b=0.0, a=0.5),
            )
        )
    if marks.rejected_px:
        grey = colour(REJECTED_RGB)
        points.append(
            PointsAnnotation(
                timestamp=ts,
                type=PointsAnnotationType.Points,
                points=[Point2(x=float(u), y=float(v)) for u, v in marks.rejected_px],
                outline_color=grey,
                fill_color=grey,
                thickness=3.0,
            )
        )
    for x0, y0, x1, y1 in marks.windows_px:
        points.append(
            PointsAnnotation(
                timestamp=ts,
                type=PointsAnnotationType.LineLoop,
                points=[
                    Point2(x=float(x0), y=float(y0)),
                    Point2(x=float(x1), y=float(y0)),
                    Point2(x=float(x1), y=float(y1)),
                    Point2(x=float(x0), y=float(y1)),
                ],
                outline_color=colour(WINDOW_RGB),
                thickness=1.5,
            )
        )
    return ImageAnnotations(points=points, texts=texts)


def scene_update(tick: McapTick, ts: fm.Timestamp) -> fm.SceneUpdate:
    """The 3-D scene: the measured ring and its LEDs in ``camera_left`` (deleted without a
    lock) and the probe tip in the tanker frame (m)."""
    from foxglove.messages import (
        Color,
        LinePrimitive,
        LinePrimitiveLineType,
        Point3,
        Pose,
        SceneEntity,
        SceneEntityDeletion,
        SceneUpdate,
        SpherePrimitive,
    )

    identity = quaternion(np.eye(3))
    entities, deletions = [], []
    drogue = None if tick.pose is None or not tick.pose.lock else tick.pose.drogue
    if drogue is not None and tick.pose is not None:
        c = np.asarray(drogue.center_mm, float) / 1e3
        ring = ring_points(c, drogue.normal, drogue.radius_mm / 1e3)
        leds = [
            SpherePrimitive(
                pose=Pose(position=vector3(np.asarray(led.xyz_mm) / 1e3), orientation=identity),
                size=vector3((LED_SPHERE_M,) * 3),
                color=Color(r=0.1, g=1.0, b=0.2, a=1.0),
            )
            for led in tick.pose.leds
        ]
        entities.append(
            SceneEntity(
                timestamp=ts,
                frame_id=FRAME_IDS["left"],
                id="drogue_measured",
                lines=[
                    LinePrimitive(
                        type=LinePrimitiveLineType.LineLoop,
                        pose=Pose(position=vector3((0, 0, 0)), orientation=identity),
                        thickness=0.02,
                        points=[Point3(x=p[0], y=p[1], z=p[2]) for p in ring],
                        color=Color(r=0.2, g=0.6, b=1.0, a=1.0),
                    )
                ],
                spheres=leds,
            )
        )
    else:
        deletions.append(SceneEntityDeletion(timestamp=ts, id="drogue_measured"))
    if tick.probe_tip_m is not None:
        entities.append(
            SceneEntity(
                timestamp=ts,
                frame_id="tanker",
                id="probe_tip",
                spheres=[
                    SpherePrimitive(
                        pose=Pose(position=vector3(tick.probe_tip_m), orientation=identity),
                        size=vector3((PROBE_SPHERE_M,) * 3),
                        color=Color(r=1.0, g=0.3, b=0.2, a=1.0),
                    )
                ],
            )
        )
    return SceneUpdate(deletions=deletions, entities=entities)


def frame_transforms(
    tick: McapTick,
    ts: fm.Timestamp,
    calibration: StereoCalibration | None,
    mount: CameraMount | None,
) -> fm.FrameTransforms:
    """tanker → drogue (its truth), tanker → receiver (its state) → camera_left (the rig's
    ``mount``) → camera_right (the ``calibration``'s extrinsics); m."""
    from foxglove.messages import FrameTransform, FrameTransforms

    out = []

    def add(parent: str, child: str, r: NDArray[np.float64], t: VecLike) -> None:
        out.append(
            FrameTransform(
                timestamp=ts,
                parent_frame_id=parent,
                child_frame_id=child,
                translation=vector3(t),
                rotation=quaternion(r),
            )
        )

    if tick.drogue_truth_m is not None:
        normal = tick.drogue_normal if tick.drogue_normal is not None else (1.0, 0.0, 0.0)
        add("tanker", "drogue", z_to(normal), tick.drogue_truth_m)
    if tick.uav_state is not None and len(tick.uav_state) >= 12:
        s = tick.uav_state
        add("tanker", "receiver", euler_to_matrix(s[6], s[7], s[8]), s[9:12])
        if mount is not None:
            add("receiver", FRAME_IDS["left"], mount.r_bc, mount.camera_b)
    if calibration is not None:
        r, t = right_in_left(calibration)
        add(FRAME_IDS["left"], FRAME_IDS["right"], r, t)
    return FrameTransforms(transforms=out)


def drogue_pose(tick: McapTick, ts: fm.Timestamp) -> fm.PoseInFrame | None:
    """The measured drogue centre (m) in ``camera_left``, +z along the ring's normal; None
    without a lock."""
    drogue = None if tick.pose is None or not tick.pose.lock else tick.pose.drogue
    if drogue is None:
        return None
    from foxglove.messages import Pose, PoseInFrame

    c = drogue.center_mm
    return PoseInFrame(
        timestamp=ts,
        frame_id=FRAME_IDS["left"],
        pose=Pose(
            position=vector3((c[0] / 1e3, c[1] / 1e3, c[2] / 1e3)),
            orientation=quaternion(z_to(drogue.normal)),
        ),
    )
