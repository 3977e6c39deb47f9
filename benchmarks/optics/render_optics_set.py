"""Physically based stereo test set of a metal drogue, rendered with Mitsuba 3.

Run with a Python that has ``mitsuba`` (the project's optional extra ``render``)::

    PYTHONPATH=. python benchmarks/optics/render_optics_set.py --set projection_check \
        --out tests/data/optics/projection_check
    PYTHONPATH=. python benchmarks/optics/render_optics_set.py --set dev --out tests/data/optics/dev
    PYTHONPATH=. python benchmarks/optics/render_optics_set.py --set holdout \
        --out tests/data/optics/holdout
    PYTHONPATH=. python benchmarks/optics/render_optics_set.py --jitter   # MC-noise check
    PYTHONPATH=. python benchmarks/optics/render_optics_set.py --refresh-visibility \
        --out tests/data/optics/dev    # redo the ray casts of a set's manifest only

Camera path (see ``tests/sim/test_optics_set.py`` for the check against the calibration): each
camera is rendered as an ideal pinhole (Mitsuba ``perspective``: square pixels, focal fx, no
skew, no distortion) on a film with a margin around the real image; the real camera's skew,
fy ≠ fx and distortion are then applied by an inverse remap (for every real pixel: normalised
distorted coordinates with the skew removed, undistorted iteratively with OpenCV, looked up
bilinearly in the ideal render), followed by the optical blur (lens PSF; defocus disc or
motion line where the condition asks), the mono luminance or the RGGB mosaic, and storage as
16-bit PNG of round(DN × dn_scale).

Mitsuba's camera looks along its local +z with image x along local −x and image y along
local −y, so the left camera's ``to_world`` is diag(−1, −1, 1) and the right camera's is
Rᵀ·diag(−1, −1, 1) at −Rᵀ·T. The principal point is set by ``principal_point_offset`` =
(W/2 − (c + 0.5))/W (Mitsuba shifts the image by minus the offset; its pixel centres sit at
+0.5, OpenCV's at integers).

Scene units are mm, the left camera frame is the world frame (x right, y down, z forward).
Direct light only (``direct`` integrator; ``scalar_rgb``: the LLVM variants abort on this
machine's libLLVM). The whole frame is rendered at SPP_FRAME, by day the drogue's box again at
SPP_DROGUE, and the result is denoised (a cross-bilateral filter guided by a render of the
same geometry lit from the camera, see :func:`denoise`: the sky light on the fabric is the
noisy term, and it would dominate the PNG size); windows around every LED and the glint bolt
are then rendered at SPP_WINDOW and pasted in unfiltered, so that sampling noise does not
move the LED centroids (≈ 0.01 px, ``--jitter``). The LEDs sit in black housings with a
black bezel: a polished rim that can see the dome mirrors it right next to the LED blob.
Visibility and the visible dome's centroid come from ray casts (:func:`visibility`). Every
case is rendered in a child process (Mitsuba's memory grows with every render), one child at
a time.
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_DISABLE_JIT", "1")  # app.geometry's helpers run as plain Python

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from app.geometry.calibration import CameraIntrinsics, StereoCalibration  # noqa: E402
from app.sim.led_ring import LedRing, random_pose, ring_basis, ring_points  # noqa: E402
from app.sim.optics_set import CONDITIONS  # noqa: E402

RENDERER_VERSION = "optics-render-1"
VARIANT = "scalar_rgb"
CALIBRATION = REPO / "sample_data" / "calibration.json"

DN_SCALE = 2.0  # stored = round(DN × DN_SCALE), uint16 (×2, not ×4: keeps the sets ≤ 30 MB)
LUMA = np.array([0.299, 0.587, 0.114])
LED_RGB = np.array([0.05, 1.0, 0.15])
PSF_SIGMA_PX = 0.6  # lens blur (Gaussian), every case
SPP_FRAME = 4  # whole frame (multi-jittered)
SPP_WINDOW = 256  # LED and glint windows
SPP_FRAME_NIGHT = 4  # night frames are black apart from the LEDs (re-rendered in windows)
SPP_DROGUE = 16  # by day: the drogue's region (rim, canopy, struts)
# by day the low-spp frame is denoised (cross-bilateral filter guided by a render lit from the
# cameras, before the LED and glint windows are pasted): sampling noise of the sky light on the fabric would otherwise
# dominate the PNG size; the windows that matter are rendered at SPP_WINDOW and not filtered
DENOISE = {
    "radius_px": 3,
    "sigma_space_px": 1.5,
    "sigma_guide_rel": 0.06,
    "sigma_dn": 25.0,
    "hot_dn": 600.0,
}

BEZEL_RADIUS_D = 1.25  # LED bezel radius in LED diameters
# the housing's floor sits just in front of the rim's front face (−0.1 d), so that no part of
# the polished rim is visible inside the housing next to the dome
HOUSING_DEPTH_D = 0.06

RINGS = {
    "lab": {"radius_mm": 75.0, "count": 5, "led_diameter_mm": 5.0, "ranges_mm": (1000, 2500)},
    "flight": {"radius_mm": 305.0, "count": 5, "led_diameter_mm": 20.0, "ranges_mm": (2500, 10000)},
}
# "blind": a second held-back set, rendered once after the navigation it checks was frozen
# (2026-12-07) and evaluated once, never tuned on
SET_SEEDS = {"dev": 20250601, "holdout": 9173311, "blind": 20261207, "projection_check": 4242}
DEV_RANGES_MM = (1000.0, 1600.0, 2300.0, 3000.0, 4500.0, 6500.0, 9500.0)


INTEGRATOR = {"type": "direct"}  # direct light only (no caustics/fireflies off the polished rim)


def load_calibration(path: Path = CALIBRATION) -> StereoCalibration:
    return StereoCalibration.load(path)


# --------------------------------------------------------------------------------------
# cameras
# --------------------------------------------------------------------------------------
class IdealCamera:
    """The ideal pinhole Mitsuba renders for one real camera, and the remap to the real one."""

    def __init__(
        self,
        name: str,
        cam: CameraIntrinsics,
        rot_cw: np.ndarray,
        center: np.ndarray,
        size: tuple[int, int],
    ) -> None:
        self.name = name
        self.cam = cam
        self.rot_cw = np.asarray(rot_cw, dtype=np.float64)  # camera → world rotation
        self.center = np.asarray(center, dtype=np.float64)  # optical centre, world mm
        self.size = size
        self.f = cam.fx
        w, h = size
        self.map_x, self.map_y = self._ideal_coords(
            *np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        )
        lo = min(self.map_x.min(), self.map_y.min())
        hi_x, hi_y = self.map_x.max() - (w - 1), self.map_y.max() - (h - 1)
        self.margin = int(math.ceil(max(-lo, hi_x, hi_y, 0.0))) + 8
        self.map_x += self.margin
        self.map_y += self.margin
        self.film_size = (w + 2 * self.margin, h + 2 * self.margin)

    def _ideal_coords(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Real (distorted, skewed) pixels → ideal pinhole pixels (f = fx, same cx, cy)."""
        k = self.cam.K
        fx, fy, g, cx, cy = k[0, 0], k[1, 1], k[0, 1], k[0, 2], k[1, 2]
        yd = (v - cy) / fy
        xd = (u - cx - g * yd) / fx
        pts = np.stack([xd.ravel(), yd.ravel()], axis=1).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
        und = cv2.undistortPoints(
            pts, np.eye(3), self.cam.dist, R=np.eye(3), P=np.eye(3), criteria=crit
        )
        und = und.reshape(-1, 2)
        # the inverse is checked: distorting it again gives the pixel back to 1e-6 px
        redist, _ = cv2.projectPoints(
            np.column_stack([und, np.ones(len(und))]).reshape(-1, 1, 3),
            np.zeros(3),
            np.zeros(3),
            np.eye(3),
            self.cam.dist,
        )
        err = np.abs(redist.reshape(-1, 2) - pts.reshape(-1, 2)).max() * fx
        if err > 1e-6:
            raise RuntimeError(f"{self.name}: undistortion did not converge ({err:.2e} px)")
        mx = (fx * und[:, 0] + cx).reshape(u.shape)
        my = (fx * und[:, 1] + cy).reshape(u.shape)
        return mx, my

    def world_to_cam(self, xyz: np.ndarray) -> np.ndarray:
        return (np.asarray(xyz, dtype=np.float64).reshape(-1, 3) - self.center) @ self.rot_cw

    def project_ideal(self, xyz: np.ndarray) -> np.ndarray:
        """World points → ideal film pixels (OpenCV convention: pixel centres at integers)."""
        pc = self.world_to_cam(xyz)
        k = self.cam.K
        return np.column_stack(
            [
                self.f * pc[:, 0] / pc[:, 2] + k[0, 2] + self.margin,
                self.f * pc[:, 1] / pc[:, 2] + k[1, 2] + self.margin,
            ]
        )

    def project_real(self, xyz: np.ndarray) -> np.ndarray:
        """World points → real (distorted, skewed) pixels of the calibration."""
        pc = self.world_to_cam(xyz)
        xd, _ = cv2.projectPoints(
            pc.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.eye(3), self.cam.dist
        )
        xd = xd.reshape(-1, 2)
        return (np.column_stack([xd, np.ones(len(xd))]) @ self.cam.K.T)[:, :2]

    def sensor_dict(
        self, spp: int, crop: tuple[int, int, int, int] | None = None
    ) -> dict[str, Any]:
        import mitsuba as mi

        wf, hf = self.film_size
        k = self.cam.K
        cx, cy = k[0, 2] + self.margin, k[1, 2] + self.margin
        m = np.eye(4)
        m[:3, :3] = self.rot_cw @ np.diag([-1.0, -1.0, 1.0])
        m[:3, 3] = self.center
        film: dict[str, Any] = {
            "type": "hdrfilm",
            "width": wf,
            "height": hf,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
            "component_format": "float32",
        }
        if crop is not None:
            x0, y0, cw, ch = crop
            film.update(crop_offset_x=x0, crop_offset_y=y0, crop_width=cw, crop_height=ch)
        return {
            "type": "perspective",
            "fov_axis": "x",
            "fov": math.degrees(2.0 * math.atan(wf / (2.0 * self.f))),
            "principal_point_offset_x": (wf / 2.0 - (cx + 0.5)) / wf,
            "principal_point_offset_y": (hf / 2.0 - (cy + 0.5)) / hf,
            "near_clip": 5.0,
            "far_clip": 1.0e6,
            "to_world": mi.ScalarTransform4f(m.tolist()),
            "sampler": {"type": "multijitter", "sample_count": int(spp)},
            "film": film,
        }

    def remap(self, ideal: np.ndarray) -> np.ndarray:
        """Ideal render (film, H'×W'[×C]) → real image (bilinear, float64 coordinates)."""
        x0 = np.floor(self.map_x).astype(np.intp)
        y0 = np.floor(self.map_y).astype(np.intp)
        ax = self.map_x - x0
        ay = self.map_y - y0
        if ideal.ndim == 3:
            ax, ay = ax[..., None], ay[..., None]
        i00 = ideal[y0, x0]
        i01 = ideal[y0, x0 + 1]
        i10 = ideal[y0 + 1, x0]
        i11 = ideal[y0 + 1, x0 + 1]
        out = (1 - ay) * ((1 - ax) * i00 + ax * i01) + ay * ((1 - ax) * i10 + ax * i11)
        return np.asarray(out, dtype=np.float64)


def cameras(calib: StereoCalibration) -> tuple[IdealCamera, IdealCamera]:
    left = IdealCamera("left", calib.left, np.eye(3), np.zeros(3), calib.image_size)
    right = IdealCamera("right", calib.right, calib.R.T, -calib.R.T @ calib.T, calib.image_size)
    return left, right


# --------------------------------------------------------------------------------------
# image formation after the render
# --------------------------------------------------------------------------------------
def disc_kernel(radius_px: float, supersample: int = 9) -> np.ndarray:
    """Normalised point-symmetric disc (pill-box) kernel, anti-aliased by supersampling."""
    half = int(math.ceil(radius_px)) + 1
    s = (np.arange(supersample) + 0.5) / supersample - 0.5
    g = np.arange(-half, half + 1, dtype=np.float64)
    xx = (g[:, None] + s[None, :]).ravel()
    inside = (xx[None, :] ** 2 + xx[:, None] ** 2) <= radius_px**2
    n = len(g)
    k = inside.reshape(n, supersample, n, supersample).sum(axis=(1, 3)).astype(np.float64)
    k = 0.5 * (k + k[::-1, ::-1])
    return k / k.sum()


def motion_kernel(length_px: float, angle_deg: float, samples: int = 2001) -> np.ndarray:
    """Normalised linear motion kernel of ``length_px`` at ``angle_deg``, centred (mid-exposure)."""
    half = int(math.ceil(length_px / 2)) + 2
    n = 2 * half + 1
    k = np.zeros((n, n))
    t = np.linspace(-0.5, 0.5, samples) * length_px
    a = math.radians(angle_deg)
    xs, ys = half + t * math.cos(a), half + t * math.sin(a)
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    np.add.at(k, (y0, x0), (1 - fx) * (1 - fy))
    np.add.at(k, (y0, x0 + 1), fx * (1 - fy))
    np.add.at(k, (y0 + 1, x0), (1 - fx) * fy)
    np.add.at(k, (y0 + 1, x0 + 1), fx * fy)
    k = 0.5 * (k + k[::-1, ::-1])
    return k / k.sum()


def optical_blur(img: np.ndarray, blur: dict[str, Any]) -> np.ndarray:
    out = cv2.GaussianBlur(
        img.astype(np.float32), (0, 0), blur["psf_sigma_px"], borderType=cv2.BORDER_REFLECT
    )
    if blur.get("defocus_radius_px"):
        k = disc_kernel(blur["defocus_radius_px"]).astype(np.float32)
        out = cv2.filter2D(out, -1, k, borderType=cv2.BORDER_REFLECT)
    if blur.get("motion_length_px"):
        k = motion_kernel(blur["motion_length_px"], blur["motion_angle_deg"]).astype(np.float32)
        out = cv2.filter2D(out, -1, k, borderType=cv2.BORDER_REFLECT)
    return np.asarray(out, dtype=np.float64)


def mosaic_rggb(rgb: np.ndarray) -> np.ndarray:
    """RGGB mosaic of a linear RGB image: R (even, even), G (even, odd) and (odd, even),
    B (odd, odd)."""
    m = rgb[..., 1].copy()
    m[0::2, 0::2] = rgb[0::2, 0::2, 0]
    m[1::2, 1::2] = rgb[1::2, 1::2, 2]
    return m


def to_sensor_plane(real_rgb: np.ndarray, sensor: str) -> np.ndarray:
    if sensor == "mono":
        return np.asarray(real_rgb @ LUMA, dtype=np.float64)
    if sensor == "bayer_rggb":
        return mosaic_rggb(real_rgb)
    raise ValueError(sensor)


def store_png(path: Path, dn: np.ndarray, dn_scale: float = DN_SCALE) -> int:
    q = np.clip(np.round(dn * dn_scale), 0, 65535).astype(np.uint16)
    if not cv2.imwrite(
        str(path),
        q,
        [
            cv2.IMWRITE_PNG_COMPRESSION,
            9,
            cv2.IMWRITE_PNG_STRATEGY,
            cv2.IMWRITE_PNG_STRATEGY_FILTERED,
        ],
    ):
        raise OSError(f"could not write {path}")
    return path.stat().st_size


# --------------------------------------------------------------------------------------
# geometry helpers and meshes
# --------------------------------------------------------------------------------------
def unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def frame_to(n: np.ndarray) -> np.ndarray:
    """Rotation whose third column is ``n`` (local z → n)."""
    n = unit(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = unit(np.cross(a, n))
    t2 = np.cross(n, t1)
    return np.column_stack([t1, t2, n])


def write_ply(path: Path, verts: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> None:
    verts = np.asarray(verts, dtype="<f4").reshape(-1, 3)
    normals = np.asarray(normals, dtype="<f4").reshape(-1, 3)
    faces = np.asarray(faces, dtype="<i4").reshape(-1, 3)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(verts)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        f"element face {len(faces)}\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    vdata = np.concatenate([verts, normals], axis=1).astype("<f4").tobytes()
    fdt = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
    frec = np.empty(len(faces), dtype=fdt)
    frec["n"] = 3
    frec["i"] = faces
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vdata)
        fh.write(frec.tobytes())


def grid_faces(nu: int, nv: int, wrap_v: bool) -> np.ndarray:
    """Quads of a (nu periodic) × (nv, periodic if wrap_v) vertex grid, as triangles."""
    faces = []
    vmax = nv if wrap_v else nv - 1
    for i in range(nu):
        i1 = (i + 1) % nu
        for j in range(vmax):
            j1 = (j + 1) % nv
            a, b, c, d = i * nv + j, i1 * nv + j, i1 * nv + j1, i * nv + j1
            faces.append((a, b, c))
            faces.append((a, c, d))
    return np.array(faces)


def torus_mesh(center, normal, e_up, e_right, major, minor, nu=384, nv=32):
    phi = 2 * np.pi * np.arange(nu) / nu
    psi = 2 * np.pi * np.arange(nv) / nv
    P, Q = np.meshgrid(phi, psi, indexing="ij")
    radial = np.cos(P)[..., None] * e_up + np.sin(P)[..., None] * e_right
    nrm = np.cos(Q)[..., None] * radial + np.sin(Q)[..., None] * normal
    verts = center + major * radial + minor * nrm
    return verts.reshape(-1, 3), nrm.reshape(-1, 3), grid_faces(nu, nv, True)


def annulus_mesh(center, normal, r_in, r_out, nu=96):
    """Flat ring between radii r_in and r_out in the plane through ``center`` ⊥ ``normal``."""
    rot = frame_to(normal)
    phi = 2 * np.pi * np.arange(nu) / nu
    ring = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(nu)]) @ rot.T
    verts = np.concatenate([center + r_in * ring, center + r_out * ring])
    nrm = np.tile(unit(normal), (2 * nu, 1))
    faces = []
    for i in range(nu):
        j = (i + 1) % nu
        faces += [(i, j, nu + j), (i, nu + j, nu + i)]
    return verts, nrm, np.array(faces)


def frustum_mesh(center, normal, e_up, e_right, r0, r1, length, nu=192, nv=12):
    """Cone frustum from radius r0 at ``center`` to radius r1 at ``center − length·normal``;
    normals point inwards (towards the axis)."""
    phi = 2 * np.pi * np.arange(nu) / nu
    t = np.linspace(0.0, 1.0, nv)
    P, Tt = np.meshgrid(phi, t, indexing="ij")
    radial = np.cos(P)[..., None] * e_up + np.sin(P)[..., None] * e_right
    rad = (r0 + (r1 - r0) * Tt)[..., None]
    verts = center + rad * radial - (length * Tt)[..., None] * normal
    # surface normal of a cone: radial and axial parts
    slope = (r0 - r1) / length
    nrm = -radial - slope * normal
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    return verts.reshape(-1, 3), nrm.reshape(-1, 3), grid_faces(nu, nv, False)


# --------------------------------------------------------------------------------------
# case planning (no mitsuba needed)
# --------------------------------------------------------------------------------------
def _sun_direction(rng: np.random.Generator, glint: bool) -> np.ndarray:
    """Unit vector towards the sun (world: up is −y, the drogue is along +z)."""
    if glint:
        az, el = rng.uniform(-55, 55), rng.uniform(20, 50)
    else:
        az, el = rng.uniform(-125, 125), rng.uniform(12, 65)
    a, e = math.radians(az), math.radians(el)
    # az measured from "behind the cameras" (−z) towards +x
    return unit(np.array([math.sin(a) * math.cos(e), -math.sin(e), -math.cos(a) * math.cos(e)]))


def _ring_config(range_mm: float, rng: np.random.Generator) -> str:
    if range_mm < 2500.0:
        return "lab"
    if range_mm > 2500.0:
        return "flight"
    return "lab" if rng.uniform() < 0.5 else "flight"


def plan_case(
    name: str, condition: str, nominal_range_mm: float, rng: np.random.Generator, calib
) -> dict[str, Any]:
    config = _ring_config(nominal_range_mm, rng)
    rc = RINGS[config]
    ring = LedRing(rc["radius_mm"], rc["count"], rc["led_diameter_mm"])
    center, normal = random_pose(
        rng, nominal_range_mm, max_tilt_deg=30.0, calib=calib, ring=ring, margin_px=40.0
    )
    roll_deg = float(rng.uniform(-30.0, 30.0))
    sensor = "bayer_rggb" if condition.endswith("_bayer") else "mono"
    night = condition.startswith("night") or (condition == "defocus" and rng.uniform() < 0.5)
    lo, hi = rc["ranges_mm"]
    near = (nominal_range_mm - lo) / (hi - lo) < 0.45
    if night:
        led_peak = rng.uniform(270, 520) if near else rng.uniform(150, 250)
    else:
        led_peak = rng.uniform(240, 330) if near else rng.uniform(180, 250)
    blur: dict[str, Any] = {"psf_sigma_px": PSF_SIGMA_PX}
    if condition == "defocus":
        blur["defocus_radius_px"] = float(rng.uniform(1.5, 3.0))
    if condition == "motion":
        blur["motion_length_px"] = float(rng.uniform(3.0, 8.0))
        blur["motion_angle_deg"] = float(rng.uniform(0.0, 180.0))
    case: dict[str, Any] = {
        "name": name,
        "condition": condition,
        "sensor": sensor,
        "ring_config": config,
        "ring_radius_mm": ring.radius_mm,
        "led_count": ring.count,
        "led_diameter_mm": ring.led_diameter_mm,
        "phase_deg": ring.phase_deg,
        "nominal_range_mm": float(nominal_range_mm),
        "center_mm": [float(x) for x in center],
        "normal": [float(x) for x in normal],
        "roll_deg": roll_deg,
        "night": bool(night),
        "led_peak_target_dn": float(led_peak),
        "blur": blur,
        "seed": int(rng.integers(1, 2**31 - 1)),
        "tanker_distance_mm": float(rng.uniform(20000, 60000)),
        "tanker_dx_mm": float(rng.uniform(-4000, 4000)),
        "tanker_bottom_slope": float(rng.uniform(0.13, 0.2)),
    }
    if night:
        case["sky"] = {"kind": "night", "level_dn": float(rng.uniform(1.0, 5.0))}
        case["sun"] = None
    else:
        horizon = float(rng.uniform(165, 190))
        case["sky"] = {
            "kind": "day",
            "horizon_dn": horizon,
            "zenith_dn": float(rng.uniform(110, 135)),
            "ground_dn": float(rng.uniform(95, 125)),
        }
        glint = condition.startswith("glint")
        for _ in range(200):
            sun = _sun_direction(rng, glint)
            if not glint:
                break
            if _glint_ok(case, sun, ring):
                break
        case["sun"] = {
            "to_sun": [float(x) for x in sun],
            "irradiance": float(rng.uniform(900, 1300)),
        }
    if condition.startswith("glint"):
        case["glint_led_index"] = int(case.get("glint_led_index", rng.integers(0, ring.count)))
        case["glint_side"] = int(rng.choice([-1, 1]))
        case["glint_distance_led_d"] = float(rng.uniform(1.25, 1.55))
    if condition == "occluded2":
        case["occluded_pair"] = int(rng.integers(0, ring.count))
    return case


def _glint_ok(case: dict[str, Any], to_sun: np.ndarray, ring: LedRing) -> bool:
    n = np.asarray(case["normal"])
    c = np.asarray(case["center_mm"])
    v = unit(-c)  # towards the cameras (≈)
    h = unit(to_sun + v)
    return float(h @ n) > 0.55 and float(to_sun @ n) > 0.2


def plan_set(set_name: str, calib: StereoCalibration) -> list[dict[str, Any]]:
    rng = np.random.default_rng(SET_SEEDS[set_name])
    cases = []
    if set_name == "dev":
        for ci, cond in enumerate(CONDITIONS):
            for ri, r in enumerate(DEV_RANGES_MM):
                rr = float(r * rng.uniform(0.94, 1.06))
                lo, hi = (1000.0, 10000.0)
                rr = min(max(rr, lo), hi)
                if r < 2500 and rr >= 2500:
                    rr = 2450.0
                cases.append(plan_case(f"dev_{ci:02d}{ri:02d}_{cond}", cond, rr, rng, calib))
    elif set_name in ("holdout", "blind"):
        # holdout: 30 pairs; blind: 4 per condition (36 pairs); ranges log-uniform 1–10 m
        n_per = [4, 3, 4, 3, 4, 3, 3, 3, 3] if set_name == "holdout" else [4] * len(CONDITIONS)
        for ci, cond in enumerate(CONDITIONS):
            for ri in range(n_per[ci]):
                rr = float(math.exp(rng.uniform(math.log(1000.0), math.log(10000.0))))
                cases.append(plan_case(f"{set_name}_{ci:02d}{ri:02d}_{cond}", cond, rr, rng, calib))
    else:
        raise ValueError(set_name)
    return cases


# --------------------------------------------------------------------------------------
# scene
# --------------------------------------------------------------------------------------
def _rgb(v) -> dict[str, Any]:
    v = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))
    return {"type": "rgb", "value": [float(x) for x in v]}


def _diffuse(v, twosided: bool = False) -> dict[str, Any]:
    b = {"type": "diffuse", "reflectance": _rgb(v)}
    return {"type": "twosided", "bsdf": b} if twosided else b


def _metal(alpha: float) -> dict[str, Any]:
    return {"type": "roughconductor", "material": "Al", "alpha": alpha, "distribution": "ggx"}


def _to_world(m3: np.ndarray, t: np.ndarray, scale=(1.0, 1.0, 1.0)):
    import mitsuba as mi

    m = np.eye(4)
    m[:3, :3] = np.asarray(m3) @ np.diag(scale)
    m[:3, 3] = t
    return mi.ScalarTransform4f(m.tolist())


def _sky_bitmap(sky: dict[str, Any], h: int = 128, w: int = 16):
    import mitsuba as mi

    theta = (np.arange(h) + 0.5) / h * np.pi  # from local +y (= world up)
    elev = 0.5 * np.pi - theta
    if sky["kind"] == "night":
        lum = np.full(h, sky["level_dn"])
        tint = np.array([0.85, 0.95, 1.25])
    else:
        hz, zn, gd = sky["horizon_dn"], sky["zenith_dn"], sky["ground_dn"]
        s = np.abs(np.sin(elev))
        lum = np.where(elev >= 0, hz - (hz - zn) * s**0.6, hz - (hz - gd) * s**0.4)
        tint = np.array([0.80, 0.97, 1.20])
    tint = tint / float(tint @ LUMA)
    img = (lum[:, None, None] * tint[None, None, :]) * np.ones((h, w, 3))
    return mi.Bitmap(img.astype(np.float32))


def led_geometry(case: dict[str, Any]) -> dict[str, Any]:
    """Positions of everything on the drogue (mm, world)."""
    ring = LedRing(
        case["ring_radius_mm"], case["led_count"], case["led_diameter_mm"], case["phase_deg"]
    )
    c = np.asarray(case["center_mm"])
    n = np.asarray(case["normal"])
    e_up, e_right = ring_basis(n)
    roll = math.radians(case["roll_deg"])
    leds = ring_points(c, n, ring, roll)
    d, r = ring.led_diameter_mm, ring.radius_mm
    rim_major, rim_minor = r + d, 0.8 * d
    rim_center = c - n * (rim_minor + 0.1 * d)
    th = math.radians(ring.phase_deg) + roll + np.arange(ring.count) * 2 * np.pi / ring.count

    def on_rim_front(angle: float) -> np.ndarray:
        return (
            rim_center
            + rim_major * (math.cos(angle) * e_up + math.sin(angle) * e_right)
            + n * rim_minor
        )

    bolts = [on_rim_front(a + np.pi / ring.count) for a in th]
    glint_bolt = None
    if "glint_led_index" in case:
        j = case["glint_led_index"]
        target = case["glint_distance_led_d"] * d
        # angle offset along the rim so that the bolt centre is `target` from LED j's centre
        lo, hi = 0.0, math.pi / ring.count
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            dist = np.linalg.norm(on_rim_front(th[j] + case["glint_side"] * mid) - leds[j])
            lo, hi = (mid, hi) if dist < target else (lo, mid)
        glint_bolt = on_rim_front(th[j] + case["glint_side"] * 0.5 * (lo + hi))
    return {
        "ring": ring,
        "c": c,
        "n": n,
        "e_up": e_up,
        "e_right": e_right,
        "leds": leds,
        "d": d,
        "r": r,
        "rim_major": rim_major,
        "rim_minor": rim_minor,
        "rim_center": rim_center,
        "bolts": bolts,
        "bolt_radius": 0.4 * d,
        "glint_bolt": glint_bolt,
        "led_angles": th,
    }


def probe_geometry(case: dict[str, Any], g: dict[str, Any]) -> dict[str, Any]:
    c, n, r, d = g["c"], g["n"], g["r"], g["d"]
    rad = 8.0 if case["ring_config"] == "lab" else 45.0
    if case["condition"] == "occluded2":
        j = case["occluded_pair"]
        k = (j + 1) % case["led_count"]
        delta = 0.45 * r
        q = [g["leds"][i] * (1.0 - delta / np.linalg.norm(g["leds"][i])) for i in (j, k)]
        a = unit(q[1] - q[0])
        tip = q[0] - a * (rad + 0.8 * d)
        tail = q[1] + a * 3.0 * float(np.linalg.norm(c))
    else:
        down = -g["e_up"]
        tip = c + down * (g["rim_major"] + g["rim_minor"] + 2.5 * rad) + n * 0.4 * r
        z0 = 0.3 * c[2]
        tail = np.array([0.3 * c[0], 0.45 * z0 + max(c[1], 0.0), z0])
    return {"radius": rad, "tip": tip, "tail": tail}


def build_scene_dict(case: dict[str, Any], guide=None) -> dict[str, Any]:
    """The case's scene; with ``guide`` (a camera) the denoiser's guide scene for that camera
    instead: the same geometry, no emitters but a point light at the camera's centre."""
    g = led_geometry(case)
    c, n, e_up, e_right = g["c"], g["n"], g["e_up"], g["e_right"]
    d, r = g["d"], g["r"]
    rot_n = frame_to(n)
    tmp = Path(case["_tmpdir"])
    scene: dict[str, Any] = {"type": "scene", "integrator": INTEGRATOR}
    gain_mono = float(LED_RGB @ LUMA)
    led_scale = case["led_peak_target_dn"] / (gain_mono if case["sensor"] == "mono" else 1.0)
    black = _diffuse(0.03)
    for k, p in enumerate(g["leds"]):
        scene[f"led_{k}"] = {
            "type": "sphere",
            "center": [float(x) for x in p],
            "radius": 0.5 * d,
            "bsdf": _diffuse(0.03),
            "emitter": {
                "type": "area",
                "radiance": _rgb(led_scale * LED_RGB),
                # emitter selection: by day the LEDs hardly light anything (sun and sky do)
                "sampling_weight": 1.0 if case["night"] else 1e-3,
            },
        }
        if guide is not None:
            del scene[f"led_{k}"]["emitter"]
        scene[f"housing_{k}"] = {
            "type": "cylinder",
            "p0": [float(x) for x in p - n * HOUSING_DEPTH_D * d],
            "p1": [float(x) for x in p + n * 0.03 * d],
            "radius": 0.62 * d,
            "bsdf": black,
        }
        scene[f"housingbase_{k}"] = {
            "type": "disk",
            "to_world": _to_world(rot_n, p - n * HOUSING_DEPTH_D * d, (0.62 * d,) * 3),
            "bsdf": black,
        }
        # black bezel (an annulus) around the housing's lip: without it the polished rim next
        # to the LED shows the dome's mirror image, which merges with the LED blob (up to
        # 0.9 px); it leaves the dome's visible part as the housing alone does
        v, nr, f = annulus_mesh(p + n * 0.03 * d, n, 0.62 * d, BEZEL_RADIUS_D * d)
        write_ply(tmp / f"bezel_{k}.ply", v, nr, f)
        scene[f"bezel_{k}"] = {
            "type": "ply",
            "filename": str(tmp / f"bezel_{k}.ply"),
            "bsdf": black,
        }
    # polished rim (torus) and bolts
    v, nr, f = torus_mesh(g["rim_center"], n, e_up, e_right, g["rim_major"], g["rim_minor"])
    write_ply(tmp / "rim.ply", v, nr, f)
    scene["rim"] = {"type": "ply", "filename": str(tmp / "rim.ply"), "bsdf": _metal(0.05)}
    for i, b in enumerate(g["bolts"]):
        scene[f"bolt_{i}"] = {
            "type": "sphere",
            "center": [float(x) for x in b],
            "radius": g["bolt_radius"],
            "bsdf": _metal(0.05),
        }
    if g["glint_bolt"] is not None:
        scene["bolt_glint"] = {
            "type": "sphere",
            "center": [float(x) for x in g["glint_bolt"]],
            "radius": g["bolt_radius"],
            "bsdf": _metal(0.05),
        }
    # canopy (fabric funnel behind the rim), struts, coupling, hose
    r0 = g["rim_major"] - 0.3 * g["rim_minor"]
    r1 = 0.22 * r
    length = 2.5 * r
    top = g["rim_center"]
    v, nr, f = frustum_mesh(top, n, e_up, e_right, r0, r1, length)
    write_ply(tmp / "canopy.ply", v, nr, f)
    scene["canopy"] = {
        "type": "ply",
        "filename": str(tmp / "canopy.ply"),
        "bsdf": _diffuse([0.46, 0.43, 0.38], twosided=True),
    }
    back = top - n * length
    sr = 0.018 * r
    for i in range(8):
        a = 2 * np.pi * (i + 0.5) / 8 + math.radians(case["roll_deg"])
        u = math.cos(a) * e_up + math.sin(a) * e_right
        scene[f"strut_{i}"] = {
            "type": "cylinder",
            "p0": [float(x) for x in top + (r0 - 1.6 * sr) * u],
            "p1": [float(x) for x in back + (r1 - 1.6 * sr) * u],
            "radius": sr,
            "bsdf": _diffuse(0.12),
        }
    scene["coupling"] = {
        "type": "cylinder",
        "p0": [float(x) for x in back],
        "p1": [float(x) for x in back - n * 0.4 * r],
        "radius": r1,
        "bsdf": _metal(0.25),
    }
    scene["coupling_face"] = {
        "type": "disk",
        "to_world": _to_world(rot_n, back - n * 0.05 * r, (r1,) * 3),
        "bsdf": _diffuse(0.06),
    }
    # tanker: fuselage and wing, far behind the drogue, in the upper part of the image
    zt = c[2] + case["tanker_distance_mm"]
    yb = -case["tanker_bottom_slope"] * zt
    xt = c[0] + case["tanker_dx_mm"]
    fus_half = np.array([1900.0, 1900.0, 22000.0])
    fus_c = np.array([xt, yb - fus_half[1], zt + fus_half[2]])
    wing_half = np.array([19000.0, 350.0, 2600.0])
    wing_c = np.array([xt, yb - 2.6 * fus_half[1], zt + 14000.0])
    grey = _diffuse([0.50, 0.50, 0.53])
    scene["tanker_fuselage"] = {
        "type": "cube",
        "to_world": _to_world(np.eye(3), fus_c, fus_half),
        "bsdf": grey,
    }
    scene["tanker_wing"] = {
        "type": "cube",
        "to_world": _to_world(np.eye(3), wing_c, wing_half),
        "bsdf": grey,
    }
    hose_end = np.array([xt, yb, zt + 3000.0])
    hose_start = back - n * 0.4 * r
    scene["hose"] = {
        "type": "cylinder",
        "p0": [float(x) for x in hose_start],
        "p1": [float(x) for x in hose_end],
        "radius": 0.12 * r,
        "bsdf": _diffuse(0.15),
    }
    # probe from the receiver side
    pg = probe_geometry(case, g)
    scene["probe"] = {
        "type": "cylinder",
        "p0": [float(x) for x in pg["tail"]],
        "p1": [float(x) for x in pg["tip"]],
        "radius": pg["radius"],
        "bsdf": _diffuse([0.33, 0.33, 0.35]),
    }
    scene["probe_tip"] = {
        "type": "sphere",
        "center": [float(x) for x in pg["tip"]],
        "radius": pg["radius"],
        "bsdf": _metal(0.08),
    }
    # light
    if guide is not None:
        scene["guide_light"] = {
            "type": "point",
            "position": [float(x) for x in guide.center],
            "intensity": _rgb(1.0e6),
        }
        return scene
    scene["sky"] = {
        "type": "envmap",
        "bitmap": _sky_bitmap(case["sky"]),
        "to_world": _to_world(np.diag([1.0, -1.0, -1.0]), np.zeros(3)),
        # emitter selection: the sun (deterministic shadow rays) almost always; the sky is
        # reached by BSDF sampling (MIS keeps it unbiased)
        "sampling_weight": 0.05 if case["night"] else 0.01,
    }
    if case["sun"] is not None:
        to_sun = np.asarray(case["sun"]["to_sun"])
        scene["sun"] = {
            "type": "directional",
            "direction": [float(x) for x in -to_sun],
            "irradiance": _rgb(case["sun"]["irradiance"] * np.array([1.0, 0.97, 0.92])),
            "sampling_weight": 1.0,
        }
    return scene


# --------------------------------------------------------------------------------------
# rendering
# --------------------------------------------------------------------------------------
def denoise(rgb: np.ndarray, guide: np.ndarray) -> np.ndarray:
    """Cross-bilateral filter of a low-spp render, guided by a nearly noise-free render of the
    same geometry lit only by a point light at the camera (``guide``: its luminance shows
    every surface and orientation edge, and no sky light): sampling noise (mostly the sky
    light on the fabric) is averaged over neighbours of similar guide value and similar
    rendered value (within a few noise σ), so geometric and shadow edges stay. Pixels the guide does not light (sky) and pixels above DENOISE["hot_dn"] (glints)
    are kept as rendered and never used as neighbours. Returns H×W×3."""
    p = DENOISE
    rgb = rgb.astype(np.float32)
    g = (guide @ LUMA).astype(np.float32)
    valid = (g > 0) & (rgb @ LUMA.astype(np.float32) < p["hot_dn"])
    rows = np.flatnonzero(valid.any(axis=1))
    out = rgb.copy()
    if rows.size == 0:
        return out.astype(np.float64)
    r = p["radius_px"]
    y0, y1 = max(rows[0] - r, 0), min(rows[-1] + r + 1, rgb.shape[0])
    sl = slice(y0, y1)
    h, w = y1 - y0, rgb.shape[1]

    def pad(a: np.ndarray) -> np.ndarray:
        widths = ((r, r), (r, r)) + ((0, 0),) * (a.ndim - 2)
        return np.pad(a[sl], widths, mode="edge")

    gmax = float(g.max())
    prgb, pg = pad(rgb), pad(np.where(valid, g, np.float32(-1e3 * gmax)))
    lum = rgb @ LUMA.astype(np.float32)
    plum, l0 = pad(lum), lum[sl]
    inv_l = np.float32(1.0 / p["sigma_dn"])
    g0 = g[sl]
    floor = np.float32(1e-6 * gmax)
    inv = np.float32(1.0) / (np.float32(p["sigma_guide_rel"]) * np.maximum(g0, floor))
    num = np.zeros((h, w, 3), np.float32)
    den = np.zeros((h, w), np.float32)
    ks = 1.0 / (2 * p["sigma_space_px"] ** 2)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            ys, xs = slice(r + dy, r + dy + h), slice(r + dx, r + dx + w)
            e = np.clip((pg[ys, xs] - g0) * inv, -20.0, 20.0)
            e *= e
            dl = (plum[ys, xs] - l0) * inv_l  # keeps the sun's shadow edges
            e += dl * dl
            e *= -0.5
            e -= np.float32(ks * (dx * dx + dy * dy))
            wgt = np.exp(np.maximum(e, np.float32(-60.0)))
            num += wgt[..., None] * prgb[ys, xs]
            den += wgt
    v = valid[sl]
    sub = out[sl]
    sub[v] = num[v] / den[v][:, None]
    return out.astype(np.float64)


def render_rgb(scene, cam: IdealCamera, spp: int, seed: int, crop=None) -> np.ndarray:
    import mitsuba as mi

    sensor = mi.load_dict(cam.sensor_dict(spp, crop))
    img = mi.render(scene, sensor=sensor, spp=spp, seed=seed)
    return np.array(img, dtype=np.float64)[..., :3]


def render_frame(scene, cam: IdealCamera, spp: int, seed: int, drogue_box=None) -> np.ndarray:
    """The whole film at ``spp``; by day the drogue's box again at SPP_DROGUE."""
    full = render_rgb(scene, cam, spp, seed)
    if drogue_box is not None:
        x0, y0, cw, ch = drogue_box
        full[y0 : y0 + ch, x0 : x0 + cw] = render_rgb(
            scene, cam, SPP_DROGUE, seed + 500, drogue_box
        )
    return full


def window_for(
    cam: IdealCamera, xyz: np.ndarray, radius_mm: float, pad_px: float
) -> tuple[int, int, int, int]:
    px = cam.project_ideal(xyz)[0]
    depth = cam.world_to_cam(xyz)[0, 2]
    half = int(math.ceil(cam.f * radius_mm / depth + pad_px))
    wf, hf = cam.film_size
    x0, y0 = max(int(round(px[0])) - half, 0), max(int(round(px[1])) - half, 0)
    x1, y1 = min(int(round(px[0])) + half + 1, wf), min(int(round(px[1])) + half + 1, hf)
    return x0, y0, x1 - x0, y1 - y0


def visibility(scene, cam: IdealCamera, g: dict[str, Any], k: int, n_grid: int = 64):
    """Ray-cast LED k from the camera centre over a square grid (``n_grid`` across) of its
    silhouette disc.

    Returns (fraction of rays whose first hit is LED k's dome or its own housing or bezel,
    i.e. not hidden by anything else; the real-image centroid of the rays that hit the dome,
    i.e. where a uniform-radiance dome's blob centre lies, px, or None)."""
    import mitsuba as mi

    p = g["leds"][k]
    rho = 0.5 * g["d"] * 0.999
    w = unit(p - cam.center)
    b = frame_to(w)
    t = (np.arange(n_grid) + 0.5) / n_grid * 2.0 - 1.0
    aa, bb = np.meshgrid(t, t)
    inside = aa**2 + bb**2 <= 1.0
    own = {f"led_{k}", f"housing_{k}", f"housingbase_{k}", f"bezel_{k}"}
    ok = 0
    hits = []
    origin = mi.Point3f(*cam.center.tolist())
    for a, c in zip(aa[inside], bb[inside], strict=True):
        q = p + rho * (a * b[:, 0] + c * b[:, 1])
        dvec = unit(q - cam.center)
        si = scene.ray_intersect(mi.Ray3f(origin, mi.Vector3f(*dvec.tolist())))
        if si.is_valid():
            sid = si.shape.id()
            # Mitsuba merges meshes sharing a BSDF (the bezels lose their ids): a hit inside
            # the LED's own housing and bezel volume counts as the LED's own
            rel = np.array([si.p[0], si.p[1], si.p[2]]) - p
            axial = float(rel @ g["n"])
            radial = float(np.linalg.norm(rel - axial * g["n"]))
            in_mount = radial <= (BEZEL_RADIUS_D + 1e-3) * g["d"] and (
                -(HOUSING_DEPTH_D + 0.01) * g["d"] <= axial <= 0.04 * g["d"]
            )
            if sid in own or in_mount:
                ok += 1
            if sid == f"led_{k}":
                hits.append(q)
    cen = cam.project_real(np.array(hits)).mean(axis=0).tolist() if hits else None
    return ok / int(inside.sum()), cen


def refresh_visibility(out_dir: Path) -> None:
    """Recompute every case's ray-cast visibility and dome centroids in a set's manifest (the
    images are not touched)."""
    import mitsuba as mi

    mi.set_variant(VARIANT)
    mi.set_log_level(mi.LogLevel.Error)
    cams = cameras(load_calibration())
    path = out_dir / "manifest.json"
    man = json.loads(path.read_text())
    for rec in man["cases"]:
        with tempfile.TemporaryDirectory() as tmpd:
            case = dict(rec, _tmpdir=tmpd)
            scene = mi.load_dict(build_scene_dict(case))
            g = led_geometry(case)
            truth = rec["truth"]
            for cam in cams:
                vv = [visibility(scene, cam, g, k) for k in range(len(g["leds"]))]
                truth["led_visible_fraction"][cam.name] = [v[0] for v in vv]
                truth["led_dome_centroid_px"][cam.name] = [v[1] for v in vv]
            frac = truth["led_visible_fraction"]
            truth["led_visible"] = [
                bool(a >= 1.0 and b >= 1.0)
                for a, b in zip(frac["left"], frac["right"], strict=True)
            ]
            del scene
    path.write_text(json.dumps(man, indent=1) + "\n")
    print(f"{path}: visibility refreshed for {len(man['cases'])} cases")


def render_case(case: dict[str, Any], out_dir: Path, cams) -> dict[str, Any]:
    import mitsuba as mi

    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmpd:
        case = dict(case, _tmpdir=tmpd)
        scene = mi.load_dict(build_scene_dict(case))
        guides = (
            [] if case["night"] else [mi.load_dict(build_scene_dict(case, guide=c)) for c in cams]
        )
        g = led_geometry(case)
        seed = case["seed"]
        spp_frame = SPP_FRAME_NIGHT if case["night"] else SPP_FRAME
        images: dict[str, str] = {}
        stats: dict[str, Any] = {"led_peak_dn": {}, "glint_peak_dn": {}, "png_bytes": {}}
        vis: dict[str, list[float]] = {}
        dome_px: dict[str, list[Any]] = {}
        led_px: dict[str, list[list[float]]] = {}
        timing = {"frame_s": 0.0, "windows_s": 0.0, "post_s": 0.0, "visibility_s": 0.0}
        for ci, cam in enumerate(cams):
            t1 = time.time()
            if case["night"]:
                full = render_frame(scene, cam, spp_frame, seed * 2 + ci)
            else:
                box = window_for(cam, g["c"][None], g["rim_major"] + g["rim_minor"], 6.0)
                full = render_frame(scene, cam, spp_frame, seed * 2 + ci, box)
                guide = render_frame(guides[ci], cam, spp_frame, seed * 2 + ci, box)
                full = denoise(full, guide)
            t2 = time.time()
            timing["frame_s"] += t2 - t1
            windows = [
                window_for(cam, g["leds"][k : k + 1], 0.62 * g["d"], 8.0)
                for k in range(len(g["leds"]))
            ]
            if g["glint_bolt"] is not None:
                windows.append(window_for(cam, g["glint_bolt"][None], g["bolt_radius"], 8.0))
            for wi, (x0, y0, cw, ch) in enumerate(windows):
                full[y0 : y0 + ch, x0 : x0 + cw] = render_rgb(
                    scene, cam, SPP_WINDOW, seed * 2 + ci + 1000 * (wi + 1), (x0, y0, cw, ch)
                )
            t3 = time.time()
            timing["windows_s"] += t3 - t2
            real = optical_blur(cam.remap(full), case["blur"])
            plane = to_sensor_plane(real, case["sensor"])
            fname = f"{case['name']}_{cam.name}.png"
            stats["png_bytes"][cam.name] = store_png(out_dir / fname, plane)
            images[cam.name] = fname
            px = cam.project_real(g["leds"])
            led_px[cam.name] = px.tolist()
            stats["led_peak_dn"][cam.name] = [
                _peak(
                    plane,
                    p,
                    max(0.35 * cam.f * g["d"] / cam.world_to_cam(x[None])[0, 2], 1.5),
                    case["sensor"],
                )
                for p, x in zip(px, g["leds"], strict=True)
            ]
            if g["glint_bolt"] is not None:
                bp = cam.project_real(g["glint_bolt"][None])[0]
                stats["glint_peak_dn"][cam.name] = _peak(
                    plane,
                    bp,
                    cam.f * g["bolt_radius"] / cam.world_to_cam(g["glint_bolt"][None])[0, 2] + 1.5,
                    "mono",
                )
            t4 = time.time()
            timing["post_s"] += t4 - t3
            vv = [visibility(scene, cam, g, k) for k in range(len(g["leds"]))]
            vis[cam.name] = [v[0] for v in vv]
            dome_px[cam.name] = [v[1] for v in vv]
            timing["visibility_s"] += time.time() - t4
            lo = np.percentile(plane, [1, 50, 99])
            stats.setdefault("percentile_1_50_99_dn", {})[cam.name] = [float(x) for x in lo]
        del scene
    led_visible = [
        bool(vis["left"][k] >= 1.0 and vis["right"][k] >= 1.0) for k in range(len(g["leds"]))
    ]
    pg = probe_geometry(case, g)
    rec = {k: v for k, v in case.items() if not k.startswith("_")}
    rec.update(
        {
            "images": images,
            "truth": {
                "led_xyz_mm": g["leds"].tolist(),
                "led_ids": list(range(1, len(g["leds"]) + 1)),
                "led_visible": led_visible,
                "led_visible_fraction": vis,
                # centroid of the visible (unhidden) dome surface in the real image: the
                # housing hides part of the dome when seen obliquely, so a uniform blob's
                # centre lies slightly off the projected LED centre (led_px)
                "led_dome_centroid_px": dome_px,
                "center_mm": g["c"].tolist(),
                "normal": g["n"].tolist(),
                "range_mm": float(np.linalg.norm(g["c"])),
                "roll_deg": case["roll_deg"],
                "led_px": led_px,
                "glint_bolt_xyz_mm": None if g["glint_bolt"] is None else g["glint_bolt"].tolist(),
                "glint_bolt_distance_mm": None
                if g["glint_bolt"] is None
                else float(np.linalg.norm(g["glint_bolt"] - g["leds"][case["glint_led_index"]])),
                "probe_tip_mm": pg["tip"].tolist(),
                "probe_radius_mm": pg["radius"],
            },
            "stats": stats,
            "render": {
                "spp_frame": spp_frame,
                "spp_window": SPP_WINDOW,
                "seed": seed,
                "time_s": round(time.time() - t0, 2),
                **{k: round(v, 2) for k, v in timing.items()},
            },
        }
    )
    return rec


def _peak(plane: np.ndarray, px: np.ndarray, radius_px: float, sensor: str) -> float:
    """Largest stored DN within ``radius_px`` of ``px`` (green sites only for a mosaic)."""
    h, w = plane.shape
    rr = int(math.ceil(radius_px)) + 1
    x0, x1 = max(int(round(px[0])) - rr, 0), min(int(round(px[0])) + rr + 1, w)
    y0, y1 = max(int(round(px[1])) - rr, 0), min(int(round(px[1])) + rr + 1, h)
    yy, xx = np.mgrid[y0:y1, x0:x1]
    sel = np.hypot(xx - px[0], yy - px[1]) <= radius_px
    if sensor == "bayer_rggb":
        sel &= (yy + xx) % 2 == 1
    win = plane[y0:y1, x0:x1][sel]
    return round(float(win.max()), 2) if win.size else 0.0


# --------------------------------------------------------------------------------------
# projection check: tiny bright emitters at known points, same camera + remap path
# --------------------------------------------------------------------------------------
PC_DEPTHS = ((1000.0, 0.5), (3000.0, 1.5))  # (depth mm, sphere radius mm)
PC_RADIANCE_DN = 2000.0


def projection_points(calib: StereoCalibration, cams) -> list[dict[str, Any]]:
    w, h = calib.image_size
    inset = 70.0
    targets = [
        (inset, inset),
        (w - 1 - inset, inset),
        (inset, h - 1 - inset),
        (w - 1 - inset, h - 1 - inset),
        ((w - 1) / 2, (h - 1) / 2),
    ]
    pts = []
    for depth, rad in PC_DEPTHS:
        for cam in cams:
            for ti, (u, v) in enumerate(targets):
                # offset the two depths a little so their emitters do not coincide in the image
                du = 0.0 if depth < 2000 else 45.0
                uv = np.array(
                    [[u + du * (1 if ti % 2 == 0 else -1), v + (0 if depth < 2000 else 35.0)]]
                )
                und = cv2.undistortPoints(
                    _unskew(cam.cam, uv).reshape(-1, 1, 2),
                    np.eye(3),
                    cam.cam.dist,
                    R=np.eye(3),
                    P=np.eye(3),
                    criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15),
                ).reshape(2)
                xc = np.array([und[0], und[1], 1.0]) * depth
                xw = cam.rot_cw @ xc + cam.center
                pts.append(
                    {
                        "xyz_mm": xw.tolist(),
                        "radius_mm": rad,
                        "target_camera": cam.name,
                        "depth_mm": depth,
                    }
                )
    return pts


def _unskew(cam: CameraIntrinsics, uv: np.ndarray) -> np.ndarray:
    k = cam.K
    yd = (uv[:, 1] - k[1, 2]) / k[1, 1]
    xd = (uv[:, 0] - k[0, 2] - k[0, 1] * yd) / k[0, 0]
    return np.column_stack([xd, yd])


def render_projection_check(out_dir: Path) -> dict[str, Any]:
    import mitsuba as mi

    mi.set_variant(VARIANT)
    calib = load_calibration()
    cams = cameras(calib)
    pts = projection_points(calib, cams)
    scene_d: dict[str, Any] = {"type": "scene", "integrator": {"type": "direct"}}
    for i, p in enumerate(pts):
        scene_d[f"pt_{i}"] = {
            "type": "sphere",
            "center": p["xyz_mm"],
            "radius": p["radius_mm"],
            "emitter": {"type": "area", "radiance": _rgb(PC_RADIANCE_DN)},
        }
    scene = mi.load_dict(scene_d)
    blur = {"psf_sigma_px": PSF_SIGMA_PX}
    t0 = time.time()
    images = {}
    w, h = calib.image_size
    for ci, cam in enumerate(cams):
        full = render_rgb(scene, cam, 4, 11 + ci)
        for i, p in enumerate(pts):
            xyz = np.asarray(p["xyz_mm"])[None]
            if cam.world_to_cam(xyz)[0, 2] <= 0:
                continue
            x0, y0, cw, ch = window_for(cam, xyz, p["radius_mm"], 8.0)
            if cw <= 0 or ch <= 0 or x0 >= cam.film_size[0] or y0 >= cam.film_size[1]:
                continue
            full[y0 : y0 + ch, x0 : x0 + cw] = render_rgb(
                scene, cam, 1024, 100 + 7 * i + ci, (x0, y0, cw, ch)
            )
        plane = to_sensor_plane(optical_blur(cam.remap(full), blur), "mono")
        fname = f"projection_{cam.name}.png"
        store_png(out_dir / fname, plane)
        images[cam.name] = fname
        for p in pts:
            uv = cam.project_real(np.asarray(p["xyz_mm"])[None])[0]
            inside = bool(10 <= uv[0] <= w - 11 and 10 <= uv[1] <= h - 11)
            p.setdefault("px", {})[cam.name] = uv.tolist() if inside else None
    return {
        "renderer_version": RENDERER_VERSION,
        "mitsuba_version": mi.__version__,
        "variant": VARIANT,
        "calibration": "sample_data/calibration.json",
        "calibration_data": calib.to_dict(),
        "dn_scale": DN_SCALE,
        "storage": "uint16 PNG = round(DN * dn_scale); mono = 0.299 R + 0.587 G + 0.114 B (linear)",
        "psf_sigma_px": PSF_SIGMA_PX,
        "spp_frame": 4,
        "spp_window": 1024,
        "radiance_dn": PC_RADIANCE_DN,
        "images": images,
        "points": pts,
        "margins_px": {cam.name: cam.margin for cam in cams},
        "render_time_s": round(time.time() - t0, 1),
    }


# --------------------------------------------------------------------------------------
# MC-noise check: one LED window rendered with two seeds
# --------------------------------------------------------------------------------------
def jitter_check(n_seeds: int = 3) -> dict[str, Any]:
    import mitsuba as mi

    mi.set_variant(VARIANT)
    calib = load_calibration()
    cams = cameras(calib)
    plan = plan_set("dev", calib)
    out: dict[str, Any] = {}
    for name_part in ("sun_mono", "night_mono"):
        case = next(
            c
            for c in plan
            if c["condition"] == name_part
            and c["ring_config"] == "flight"
            and c["nominal_range_mm"] > 8000
        )
        with tempfile.TemporaryDirectory() as tmpd:
            case = dict(case, _tmpdir=tmpd)
            scene = mi.load_dict(build_scene_dict(case))
            g = led_geometry(case)
            cam = cams[0]
            win = window_for(cam, g["leds"][0:1], 0.62 * g["d"], 10.0)
            p = cam.project_ideal(g["leds"][0:1])[0] - np.array(win[:2])
            for spp in (SPP_FRAME, SPP_WINDOW):
                cents = []
                for s in range(n_seeds):
                    img = render_rgb(scene, cam, spp, 555 + s, win) @ LUMA
                    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), PSF_SIGMA_PX).astype(
                        np.float64
                    )
                    cents.append(
                        _centroid(
                            img,
                            p,
                            0.5 * g["d"] * cam.f / cam.world_to_cam(g["leds"][0:1])[0, 2] + 2.5,
                        )
                    )
                cents = np.array(cents)
                dev = np.linalg.norm(cents - cents.mean(axis=0), axis=1)
                out[f"{name_part}_{case['name']}_spp{spp}"] = {
                    "centroids": cents.tolist(),
                    "max_pairwise_px": float(
                        max(np.linalg.norm(a - b) for a in cents for b in cents)
                    ),
                    "rms_about_mean_px": float(np.sqrt(np.mean(dev**2))),
                    "bias_vs_ideal_projection_px": (cents.mean(axis=0) - p).tolist(),
                }
    return out


def _centroid(img: np.ndarray, p: np.ndarray, radius: float) -> np.ndarray:
    """Centroid within ``radius`` of ``p`` above a plane fitted to a ring around it."""
    yy, xx = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    rr = np.hypot(xx - p[0], yy - p[1])
    ring = (rr > radius + 1.0) & (rr < radius + 4.0)
    a = np.column_stack([np.ones(ring.sum()), xx[ring], yy[ring]])
    coef = np.linalg.lstsq(a, img[ring], rcond=None)[0]
    bg = coef[0] + coef[1] * xx + coef[2] * yy
    wgt = np.where(rr <= radius, np.clip(img - bg, 0, None), 0.0)
    return np.array([(wgt * xx).sum() / wgt.sum(), (wgt * yy).sum() / wgt.sum()])


# --------------------------------------------------------------------------------------
# CLI: the parent plans and merges, one child process renders a batch of cases
# --------------------------------------------------------------------------------------
def worker(plan_path: Path, indices: list[int], out_dir: Path) -> None:
    import mitsuba as mi

    mi.set_variant(VARIANT)
    mi.set_log_level(mi.LogLevel.Error)  # cylinders at metre scale warn of float32 "shear"
    calib = load_calibration()
    cams = cameras(calib)
    plan = json.loads(plan_path.read_text())
    for i in indices:
        case = plan[i]
        rec = render_case(case, out_dir, cams)
        (out_dir / f"_{case['name']}.json").write_text(json.dumps(rec))
        vis = rec["truth"]["led_visible"]
        pk = rec["stats"]["led_peak_dn"]
        print(
            f"  [{i + 1}/{len(plan)}] {case['name']}: {rec['render']['time_s']:.1f} s, "
            f"range {rec['truth']['range_mm']:.0f} mm, visible {sum(vis)}/{len(vis)}, "
            f"LED peak L {min(pk['left']):.0f}-{max(pk['left']):.0f} R {min(pk['right']):.0f}-{max(pk['right']):.0f} DN, "
            f"png {sum(rec['stats']['png_bytes'].values()) / 1e3:.0f} kB",
            flush=True,
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=["dev", "holdout", "blind", "projection_check"])
    ap.add_argument("--out", type=Path)
    ap.add_argument("--batch", type=int, default=6, help="cases per child process")
    ap.add_argument("--only", type=str, default=None, help="comma-separated case indices")
    ap.add_argument("--jitter", action="store_true", help="MC-noise centroid check")
    ap.add_argument(
        "--refresh-visibility", action="store_true", help="redo the ray casts of --out's manifest"
    )
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--indices", type=str, default="", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.worker is not None:
        worker(args.worker, [int(x) for x in args.indices.split(",") if x], args.out)
        return 0
    if args.refresh_visibility:
        refresh_visibility(args.out)
        return 0
    if args.jitter:
        print(json.dumps(jitter_check(), indent=1))
        return 0
    if args.set is None or args.out is None:
        ap.error("--set and --out are required")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    if args.set == "projection_check":
        man = render_projection_check(out)
        (out / "manifest.json").write_text(json.dumps(man, indent=1) + "\n")
        print(f"projection check: {len(man['points'])} points, {man['render_time_s']} s")
        return 0

    calib = load_calibration()
    plan = plan_set(args.set, calib)
    plan_path = out / "_plan.json"
    plan_path.write_text(json.dumps(plan))
    todo = list(range(len(plan)))
    if args.only:
        todo = [int(x) for x in args.only.split(",")]
    todo = [i for i in todo if not (out / f"_{plan[i]['name']}.json").exists()]
    t0 = time.time()
    print(f"{args.set}: {len(plan)} cases, {len(todo)} to render", flush=True)
    for b in range(0, len(todo), args.batch):
        batch = todo[b : b + args.batch]
        cmd = [
            sys.executable,
            __file__,
            "--worker",
            str(plan_path),
            "--indices",
            ",".join(map(str, batch)),
            "--out",
            str(out),
        ]
        subprocess.run(cmd, check=True)
        print(f"  batch done, {time.time() - t0:.0f} s elapsed", flush=True)
    records = []
    for case in plan:
        part = out / f"_{case['name']}.json"
        if part.exists():
            records.append(json.loads(part.read_text()))
    if len(records) == len(plan):
        import mitsuba as mi

        man = {
            "renderer_version": RENDERER_VERSION,
            "mitsuba_version": mi.__version__,
            "variant": VARIANT,
            "set": args.set,
            "set_seed": SET_SEEDS[args.set],
            "calibration": "sample_data/calibration.json",
            "calibration_data": calib.to_dict(),
            "dn_scale": DN_SCALE,
            "storage": (
                "ideal (noise-free) images after the distortion/skew remap and optical blur, "
                "linear sensor DN, uint16 PNG = round(DN * dn_scale) clipped to 65535; "
                "mono = 0.299 R + 0.587 G + 0.114 B of linear RGB; bayer_rggb = RGGB mosaic "
                "(R at even row/even col, G at even/odd and odd/even, B at odd/odd)"
            ),
            "led_rgb": LED_RGB.tolist(),
            "spp_frame": SPP_FRAME,
            "spp_frame_night": SPP_FRAME_NIGHT,
            "spp_window": SPP_WINDOW,
            "psf_sigma_px": PSF_SIGMA_PX,
            "render_time_s": round(sum(r["render"]["time_s"] for r in records), 1),
            "cases": records,
        }
        (out / "manifest.json").write_text(json.dumps(man, indent=1) + "\n")
        for case in plan:
            (out / f"_{case['name']}.json").unlink()
        plan_path.unlink()
        print(f"manifest: {len(records)} cases, render time {man['render_time_s']} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
