"""Everything bright in a rendered pair that is not an LED of the ring: clutter (3-D and
monocular glints of random size, the hose's elongated glint), kept away from the ring's image,
and the hostile extras (all off by default; they draw from their own random stream):

* ``glints``: 3-D glints that look exactly like LEDs — spheres of the LED diameter and
  brightness, seen consistently by both cameras, at a depth near the drogue's, away from
  the ring's image and from each other (each is a separate LED-sized blob);
* ``mono_glints``: LED-sized glints seen by one camera only;
* ``rim_reflections``: LED-sized bright spots ON the ring's circle, at a given angular
  offset from a given LED (a reflection of that LED on the drogue's rim).

Positions: left camera frame (mm) and distorted pixels (px).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import StereoCalibration
from app.sim.led_ring import LedRing, led_angles_rad, ring_basis
from app.sim.stereo_render.blobs import (
    LightSpot,
    in_frame,
    project_checked,
    spectral_norm,
    sphere_shapes,
    to_right,
)
from app.sim.stereo_render.scene import LED_BGR, RenderSettings
from app.types import FloatArray

GLINT_DEPTH_FACTORS = (0.87, 1.13)  # default glint depth window, × drogue centre depth
GLINT_GAP_PX = 4.0  # min gap between the discs of two glints (or a glint and clutter)
GLINT_TRIES = 2000  # draws per glint before it is given up (truth then has fewer rows)


@dataclass
class Clutter:
    left: list[LightSpot] = field(default_factory=list)
    right: list[LightSpot] = field(default_factory=list)
    left_px: list[FloatArray] = field(default_factory=list)
    right_px: list[FloatArray] = field(default_factory=list)
    xyz: list[FloatArray] = field(default_factory=list)
    second_left: FloatArray | None = None
    second_right: FloatArray | None = None


class Keepout:
    """Image regions clutter must avoid: the ring disc and every LED blob (per image)."""

    def __init__(
        self, ring_center_px: FloatArray, led_px: FloatArray, led_r_px: FloatArray
    ) -> None:
        self.center = ring_center_px
        finite = np.all(np.isfinite(led_px), axis=1)
        self.led_px = led_px[finite]
        self.led_r = led_r_px[finite]
        if np.all(np.isfinite(ring_center_px)) and len(self.led_px):
            d = np.linalg.norm(self.led_px - ring_center_px, axis=1) + self.led_r
            self.ring_r = float(np.max(d))
        else:
            self.ring_r = 0.0

    def ok(self, p: FloatArray, r_px: float) -> bool:
        if np.all(np.isfinite(self.center)) and self.ring_r > 0:
            if np.linalg.norm(p - self.center) - r_px <= 1.4 * self.ring_r + 10.0:
                return False
        if len(self.led_px):
            gaps = np.linalg.norm(self.led_px - p, axis=1) - self.led_r - r_px
            if np.any(gaps < 15.0):
                return False
        return True


def make_clutter(
    calib: StereoCalibration,
    settings: RenderSettings,
    rng: np.random.Generator,
    range_mm: float,
    keep_left: Keepout,
    keep_right: Keepout,
    gray_bgr: NDArray[np.float32],
) -> Clutter:
    w, h = calib.image_size
    out = Clutter()
    n3d = (settings.clutter + 1) // 2
    n_mono = settings.clutter - n3d
    fl = 0.5 * (calib.left.fx + calib.left.fy)
    max_tries = 500

    def peak() -> float:
        return float(settings.led_peak * rng.uniform(0.85, 1.1))

    def tint() -> NDArray[np.float32]:
        # whitish glints: similar grey level to the LEDs, so thresholds cannot drop them
        return np.clip(gray_bgr + rng.uniform(-0.15, 0.15, 3).astype(np.float32), 0.2, 1.0)

    for _ in range(n3d):  # 3-D glints, seen consistently by both cameras
        for _try in range(max_tries):
            z = range_mm * rng.uniform(0.5, 3.0)
            u, v = rng.uniform(0, w - 1), rng.uniform(0, h - 1)
            xn = (u - calib.left.u0) / fl
            yn = (v - calib.left.v0) / fl
            xyz = np.array([[xn * z, yn * z, z]])
            size_mm = rng.uniform(2.0, 10.0)
            pl, pr, zl, zr = project_checked(calib, xyz)
            in_l = bool(in_frame(pl, calib.image_size)[0])
            in_r = bool(in_frame(pr, calib.image_size)[0])
            if not (in_l or in_r):
                continue
            rad = np.array([0.5 * size_mm])
            al = sphere_shapes(calib.left, xyz, rad)[0] if in_l else None
            ar = sphere_shapes(calib.right, to_right(calib, xyz), rad)[0] if in_r else None
            if al is not None and not keep_left.ok(pl[0], float(np.linalg.norm(al, 2))):
                continue
            if ar is not None and not keep_right.ok(pr[0], float(np.linalg.norm(ar, 2))):
                continue
            pk, col = peak(), tint()
            if al is not None:
                out.left.append(LightSpot(pl[0], al, pk, col))
            if ar is not None:
                out.right.append(LightSpot(pr[0], ar, pk, col))
            out.left_px.append(pl[0] if in_l else np.full(2, np.nan))
            out.right_px.append(pr[0] if in_r else np.full(2, np.nan))
            out.xyz.append(xyz[0])
            break

    for i in range(n_mono):  # monocular glints, alternating left / right
        left_side = i % 2 == 0
        keep = keep_left if left_side else keep_right
        for _try in range(max_tries):
            p = np.array([rng.uniform(0, w - 1), rng.uniform(0, h - 1)])
            r_px = float(rng.uniform(1.5, 6.0))
            if not keep.ok(p, r_px):
                continue
            b = LightSpot(p, np.eye(2) * r_px, peak(), tint())
            nan2 = np.full(2, np.nan)
            (out.left if left_side else out.right).append(b)
            out.left_px.append(p if left_side else nan2)
            out.right_px.append(nan2 if left_side else p)
            out.xyz.append(np.full(3, np.nan))
            break

    if settings.second_object:  # elongated glint off the hose, ~30×8 px, in both images
        for _try in range(max_tries):
            z = range_mm * rng.uniform(0.8, 1.3)
            u, v = rng.uniform(0, w - 1), rng.uniform(0, h - 1)
            xyz = np.array([[(u - calib.left.u0) / fl * z, (v - calib.left.v0) / fl * z, z]])
            pl, pr, _, _ = project_checked(calib, xyz)
            if not (in_frame(pl, calib.image_size)[0] and in_frame(pr, calib.image_size)[0]):
                continue
            ang = rng.uniform(0, math.pi)
            rot = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
            A = rot @ np.diag([15.0, 4.0])
            if not (keep_left.ok(pl[0], 15.0) and keep_right.ok(pr[0], 15.0)):
                continue
            pk, col = peak(), tint()
            out.left.append(LightSpot(pl[0], A, pk, col))
            out.right.append(LightSpot(pr[0], A, pk, col))
            out.second_left, out.second_right = pl[0], pr[0]
            break
    return out


@dataclass
class Extras:
    left: list[LightSpot] = field(default_factory=list)
    right: list[LightSpot] = field(default_factory=list)
    glint_xyz: list[FloatArray] = field(default_factory=list)
    glint_left_px: list[FloatArray] = field(default_factory=list)
    glint_right_px: list[FloatArray] = field(default_factory=list)
    mono_left_px: list[FloatArray] = field(default_factory=list)
    mono_right_px: list[FloatArray] = field(default_factory=list)
    refl_xyz: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    refl_left_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    refl_right_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))


class _Occupied:
    """Discs (centre, radius px) already placed in one image; new glints keep a gap."""

    def __init__(self, blobs: list[LightSpot]) -> None:
        self.p = [b.center_px for b in blobs]
        self.r = [spectral_norm(b.shape_px) for b in blobs]

    def ok(self, p: FloatArray, r_px: float) -> bool:
        if not self.p:
            return True
        gaps = np.linalg.norm(np.array(self.p) - p, axis=1) - np.array(self.r) - r_px
        return bool(np.all(gaps >= GLINT_GAP_PX))

    def add(self, p: FloatArray, r_px: float) -> None:
        self.p.append(p)
        self.r.append(r_px)


def _disc_inside(p: FloatArray, r_px: float, size: tuple[int, int]) -> bool:
    """The whole disc (plus 1 px) lies inside the image, so it is drawn unclipped."""
    w, h = size
    m = r_px + 1.0
    return bool(m <= p[0] <= w - 1 - m and m <= p[1] <= h - 1 - m)


def make_extras(
    calib: StereoCalibration,
    settings: RenderSettings,
    ring: LedRing,
    rng: np.random.Generator,
    center: FloatArray,
    normal: FloatArray,
    roll_rad: float,
    keep: tuple[Keepout, Keepout] | None,
    clutter: Clutter,
    led_bgr: NDArray[np.float32],
) -> Extras:
    """Draw the hostile extras of ``settings`` (own random stream ``rng``)."""
    out = Extras()
    size = calib.image_size
    w, h = size
    r_led = 0.5 * ring.led_diameter_mm
    white = np.ones(3, dtype=np.float32)

    def peak() -> float:
        return float(settings.led_peak * rng.uniform(0.9, 1.1))

    def colour() -> NDArray[np.float32]:
        # drawn in every mode, so the glints' places do not depend on color/glint_led_color
        tint = rng.uniform(-0.15, 0.15, 3).astype(np.float32)
        if not settings.color:
            return white
        if settings.glint_led_color:
            return LED_BGR
        # whitish, like the clutter glints: similar grey level to the LEDs
        return np.clip(white + tint, 0.2, 1.0)

    if keep is not None:
        keep_l, keep_r = keep
        occ_l, occ_r = _Occupied(clutter.left), _Occupied(clutter.right)
        range_mm = max(float(center[2]), 100.0)
        lo, hi = settings.glint_depth_mm or tuple(f * range_mm for f in GLINT_DEPTH_FACTORS)
        fl = 0.5 * (calib.left.fx + calib.left.fy)
        rad = np.array([r_led])
        for _ in range(settings.glints):  # LED-like 3-D glints, seen by both cameras
            for _try in range(GLINT_TRIES):
                z = rng.uniform(lo, hi)
                u, v = rng.uniform(0, w - 1), rng.uniform(0, h - 1)
                xyz = np.array([[(u - calib.left.u0) / fl * z, (v - calib.left.v0) / fl * z, z]])
                pl, pr, _, _ = project_checked(calib, xyz)
                if not (np.all(np.isfinite(pl)) and np.all(np.isfinite(pr))):
                    continue
                al = sphere_shapes(calib.left, xyz, rad)[0]
                ar = sphere_shapes(calib.right, to_right(calib, xyz), rad)[0]
                rl, rr = spectral_norm(al), spectral_norm(ar)
                if not (_disc_inside(pl[0], rl, size) and _disc_inside(pr[0], rr, size)):
                    continue
                if not (keep_l.ok(pl[0], rl) and keep_r.ok(pr[0], rr)):
                    continue
                if not (occ_l.ok(pl[0], rl) and occ_r.ok(pr[0], rr)):
                    continue
                pk, col = peak(), colour()
                out.left.append(LightSpot(pl[0], al, pk, col))
                out.right.append(LightSpot(pr[0], ar, pk, col))
                occ_l.add(pl[0], rl)
                occ_r.add(pr[0], rr)
                out.glint_xyz.append(xyz[0])
                out.glint_left_px.append(pl[0])
                out.glint_right_px.append(pr[0])
                break

        # monocular glints: a disc of the LEDs' image radius at the drogue's depth
        z_r = max(float(to_right(calib, center[None, :])[0, 2]), 100.0)
        mono_r = (
            0.5 * (calib.left.fx + calib.left.fy) * r_led / range_mm,
            0.5 * (calib.right.fx + calib.right.fy) * r_led / z_r,
        )
        for i in range(settings.mono_glints):
            left_side = i % 2 == 0
            keep_i, occ_i = (keep_l, occ_l) if left_side else (keep_r, occ_r)
            r_px = mono_r[0] if left_side else mono_r[1]
            for _try in range(GLINT_TRIES):
                p = np.array([rng.uniform(0, w - 1), rng.uniform(0, h - 1)])
                if not (_disc_inside(p, r_px, size) and keep_i.ok(p, r_px) and occ_i.ok(p, r_px)):
                    continue
                b = LightSpot(p, np.eye(2) * r_px, peak(), colour())
                (out.left if left_side else out.right).append(b)
                occ_i.add(p, r_px)
                nan2 = np.full(2, np.nan)
                out.mono_left_px.append(p if left_side else nan2)
                out.mono_right_px.append(nan2 if left_side else p)
                break

    if settings.rim_reflections:  # on the rim circle, θ_id + offset, LED size and colour
        ids = np.array([i for i, _ in settings.rim_reflections], dtype=np.int64)
        offs = np.radians([off for _, off in settings.rim_reflections])
        th = led_angles_rad(ring, roll_rad)[ids - 1] + offs
        e_up, e_right = ring_basis(normal)
        xyz = center + ring.radius_mm * (np.outer(np.cos(th), e_up) + np.outer(np.sin(th), e_right))
        pl, pr, _, _ = project_checked(calib, xyz)
        in_l, in_r = in_frame(pl, size), in_frame(pr, size)
        rad = np.full(len(xyz), r_led)
        al = sphere_shapes(calib.left, xyz, rad)
        ar = sphere_shapes(calib.right, to_right(calib, xyz), rad)
        for k in range(len(xyz)):
            if in_l[k]:
                out.left.append(LightSpot(pl[k], al[k], settings.led_peak, led_bgr))
            if in_r[k]:
                out.right.append(LightSpot(pr[k], ar[k], settings.led_peak, led_bgr))
        out.refl_xyz, out.refl_left_px, out.refl_right_px = xyz, pl, pr
    return out
