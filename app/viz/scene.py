"""The docking 3-D scene (viser). Tanker-fixed frame in metres: x forward, y right, z down.

Nodes are created once (:meth:`DockingScene.__init__`) and only updated afterwards
(:meth:`DockingScene.update`, inside ``server.atomic()``). Named nodes:

``/tanker``, ``/hose`` (with ``/hose/readout``: the tension and reel payout), ``/drogue`` (with ``/drogue/basket`` ghosted truth, ``/drogue/capture_disc``),
``/drogue_normal`` (arrow), ``/leds/led_1..N`` (spheres coloured by id), ``/measured/center``,
``/measured/ring``, ``/measured/leds`` (point cloud), ``/receiver`` (with ``/receiver/fuselage``,
``/receiver/wing``), ``/probe``, ``/probe_tip``, ``/cameras/left``, ``/cameras/right`` (frustums
with the current images), ``/match_lines`` (one batched segment set), ``/trail``, ``/reference``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import viser
import viser.transforms as vtf

from app.geometry.led_ids import DEFAULT_PHASE_DEG
from app.geometry.rotations import euler_to_matrix
from app.model.frames import RawFrame
from app.model.mount import CameraMount
from app.model.tick import HoseInfo, TickRecord
from app.streams.annotations import LED_COLORS_RGB, annotate, led_color

DROGUE_RADIUS_M = 0.305
TRAIL_POINTS = 240
LED_COUNT = 5

NODE_NAMES = (
    "/tanker",
    "/hose",
    "/hose/readout",
    "/drogue",
    "/drogue/basket",
    "/drogue/capture_disc",
    "/drogue_normal",
    "/leds/led_1",
    "/measured/center",
    "/measured/ring",
    "/measured/leds",
    "/receiver",
    "/receiver/fuselage",
    "/receiver/wing",
    "/probe",
    "/probe_tip",
    "/cameras/left",
    "/cameras/right",
    "/match_lines",
    "/trail",
    "/reference",
)


@dataclass(frozen=True)
class CameraPose:
    """Left camera in the tanker frame: ``p_T = R_TC · p_C + t_TC`` (m)."""

    R_TC: np.ndarray
    t_TC: np.ndarray

    def to_tanker(self, xyz_cam_mm: np.ndarray) -> np.ndarray:
        pts = np.asarray(xyz_cam_mm, dtype=float).reshape(-1, 3) / 1000.0
        return np.asarray((self.R_TC @ pts.T).T + self.t_TC)


def wxyz_from_matrix(R: np.ndarray) -> np.ndarray:
    return np.asarray(vtf.SO3.from_matrix(np.asarray(R, dtype=float)).wxyz)


def frame_from_z(n: np.ndarray) -> np.ndarray:
    """Rotation whose third column is ``n`` (unit); first column kept horizontal if possible."""
    z = np.asarray(n, dtype=float)
    norm = float(np.linalg.norm(z))
    z = z / norm if norm > 1e-9 else np.array([-1.0, 0.0, 0.0])
    ref = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


euler_matrix = euler_to_matrix  # one 3-2-1 convention, from the simulation core


def basket_mesh(radius: float = DROGUE_RADIUS_M, n: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A drogue basket: a conical frustum, rim at z=0 (radius ``radius``), throat at z=−0.45."""
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rim = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(n)])
    throat = np.column_stack([0.09 * np.cos(ang), 0.09 * np.sin(ang), np.full(n, -0.45)])
    verts = np.vstack([rim, throat])
    faces = []
    for i in range(n):
        j = (i + 1) % n
        faces.append([i, j, n + i])
        faces.append([j, n + j, n + i])
    return verts.astype(np.float32), np.asarray(faces, dtype=np.uint32)


def disc_mesh(radius: float, n: int = 48) -> tuple[np.ndarray, np.ndarray]:
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    verts = np.vstack(
        [
            [0.0, 0.0, 0.0],
            np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(n)]),
        ]
    )
    faces = [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
    return verts.astype(np.float32), np.asarray(faces, dtype=np.uint32)


def circle_segments(center: np.ndarray, R: np.ndarray, radius: float, n: int = 40) -> np.ndarray:
    ang = np.linspace(0, 2 * np.pi, n + 1)
    local = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(n + 1)])
    pts = (R @ local.T).T + center
    return np.stack([pts[:-1], pts[1:]], axis=1)


def polyline_segments(points: np.ndarray) -> np.ndarray:
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(pts) < 2:
        p = pts[0] if len(pts) else np.zeros(3)
        return np.stack([p, p])[None]
    return np.stack([pts[:-1], pts[1:]], axis=1)


class HasUavState(Protocol):
    """A tick record, or the receiver state of the frame's time: ``uav_state`` (12 states)."""

    @property
    def uav_state(self) -> Sequence[float] | None: ...


@dataclass(frozen=True)
class FrameUavState:
    """The receiver's state when a tick's camera frame was taken (12 states)."""

    uav_state: Sequence[float] | None


def camera_pose_from_tick(
    record: HasUavState, raw: RawFrame | None, geometry: CameraMount | None
) -> CameraPose | None:
    """The left camera's pose in the tanker frame for a simulated tick, if it can be known.

    ``raw.camera_pose_T`` ((R_TC, t_TC)) when given; otherwise from the receiver state
    (``uav_state``: φ, θ, ψ at 6..8, position at 9..11) and the camera mounting.
    """
    pose = None if raw is None else raw.camera_pose_T
    if pose is not None:
        R, t = pose
        return CameraPose(np.asarray(R, float), np.asarray(t, float))
    uav = record.uav_state
    if geometry is None or uav is None or len(uav) < 12:
        return None
    R_TB = euler_matrix(uav[6], uav[7], uav[8])
    return CameraPose(R_TB @ geometry.r_bc, np.asarray(uav[9:12], float) + R_TB @ geometry.camera_b)


def hose_readout(hose: HoseInfo | None) -> str | None:
    """The hose's readout in the 3-D view (None: the hose model has no tension or reel)."""
    if hose is None or hose.tension_n is None:
        return None
    text = f"hose {hose.tension_n:.0f} N"
    if hose.payout_m is not None:
        text += f" · reel payout {hose.payout_m:.2f} m"
    if hose.contact_peak_tension_n is not None:
        text += f" · contact peak {hose.contact_peak_tension_n:.0f} N"
    return text


class DockingScene:
    """Creates the scene nodes once and updates them from tick records."""

    def __init__(
        self,
        server: viser.ViserServer,
        calibration: Any,
        geometry: CameraMount | None = None,
    ) -> None:
        self.server = server
        self.geometry = geometry
        self._last_cam: CameraPose | None = None
        self.scene = server.scene
        self._trail: deque[np.ndarray] = deque(maxlen=TRAIL_POINTS)
        self._ref: deque[np.ndarray] = deque(maxlen=TRAIL_POINTS)
        self._last_run: int | None = None
        s = self.scene
        s.set_up_direction("-z")
        s.add_grid(
            "/grid",
            width=40.0,
            height=20.0,
            plane="xy",
            position=(-12.0, 0.0, 12.0),
            cell_size=1.0,
            section_size=5.0,
        )
        s.add_frame("/tanker", axes_length=1.0, axes_radius=0.03)
        s.add_label("/tanker/label", "tanker (hose exit)", position=(0.0, 0.0, -0.4))
        self.hose = s.add_line_segments(
            "/hose", np.zeros((10, 2, 3), np.float32), (40, 40, 40), thickness=0.04
        )
        self.hose_readout = s.add_label(
            "/hose/readout", "", position=(-7.5, 0.0, 0.6), visible=False
        )
        self.drogue = s.add_frame("/drogue", show_axes=False, position=(-15.0, 0.0, 3.0))
        bv, bf = basket_mesh()
        self.basket = s.add_mesh_simple(
            "/drogue/basket", bv, bf, color=(200, 200, 210), opacity=0.35, side="double"
        )
        dv, df = disc_mesh(DROGUE_RADIUS_M)
        self.capture_disc = s.add_mesh_simple(
            "/drogue/capture_disc", dv, df, color=(80, 220, 120), opacity=0.25, side="double"
        )
        self.normal_arrow = s.add_arrows(
            "/drogue_normal",
            np.zeros((1, 2, 3), np.float32) + np.array([[[0, 0, 0], [0.5, 0, 0]]], np.float32),
            (255, 200, 0),
            shaft_radius=0.012,
            head_radius=0.03,
            head_length=0.08,
        )
        self.leds = [
            s.add_icosphere(
                f"/leds/led_{i + 1}", radius=0.035, color=LED_COLORS_RGB[i], subdivisions=2
            )
            for i in range(LED_COUNT)
        ]
        self.measured_center = s.add_icosphere(
            "/measured/center", radius=0.03, color=(255, 60, 200), visible=False
        )
        self.measured_ring = s.add_line_segments(
            "/measured/ring",
            np.zeros((40, 2, 3), np.float32),
            (255, 60, 200),
            thickness=0.015,
            visible=False,
        )
        self.measured_leds = s.add_point_cloud(
            "/measured/leds",
            np.zeros((LED_COUNT, 3), np.float32),
            np.array(LED_COLORS_RGB, dtype=np.uint8),
            point_size=0.05,
            point_shape="circle",
            precision="float32",
            visible=False,
        )
        self.receiver = s.add_frame("/receiver", axes_length=0.6, axes_radius=0.02)
        s.add_box(
            "/receiver/fuselage",
            color=(90, 110, 140),
            dimensions=(2.0, 0.3, 0.3),
            position=(-0.6, 0.0, 0.0),
        )
        s.add_box(
            "/receiver/wing",
            color=(110, 130, 160),
            dimensions=(0.45, 2.9, 0.05),
            position=(-0.5, 0.0, 0.05),
        )
        self.probe = s.add_line_segments(
            "/probe", np.zeros((1, 2, 3), np.float32), (230, 230, 230), thickness=0.03
        )
        self.probe_tip = s.add_icosphere("/probe_tip", radius=0.04, color=(255, 255, 255))
        self.frustums: dict[str, Any] = {}
        self.match_lines = s.add_line_segments(
            "/match_lines",
            np.zeros((1, 2, 3), np.float32),
            (0, 230, 255),
            thickness=0.006,
            visible=False,
        )
        self.trail = s.add_line_segments(
            "/trail", np.zeros((1, 2, 3), np.float32), (255, 120, 40), thickness=0.02
        )
        self.reference = s.add_line_segments(
            "/reference", np.zeros((1, 2, 3), np.float32), (60, 160, 255), thickness=0.015
        )
        self.set_calibration(calibration)

    # ---- cameras ---------------------------------------------------------------------
    def set_calibration(self, calibration: Any) -> None:
        self.calibration = calibration
        w, h = calibration.image_size
        for side, cam in (("left", calibration.left), ("right", calibration.right)):
            fov = 2.0 * math.atan2(h / 2.0, cam.fy)
            color = (230, 80, 80) if side == "left" else (80, 120, 240)
            old = self.frustums.get(side)
            kwargs: dict[str, Any] = {}
            if old is not None:
                kwargs = {"position": old.position, "wxyz": old.wxyz}
            self.frustums[side] = self.scene.add_camera_frustum(
                f"/cameras/{side}",
                fov=fov,
                aspect=w / h,
                scale=0.25,
                color=color,
                thickness=0.01,
                **kwargs,
            )
        self._R_lr = np.asarray(calibration.R, float).T  # right camera axes in the left frame
        self._c_r = -np.asarray(calibration.R, float).T @ np.asarray(calibration.T, float) / 1000.0

    def camera_centers(self, cam: CameraPose) -> tuple[np.ndarray, np.ndarray]:
        return cam.t_TC, cam.t_TC + cam.R_TC @ self._c_r

    # ---- per-tick update ------------------------------------------------------------
    def reset_trails(self) -> None:
        self._trail.clear()
        self._ref.clear()

    def update(
        self,
        record: TickRecord,
        raw: RawFrame | None,
        *,
        images: bool = False,
        frame_uav: Any = None,
    ) -> None:
        """Update every node from a tick record (inside ``server.atomic()``).

        ``frame_uav``: the receiver state when this tick's camera frame was taken (the
        simulation renders before it integrates, i.e. the previous tick's ``uav_state``);
        it places the measured points and the LED truth. Default: ``record.uav_state``.
        """
        if record.source == "sim" and record.run != self._last_run:
            self._last_run = record.run
            self.reset_trails()
        cam_now: CameraPose | None = None
        if record.source == "sim":
            cam_now = camera_pose_from_tick(record, raw, self.geometry)
            cam = cam_now
            if frame_uav is not None:
                cam = camera_pose_from_tick(FrameUavState(frame_uav), raw, self.geometry)
            if cam_now is not None:
                self._last_cam = cam_now
        else:  # an uploaded pair: shown as seen from the current camera pose
            cam = self._last_cam
        with self.server.atomic():
            if record.source == "sim":
                self._update_sim(record, cam_now, cam)
            self._update_measured(record, cam)
            if images and raw is not None:
                self._update_images(record, raw)

    def _update_hose(self, record: TickRecord, drogue: np.ndarray, normal: np.ndarray) -> None:
        """The flown hose's nodes (the record's), else a display line from the hose exit to
        the drogue's throat with a little sag; the readout: tension, reel payout and the last
        contact's peak tension where the hose model has them."""
        hose = record.hose
        if hose is not None and len(hose.nodes_m) >= 2:
            pts = np.asarray(hose.nodes_m, float)
        else:
            throat = drogue - 0.45 * normal
            s = np.linspace(0.0, 1.0, 11)[:, None]
            pts = s * throat[None, :]
            pts[:, 2] += 0.08 * np.linalg.norm(throat) * np.sin(np.pi * s[:, 0])
        self.hose.points = polyline_segments(pts).astype(np.float32)
        text = hose_readout(hose)
        self.hose_readout.visible = text is not None
        if text is not None:
            self.hose_readout.text = text
            self.hose_readout.position = tuple(0.5 * pts[len(pts) // 2] + 0.5 * pts[-1])

    def _update_sim(
        self, record: TickRecord, cam: CameraPose | None, cam_frame: CameraPose | None
    ) -> None:
        drogue = record.drogue_truth_m
        if drogue is not None:
            d = np.asarray(drogue)
            n = np.asarray(record.drogue_normal if record.drogue_normal is not None else (-1, 0, 0))
            R = frame_from_z(n)
            self.drogue.position = d
            self.drogue.wxyz = wxyz_from_matrix(R)
            self.normal_arrow.points = np.array([[d, d + 0.6 * n]], dtype=np.float32)
            self._update_hose(record, d, n)
            leds_cam = record.led_truth_cam_mm
            if leds_cam is not None and cam_frame is not None and len(leds_cam) > 0:
                world = cam_frame.to_tanker(np.asarray(leds_cam))
            else:  # on the rim at roll 0 (the id convention of app.geometry.led_ids)
                world = np.array(
                    [
                        d + DROGUE_RADIUS_M * (R @ np.array([math.sin(a), -math.cos(a), 0.0]))
                        for a in np.radians(
                            DEFAULT_PHASE_DEG + np.arange(LED_COUNT) * 360.0 / LED_COUNT
                        )
                    ]
                )
            for i, h in enumerate(self.leds):
                if i < len(world):
                    h.position = world[i]
                    h.visible = True
                else:
                    h.visible = False
        uav = record.uav_state
        if uav is not None and len(uav) >= 12:
            self.receiver.position = np.asarray(uav[9:12], float)
            self.receiver.wxyz = wxyz_from_matrix(euler_matrix(uav[6], uav[7], uav[8]))
        tip = record.probe_tip_m
        if tip is not None:
            t = np.asarray(tip, float)
            self.probe_tip.position = t
            if self.geometry is not None:
                R_TB = euler_matrix(
                    *(np.asarray(uav[6:9], float) if uav is not None else (0, 0, 0))
                )
                base = np.asarray(self.receiver.position, float) + R_TB @ self.geometry.nose_b
            else:
                base = np.asarray(self.receiver.position, float)
            self.probe.points = np.array([[base, t]], dtype=np.float32)
            self._trail.append(t)
            self.trail.points = polyline_segments(np.array(self._trail)).astype(np.float32)
        if record.reference_m is not None:
            self._ref.append(np.asarray(record.reference_m, float))
            self.reference.points = polyline_segments(np.array(self._ref)).astype(np.float32)
        if cam is not None:
            cl, cr = self.camera_centers(cam)
            self.frustums["left"].position = cl
            self.frustums["left"].wxyz = wxyz_from_matrix(cam.R_TC)
            self.frustums["right"].position = cr
            self.frustums["right"].wxyz = wxyz_from_matrix(cam.R_TC @ self._R_lr)

    def _update_measured(self, record: TickRecord, cam: CameraPose | None) -> None:
        pose = record.pose
        if pose is None or not pose.leds or cam is None:
            self.match_lines.visible = False
            self.measured_leds.visible = False
            self.measured_center.visible = False
            self.measured_ring.visible = False
            return
        xyz = np.array([led.xyz_mm for led in pose.leds], float)
        world = cam.to_tanker(xyz)
        colors = np.array([led_color(led.id) for led in pose.leds], dtype=np.uint8)
        self.measured_leds.points = world.astype(np.float32)
        self.measured_leds.colors = colors
        self.measured_leds.visible = True
        cl, cr = self.camera_centers(cam)
        segs = np.concatenate(
            [
                np.stack([np.broadcast_to(cl, world.shape), world], axis=1),
                np.stack([np.broadcast_to(cr, world.shape), world], axis=1),
            ]
        )
        self.match_lines.points = segs.astype(np.float32)
        self.match_lines.visible = True
        if pose.drogue is not None:
            c = cam.to_tanker(np.asarray(pose.drogue.center_mm))[0]
            n = cam.R_TC @ np.asarray(pose.drogue.normal, float)
            self.measured_center.position = c
            self.measured_center.visible = True
            self.measured_ring.points = circle_segments(
                c, frame_from_z(n), pose.drogue.radius_mm / 1000.0
            ).astype(np.float32)
            self.measured_ring.visible = True
        else:
            self.measured_center.visible = False
            self.measured_ring.visible = False

    def _update_images(self, record: TickRecord, raw: RawFrame | None) -> None:
        for side in ("left", "right"):
            img = None if raw is None else (raw.left_image if side == "left" else raw.right_image)
            if img is None:
                continue
            windows = None if raw is None else raw.image_windows_px
            rgb = annotate(
                img,
                record.pose,
                side,
                lock=record.lock,
                windows_px=None if windows is None else windows[side == "right"],
            )
            self.frustums[side].image = rgb
