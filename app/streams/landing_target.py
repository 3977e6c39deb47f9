"""The navigation result as an autopilot's precision-landing target (MAVLink ``LANDING_TARGET``).

Pure numbers, no I/O: :func:`landing_target` maps one pipeline result (the drogue centre and
normal in the left-camera frame, mm; paper eqs. 17-19 and §5's circle fit) and the rig's mount
on the receiver to the fields of MAVLink 2's ``LANDING_TARGET`` (message 149). The link that
sends it is :mod:`app.streams.mavlink_link`; the mapping is documented in
``docs/ecosystem.md``.

Frames (``app.geometry.rotations``): camera ``C`` (x right, y down, z along the optical axis) and the
receiver's body ``B`` (x forward, y right wing, z down: MAVLink's ``MAV_FRAME_BODY_FRD``).

- ``angle_x`` / ``angle_y`` (rad): the drogue centre's angular offset from the left camera's
  optical axis, ``atan2(x_C, z_C)`` and ``atan2(y_C, z_C)`` (right and down positive).
- ``distance`` (m): the centre's range from the left camera's optical centre.
- ``size_x`` / ``size_y`` (rad): the ring's angular diameter, ``2·atan(r / distance)``.
- ``x, y, z`` (m, body FRD): the drogue centre relative to the probe tip,
  ``R_BC · c_C + r_cam_B − r_probe_B`` (with no probe in the mount: relative to the camera).
- ``q`` (w, x, y, z): the drogue's attitude in the body frame, the shortest rotation that takes
  body +x onto the drogue's axis (its ring normal oriented forward, away from the receiver), so
  a drogue square to the receiver is (1, 0, 0, 0); the roll about the axis is not observed by
  a circle and is reported as none.
- ``position_valid``: 1 only for a lock; without one every position field is 0 (no stale
  position is ever sent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from app.model.mount import CameraMount
from app.model.pose import PoseResult
from app.types import FloatArray

MAV_FRAME_BODY_FRD = 12  # MAVLink common.xml, MAV_FRAME
LANDING_TARGET_TYPE_VISION_FIDUCIAL = 2  # MAVLink common.xml, LANDING_TARGET_TYPE


def _identity() -> FloatArray:
    return np.eye(3)


@dataclass(frozen=True)
class RigMount:
    """Where the stereo rig's left camera sits on the receiver (body FRD frame, m).

    ``r_bc``: camera → body rotation (``p_B = r_bc · p_C + camera_body_m``);
    ``probe_tip_body_m``: the probe tip, or None to report positions relative to the camera.
    """

    camera_body_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    r_bc: FloatArray = field(default_factory=_identity)
    probe_tip_body_m: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        r = np.asarray(self.r_bc, dtype=float)
        if r.shape != (3, 3) or not np.all(np.isfinite(r)):
            raise ValueError("r_bc must be a finite 3x3 rotation")
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise ValueError("r_bc must be a proper rotation (orthonormal, det +1)")
        for name in ("camera_body_m", "probe_tip_body_m"):
            v = getattr(self, name)
            if v is not None and (len(v) != 3 or not all(math.isfinite(c) for c in v)):
                raise ValueError(f"{name} must be three finite numbers (m)")
        object.__setattr__(self, "r_bc", r)

    @classmethod
    def on_airframe(cls, mount: CameraMount) -> RigMount:
        """The rig of ``mount`` with its probe (body frame, m: e.g.
        :func:`app.sim.rig_mount.default_mount`'s)."""
        cam = np.asarray(mount.camera_b, dtype=float)
        tip = np.asarray(mount.probe_tip_b, dtype=float)
        return cls(
            camera_body_m=(float(cam[0]), float(cam[1]), float(cam[2])),
            r_bc=np.asarray(mount.r_bc, dtype=float),
            probe_tip_body_m=(float(tip[0]), float(tip[1]), float(tip[2])),
        )

    @classmethod
    def forward_looking(cls) -> RigMount:
        """The camera's optical axis along body +x, image right along body +y, at the body
        origin, no probe: positions relative to the left camera (the mount when none is given)."""
        # columns: the camera's x (right), y (down), z (forward) in body coordinates
        return cls(r_bc=np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))


@dataclass(frozen=True)
class LandingTarget:
    """The fields of MAVLink's ``LANDING_TARGET`` (SI units: s, rad, m)."""

    time_usec: int  # the exposure time of the frame pair (µs)
    angle_x: float
    angle_y: float
    distance: float
    size_x: float
    size_y: float
    x: float
    y: float
    z: float
    q: tuple[float, float, float, float]
    position_valid: int
    frame: int = MAV_FRAME_BODY_FRD
    type: int = LANDING_TARGET_TYPE_VISION_FIDUCIAL
    target_num: int = 0


def _shortest_arc(a: FloatArray, b: FloatArray) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) of the shortest rotation taking unit ``a`` onto unit ``b``."""
    dot = float(np.clip(a @ b, -1.0, 1.0))
    if dot < -1.0 + 1e-12:  # opposite: any perpendicular axis
        axis = np.cross(a, [0.0, 0.0, 1.0])
        if np.linalg.norm(axis) < 1e-9:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis = axis / np.linalg.norm(axis)
        return (0.0, float(axis[0]), float(axis[1]), float(axis[2]))
    c = np.cross(a, b)
    q = np.array([1.0 + dot, c[0], c[1], c[2]])
    q = q / np.linalg.norm(q)
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def no_target(exposure_time_s: float) -> LandingTarget:
    """The message for a frame without a lock: ``position_valid`` 0 and no position."""
    return LandingTarget(
        time_usec=_usec(exposure_time_s),
        angle_x=0.0,
        angle_y=0.0,
        distance=0.0,
        size_x=0.0,
        size_y=0.0,
        x=0.0,
        y=0.0,
        z=0.0,
        q=(1.0, 0.0, 0.0, 0.0),
        position_valid=0,
    )


def _usec(t_s: float) -> int:
    if not math.isfinite(t_s) or t_s < 0:
        raise ValueError(f"exposure time must be a finite, non-negative time (s), got {t_s!r}")
    return int(round(t_s * 1e6))


def landing_target(
    pose: PoseResult | None, exposure_time_s: float, mount: RigMount
) -> LandingTarget:
    """``LANDING_TARGET`` for one result (see the module docstring for the mapping).

    A result without a lock, without a drogue, or with a non-finite centre or normal gives
    :func:`no_target` (``position_valid`` 0): never a stale or confident wrong position.
    """
    if pose is None or not pose.lock or pose.drogue is None:
        return no_target(exposure_time_s)
    c_m = np.asarray(pose.drogue.center_mm, dtype=float) / 1000.0
    n_c = np.asarray(pose.drogue.normal, dtype=float)
    if not (np.all(np.isfinite(c_m)) and np.all(np.isfinite(n_c))) or c_m[2] <= 0.0:
        return no_target(exposure_time_s)
    distance = float(np.linalg.norm(c_m))
    n_norm = float(np.linalg.norm(n_c))
    if distance == 0.0 or n_norm == 0.0:
        return no_target(exposure_time_s)
    size = 2.0 * math.atan2(pose.drogue.radius_mm / 1000.0, distance)
    c_b = mount.r_bc @ c_m + np.asarray(mount.camera_body_m, dtype=float)
    origin = mount.probe_tip_body_m if mount.probe_tip_body_m is not None else mount.camera_body_m
    rel = c_b - np.asarray(origin, dtype=float)
    n_b = mount.r_bc @ (n_c / n_norm)
    if n_b[0] < 0.0:  # the ring's normal is a line: orient it forward
        n_b = -n_b
    return LandingTarget(
        time_usec=_usec(exposure_time_s),
        angle_x=math.atan2(float(c_m[0]), float(c_m[2])),
        angle_y=math.atan2(float(c_m[1]), float(c_m[2])),
        distance=distance,
        size_x=size,
        size_y=size,
        x=float(rel[0]),
        y=float(rel[1]),
        z=float(rel[2]),
        q=_shortest_arc(np.array([1.0, 0.0, 0.0]), n_b),
        position_valid=1,
    )
