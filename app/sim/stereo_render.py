"""Synthetic stereo images of the drogue's LED ring with exact ground truth (paper §3–5).

Each LED is a small emitting sphere, so its image is a disc whatever the drogue tilt. The
disc is centred on the projection of the LED centre through the full camera model
(distortion and skew, eqs. 2 and 7, via :func:`app.geometry.projection.project_stereo`) and
shaped by the local Jacobian of that projection (radius f·r/Z, slightly elliptical where the
skew or the distortion stretch the image). It is drawn with anti-aliased supersampled
coverage, blurred with a symmetric Gaussian, and placed on a noisy background. Every step is
point-symmetric about the projected centre, so an intensity-weighted centroid (eq. 11) of
the noise-free blob returns the truth pixel to well under 0.01 px.

Hostile extras (all off by default; they draw from their own random stream, so a render
without them is byte-identical to one made before they existed):

* ``glints``: 3-D glints that look exactly like LEDs — spheres of the LED diameter and
  brightness, seen consistently by both cameras, at a depth near the drogue's, away from
  the ring's image and from each other (each is a separate LED-sized blob);
* ``mono_glints``: LED-sized glints seen by one camera only;
* ``rim_reflections``: LED-sized bright spots ON the ring's circle, at a given angular
  offset from a given LED (a reflection of that LED on the drogue's rim).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import CameraIntrinsics, FloatArray, StereoCalibration
from app.geometry.projection import project_camera, project_stereo
from app.sim.led_ring import LedRing, check_pose, led_angles_rad, ring_basis, ring_points

# (B, G, R) weights of an LED seen through the green filter (mostly green).
LED_BGR = np.array([0.45, 1.0, 0.30], dtype=np.float32)
NOISE_FIELD_PAD = 256  # px added to each side of the cached noise field (fast_noise)
_MIN_DEPTH_MM = 1.0
_EXTRAS_STREAM = 0x676C6E74  # second seed word of the hostile extras' random stream
_GLINT_DEPTH_FACTORS = (0.87, 1.13)  # default glint depth window, × drogue centre depth
_GLINT_GAP_PX = 4.0  # min gap between the discs of two glints (or a glint and clutter)
Rect = tuple[int, int, int, int]  # (x0, y0, x1, y1) px, half-open
_GLINT_TRIES = 2000  # draws per glint before it is given up (truth then has fewer rows)


@dataclass(frozen=True)
class RenderSettings:
    """Image formation parameters (DN = digital number, 8-bit grey levels)."""

    led_peak: float = 235.0  # DN above background at the LED core (before blur)
    background: float = 12.0  # DN
    noise_sigma: float = 2.0  # DN, Gaussian sensor noise
    blur_sigma_px: float = 0.7  # px, Gaussian optical blur
    supersample: int = 8  # sub-samples per pixel side (anti-aliasing)
    clutter: int = 0  # number of clutter glints (half 3-D, half monocular)
    second_object: bool = False  # one large elongated bright non-LED blob (hose glint)
    occluded: tuple[int, ...] = ()  # LED ids (1..N) hidden in both images
    color: bool = False  # BGR output with mostly-green LEDs instead of grey
    fast_noise: bool = False  # noise from a cached field at a random offset (closed loop)
    # ---- hostile extras (see the module docstring); none drawn by default
    glints: int = 0  # LED-like 3-D glints (LED size and brightness, both cameras)
    glint_depth_mm: tuple[float, float] | None = None  # None: drogue depth × (0.87, 1.13)
    glint_led_color: bool = False  # colour images: glints in LED_BGR instead of whitish
    mono_glints: int = 0  # LED-sized glints seen by one camera (alternating left/right)
    rim_reflections: tuple[tuple[int, float], ...] = ()  # (LED id, offset deg) on the rim

    def __post_init__(self) -> None:
        for name in ("led_peak", "background", "noise_sigma", "blur_sigma_px"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"RenderSettings.{name} must be a finite number >= 0, got {v!r}")
        if self.background > 255:
            raise ValueError(f"RenderSettings.background must be <= 255, got {self.background}")
        if not isinstance(self.supersample, int) or not 1 <= self.supersample <= 64:
            raise ValueError(
                f"RenderSettings.supersample must be an integer in 1..64, got {self.supersample!r}"
            )
        if not isinstance(self.clutter, int) or self.clutter < 0:
            raise ValueError(
                f"RenderSettings.clutter must be an integer >= 0, got {self.clutter!r}"
            )
        try:
            occ = tuple(int(i) for i in self.occluded)
        except (TypeError, ValueError):
            raise ValueError(
                f"RenderSettings.occluded must be LED ids (integers), got {self.occluded!r}"
            ) from None
        object.__setattr__(self, "occluded", occ)
        for name in ("glints", "mono_glints"):
            v = getattr(self, name)
            if not isinstance(v, int | np.integer) or isinstance(v, bool) or v < 0:
                raise ValueError(f"RenderSettings.{name} must be an integer >= 0, got {v!r}")
            object.__setattr__(self, name, int(v))
        if not isinstance(self.glint_led_color, bool | np.bool_):
            raise ValueError(
                f"RenderSettings.glint_led_color must be a bool, got {self.glint_led_color!r}"
            )
        object.__setattr__(self, "glint_led_color", bool(self.glint_led_color))
        if self.glint_depth_mm is not None:
            object.__setattr__(self, "glint_depth_mm", _check_depth_window(self.glint_depth_mm))
        object.__setattr__(self, "rim_reflections", _check_reflections(self.rim_reflections))

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["occluded"] = list(self.occluded)
        d["glint_depth_mm"] = None if self.glint_depth_mm is None else list(self.glint_depth_mm)
        d["rim_reflections"] = [[i, off] for i, off in self.rim_reflections]
        return d


def _check_depth_window(value: object) -> tuple[float, float]:
    msg = "RenderSettings.glint_depth_mm must be None or (near, far) mm with 1 <= near <= far"
    try:
        lo, hi = (float(v) for v in value)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise ValueError(f"{msg}, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and _MIN_DEPTH_MM <= lo <= hi):
        raise ValueError(f"{msg}, got {value!r}")
    return lo, hi


def _check_reflections(value: object) -> tuple[tuple[int, float], ...]:
    msg = "RenderSettings.rim_reflections must be (LED id >= 1, finite offset deg) pairs"
    try:
        items = list(value)  # type: ignore[call-overload]
    except TypeError:
        raise ValueError(f"{msg}, got {value!r}") from None
    out: list[tuple[int, float]] = []
    for item in items:
        try:
            led_id, off = item
            fid, foff = float(led_id), float(off)
        except (TypeError, ValueError):
            raise ValueError(f"{msg}, got entry {item!r}") from None
        if isinstance(led_id, bool) or not (math.isfinite(fid) and fid == round(fid)):
            raise ValueError(f"{msg}: LED id must be an integer, got {led_id!r}")
        if fid < 1:
            raise ValueError(f"{msg}: LED id must be >= 1, got {led_id!r}")
        if not math.isfinite(foff):
            raise ValueError(f"{msg}: offset must be finite, got {off!r}")
        out.append((int(fid), foff))
    return tuple(out)


def _check_windows(windows: object) -> tuple[list[Rect], list[Rect]]:
    msg = "windows must be (left, right) lists of (x0, y0, x1, y1) integer pixel rectangles"
    sides: list[list[Rect]] = []
    try:
        for side in windows:  # type: ignore[attr-defined]
            rects: list[Rect] = []
            for r in side:
                x0, y0, x1, y1 = (int(v) for v in r)
                if x1 < x0 or y1 < y0:
                    raise ValueError
                rects.append((x0, y0, x1, y1))
            sides.append(rects)
    except (TypeError, ValueError):
        raise ValueError(f"{msg}, got {windows!r}") from None
    if len(sides) != 2:
        raise ValueError(f"{msg}, got {windows!r}")
    return sides[0], sides[1]


def _nan_to_none(value: Any) -> Any:
    if isinstance(value, list):
        return [_nan_to_none(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@dataclass
class RenderTruth:
    """Ground truth of one rendered pair (left camera frame, mm; distorted pixels, px).

    ``led_left_px``/``led_right_px`` are the projections of the LED centres through the full
    camera model, i.e. what a perfect centroid of each blob returns. ``visible`` is True
    where the LED is drawn in both images (in frame, in front of both cameras, not occluded);
    ``in_left``/``in_right`` say per image. An LED counts as in an image when its centre
    projects inside it; one within a blob radius of the border is drawn clipped (as a camera
    would show it), so its centroid is biased: keep accuracy poses away from the borders.
    Clutter pixel rows are NaN where that item is not in that image (monocular glints, or out
    of frame).

    Hostile extras: ``glint_*`` rows are the LED-like 3-D glints actually placed (centre mm;
    its projection in each image, always inside both); ``mono_glint_left_px`` /
    ``mono_glint_right_px`` one row per monocular glint, NaN in the image it is not in;
    ``reflection_*`` one row per ``RenderSettings.rim_reflections`` entry, in that order
    (the projection, NaN only behind a camera; drawn where it falls in the image).
    """

    led_xyz_mm: FloatArray
    led_ids: NDArray[np.int64]
    visible: NDArray[np.bool_]
    led_left_px: FloatArray
    led_right_px: FloatArray
    center_mm: FloatArray
    normal: FloatArray
    radius_mm: float
    clutter_left_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    clutter_right_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    in_left: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    in_right: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    led_left_radius_px: FloatArray = field(default_factory=lambda: np.zeros(0))
    led_right_radius_px: FloatArray = field(default_factory=lambda: np.zeros(0))
    clutter_xyz_mm: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    second_object_left_px: FloatArray | None = None
    second_object_right_px: FloatArray | None = None
    roll_rad: float = 0.0
    glint_xyz_mm: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    glint_left_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    glint_right_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    mono_glint_left_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    mono_glint_right_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    reflection_xyz_mm: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    reflection_left_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    reflection_right_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (lists; NaN → null)."""
        out: dict[str, Any] = {}
        for key, value in self.__dict__.items():
            if isinstance(value, np.ndarray):
                out[key] = _nan_to_none(value.tolist())
            elif isinstance(value, float | np.floating):
                out[key] = _nan_to_none(float(value))
            else:
                out[key] = value
        return out


@dataclass
class RenderedPair:
    """A stereo pair (uint8, H×W grey or H×W×3 BGR) and its ground truth."""

    left: NDArray[np.uint8]
    right: NDArray[np.uint8]
    truth: RenderTruth


# ----------------------------------------------------------------------------------------
# Blob drawing
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Blob:
    center_px: FloatArray  # (2,) distorted px
    shape_px: FloatArray  # 2×2 A: unit disc → px ellipse around the centre
    peak: float  # DN
    bgr: NDArray[np.float32]  # colour weights (B, G, R)


def _spectral_norm(M: FloatArray) -> float:
    """Largest singular value of a 2×2 matrix."""
    a, b, c, d = float(M[0, 0]), float(M[0, 1]), float(M[1, 0]), float(M[1, 1])
    s1 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return math.sqrt(0.5 * (s1 + math.sqrt(max(s1 * s1 - 4 * det * det, 0.0))))


def _spectral_norms(m: FloatArray) -> FloatArray:
    """Largest singular values of a stack of 2×2 matrices (B×2×2)."""
    a, b, c, d = m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1]
    s1 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return np.asarray(np.sqrt(0.5 * (s1 + np.sqrt(np.maximum(s1 * s1 - 4 * det * det, 0.0)))))


def _patch_half(blob: _Blob, blur_sigma: float) -> int:
    """Half-size (px) of a blob's square patch: longest semi-axis + 2 px + the blur's reach."""
    kr = int(math.ceil(4.0 * blur_sigma)) if blur_sigma > 0 else 0
    return int(math.ceil(_spectral_norm(blob.shape_px))) + 2 + kr


def _patch_box(blob: _Blob, blur_sigma: float) -> tuple[int, int, int, int]:
    """The patch's pixel rectangle (x0, y0, x1, y1), half-open."""
    half = _patch_half(blob, blur_sigma)
    x0 = int(round(float(blob.center_px[0]))) - half
    y0 = int(round(float(blob.center_px[1]))) - half
    return x0, y0, x0 + 2 * half + 1, y0 + 2 * half + 1


def _blur_taps(blur_sigma: float) -> NDArray[np.float64]:
    """Normalised Gaussian taps (2·kr + 1, kr = ⌈4σ⌉), as ``cv2.getGaussianKernel``."""
    kr = int(math.ceil(4.0 * blur_sigma))
    return np.asarray(cv2.getGaussianKernel(2 * kr + 1, blur_sigma, cv2.CV_64F), float).ravel()


@lru_cache(maxsize=64)
def _blur_matrix(blur_sigma: float, n: int) -> NDArray[np.float64]:
    """n×n banded matrix T with (P·T)[i, j] = Σ_k taps[k] P[i, j + k − kr] (zero outside)."""
    taps = _blur_taps(blur_sigma)
    kr = (len(taps) - 1) // 2
    t = np.zeros((n, n))
    for j in range(n):
        for k in range(-kr, kr + 1):
            if 0 <= j + k < n:
                t[j + k, j] = taps[k + kr]
    t.setflags(write=False)
    return t


def _blob_patches(
    blobs: list[_Blob], supersample: int, blur_sigma: float
) -> list[tuple[int, int, NDArray[np.float32]]]:
    """Rendered blobs (float32 DN), each on its own square patch: [(x0, y0, patch)].

    Coverage is evaluated on ``supersample``² sub-samples per pixel with an anti-aliased
    edge (signed distance along the ray from the centre, one sub-sample wide), then blurred
    with a symmetric Gaussian (zero outside the patch). All steps are point-symmetric about
    the centre. Blobs of equal patch size are computed together, with element-wise
    arithmetic only (no reductions across pixels except the fixed s² sub-sample mean and the
    fixed-order blur taps), so a blob's patch is bit-identical whichever other blobs share
    the call — a windowed render (a subset of the blobs) equals the full render there.
    """
    out: list[tuple[int, int, NDArray[np.float32]] | None] = [None] * len(blobs)
    blurred = blur_sigma > 0
    s = supersample
    off = (np.arange(s, dtype=np.float64) + 0.5) / s - 0.5
    off_x, off_y = np.tile(off, s), np.repeat(off, s)  # sub-sample offsets, px
    groups: dict[int, list[int]] = {}
    for i, b in enumerate(blobs):
        groups.setdefault(_patch_half(b, blur_sigma), []).append(i)
    for half, idx in groups.items():
        n = 2 * half + 1
        sel = [blobs[i] for i in idx]
        ainv = np.linalg.inv(np.array([b.shape_px for b in sel], dtype=np.float64))  # (B,2,2)
        g = _spectral_norms(ainv)  # max change of u per px
        cx = np.array([float(b.center_px[0]) for b in sel])
        cy = np.array([float(b.center_px[1]) for b in sel])
        x0 = np.rint(cx).astype(np.int64) - half  # round half to even, like round()
        y0 = np.rint(cy).astype(np.int64) - half
        ar = np.arange(n, dtype=np.float64)
        dx = (x0[:, None] + ar[None, :]) - cx[:, None]  # (B, n)
        dy = (y0[:, None] + ar[None, :]) - cy[:, None]
        a00, a01 = ainv[:, 0, 0, None, None], ainv[:, 0, 1, None, None]
        a10, a11 = ainv[:, 1, 0, None, None], ainv[:, 1, 1, None, None]
        ddx, ddy = dx[:, None, :], dy[:, :, None]
        # pixel centres: the ellipse "radius" u (1 = edge) decides fully inside / outside
        qx, qy = a00 * ddx + a01 * ddy, a10 * ddx + a11 * ddy
        u_c = np.sqrt(qx * qx + qy * qy)  # (B, n, n)
        # sub-sample offsets (s², row-major) and their images under A⁻¹ per blob (B, s²)
        q_off = (
            ainv[:, 0, 0, None] * off_x + ainv[:, 0, 1, None] * off_y,
            ainv[:, 1, 0, None] * off_x + ainv[:, 1, 1, None] * off_y,
        )
        band = (g * (0.75 + 0.5 / s))[:, None, None]  # sub-samples ≤ √2/2 px away; AA width
        cov = (u_c < 1.0 - band).astype(np.float64)
        eb, ey, ex = np.nonzero(np.abs(u_c - 1.0) <= band)
        if len(eb):
            # supersample only the edge pixels: s² sub-samples each, anti-aliased edge
            px, py = dx[eb, ex], dy[eb, ey]  # (E,) pixel centre − blob centre
            # in-place arithmetic on (E, s²) arrays (fewer large temporaries)
            qx = (ainv[eb, 0, 0] * px + ainv[eb, 0, 1] * py)[:, None] + q_off[0][eb]
            qy = (ainv[eb, 1, 0] * px + ainv[eb, 1, 1] * py)[:, None] + q_off[1][eb]
            np.multiply(qx, qx, out=qx)
            np.multiply(qy, qy, out=qy)
            u = np.sqrt(np.add(qx, qy, out=qx), out=qx)  # (E, s²)
            sx = np.add(px[:, None], off_x, out=qy)
            np.multiply(sx, sx, out=sx)
            sy = py[:, None] + off_y
            np.multiply(sy, sy, out=sy)
            d = np.sqrt(np.add(sx, sy, out=sx), out=sx)  # px distance from the centre
            ok = u > 1e-12  # (u = 0 only at the centre itself: inside, coverage 1)
            sd = np.full_like(u, np.inf)
            np.divide(d, u, out=sd, where=ok)
            np.subtract(sd, d, out=sd, where=ok)  # signed distance to the edge along the ray, px
            np.multiply(sd, s, out=sd)
            np.add(sd, 0.5, out=sd)
            np.clip(sd, 0.0, 1.0, out=sd)
            cov[eb, ey, ex] = sd.mean(axis=1)
        peaks = np.array([float(np.float32(b.peak)) for b in sel])
        patch = cov * peaks[:, None, None]
        if blurred:
            # separable blur with a zero border as T_nᵀ · P · T_n (one matrix product per blob
            # of the same shape: the same arithmetic whichever other blobs share the batch)
            t_n = _blur_matrix(blur_sigma, n)
            patch = np.matmul(np.matmul(t_n.T, patch), t_n)
        p32 = patch.astype(np.float32)
        for j, i in enumerate(idx):
            out[i] = (int(x0[j]), int(y0[j]), p32[j])
    return [o for o in out if o is not None]


def _paste(
    canvas: NDArray[Any],
    x0: int,
    y0: int,
    patch: NDArray[np.float32],
    bgr: NDArray[np.float32] | None,
) -> tuple[int, int, int, int, NDArray[np.float32]] | None:
    """Clip a patch to the canvas; returns (ya, yb, xa, xb, clipped patch[, ×bgr]) or None."""
    h, w = canvas.shape[:2]
    ph, pw = patch.shape
    xa, ya = max(x0, 0), max(y0, 0)
    xb, yb = min(x0 + pw, w), min(y0 + ph, h)
    if xa >= xb or ya >= yb:
        return None
    p = patch[ya - y0 : yb - y0, xa - x0 : xb - x0]
    if bgr is not None:
        p = p[:, :, None] * bgr[None, None, :]
    return ya, yb, xa, xb, p


def _clip_rects(rects: list[Rect], shape: tuple[int, ...]) -> list[Rect]:
    """Rectangles clipped to the image; empty ones dropped."""
    h, w = shape[:2]
    out = []
    for x0, y0, x1, y1 in rects:
        xa, ya, xb, yb = max(int(x0), 0), max(int(y0), 0), min(int(x1), w), min(int(y1), h)
        if xa < xb and ya < yb:
            out.append((xa, ya, xb, yb))
    return out


def _overlaps(box: Rect, rects: list[Rect]) -> bool:
    x0, y0, x1, y1 = box
    return any(x0 < rb and ra < x1 and y0 < sb and sa < y1 for ra, sa, rb, sb in rects)


def _region_mask(
    ya: int, yb: int, xa: int, xb: int, rects: list[Rect]
) -> NDArray[np.bool_] | Rect | None:
    """Which pixels of the region [ya, yb) × [xa, xb) lie in a window: None (all of them),
    one rectangle (x0, y0, x1, y1) relative to the region (the usual case: the region meets
    one window), or a boolean mask."""
    hits = []
    for x0, y0, x1, y1 in rects:
        if x0 < xb and xa < x1 and y0 < yb and ya < y1:
            if x0 <= xa and xb <= x1 and y0 <= ya and yb <= y1:
                return None
            hits.append((max(x0, xa) - xa, max(y0, ya) - ya, min(x1, xb) - xa, min(y1, yb) - ya))
    if len(hits) == 1:
        return hits[0]
    mask = np.zeros((yb - ya, xb - xa), dtype=bool)
    for x0, y0, x1, y1 in hits:
        mask[y0:y1, x0:x1] = True
    return mask


def _compose(
    shape: tuple[int, ...],
    blobs: list[_Blob],
    settings: RenderSettings,
    rng: np.random.Generator,
    windows: list[Rect] | None = None,
    patches: list[tuple[int, int, NDArray[np.float32], NDArray[np.float32]]] | None = None,
) -> NDArray[np.uint8]:
    """Background + noise + blobs → uint8 image.

    ``windows``: render only these rectangles (pixels elsewhere are 0); inside them the image
    is bit-identical to the full render (same random draws, same blobs in the same order).
    ``patches``: the blobs' patches (x0, y0, patch, bgr), computed beforehand (in order).
    """
    color = len(shape) == 3
    rects = None if windows is None else _clip_rects(windows, shape)
    if patches is None:
        if rects is not None and settings.fast_noise:
            # only the blobs whose patch reaches a window
            blobs = [b for b in blobs if _overlaps(_patch_box(b, settings.blur_sigma_px), rects)]
        made = _blob_patches(blobs, settings.supersample, settings.blur_sigma_px)
        patches = [(x0, y0, p, b.bgr) for (x0, y0, p), b in zip(made, blobs, strict=True)]
    if settings.fast_noise:
        if rects is None:
            base = _noise_window(shape, settings, rng)
        else:
            base = _noise_windows(shape, settings, rng, rects)
        for x0, y0, patch, bgr in patches:
            cut = _paste(base, x0, y0, patch, bgr if color else None)
            if cut is None:
                continue
            ya, yb, xa, xb, p = cut
            region = base[ya:yb, xa:xb].astype(np.float32) + p
            new = np.clip(np.rint(region), 0, 255).astype(np.uint8)
            m = None if rects is None else _region_mask(ya, yb, xa, xb, rects)
            if m is None:
                base[ya:yb, xa:xb] = new
            elif isinstance(m, tuple):  # the part of the patch inside its one window
                rx0, ry0, rx1, ry1 = m
                base[ya + ry0 : ya + ry1, xa + rx0 : xa + rx1] = new[ry0:ry1, rx0:rx1]
            else:  # a patch reaching several windows: write only its window pixels
                np.copyto(base[ya:yb, xa:xb], new, where=m[:, :, None] if color else m)
        return base
    img = np.full(shape, settings.background, dtype=np.float32)
    if settings.noise_sigma > 0:
        img += rng.standard_normal(shape, dtype=np.float32) * np.float32(settings.noise_sigma)
    for x0, y0, patch, bgr in patches:
        cut = _paste(img, x0, y0, patch, bgr if color else None)
        if cut is None:
            continue
        ya, yb, xa, xb, p = cut
        img[ya:yb, xa:xb] += p
    full = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if rects is None:
        return full
    out = np.zeros(shape, dtype=np.uint8)  # fresh noise needs the whole frame's draws anyway
    for xa, ya, xb, yb in rects:
        out[ya:yb, xa:xb] = full[ya:yb, xa:xb]
    return out


@lru_cache(maxsize=8)
def _noise_field(
    shape: tuple[int, ...], background: float, sigma: float, seed: int
) -> NDArray[np.uint8]:
    """Pre-quantised background + noise, padded by NOISE_FIELD_PAD px on each side."""
    h, w = shape[:2]
    big = (h + 2 * NOISE_FIELD_PAD, w + 2 * NOISE_FIELD_PAD, *shape[2:])
    rng = np.random.default_rng(seed)
    f = background + sigma * rng.standard_normal(big, dtype=np.float32)
    field_u8 = np.clip(np.rint(f), 0, 255).astype(np.uint8)
    field_u8.setflags(write=False)
    return field_u8


def _noise_window(
    shape: tuple[int, ...], settings: RenderSettings, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """A writable copy of the cached noise field at a random offset (fast_noise)."""
    noise = _noise_field(shape, float(settings.background), float(settings.noise_sigma), 0)
    h, w = shape[:2]
    oy, ox = rng.integers(0, 2 * NOISE_FIELD_PAD + 1, size=2)
    return noise[oy : oy + h, ox : ox + w].copy()


def _noise_windows(
    shape: tuple[int, ...], settings: RenderSettings, rng: np.random.Generator, rects: list[Rect]
) -> NDArray[np.uint8]:
    """:func:`_noise_window`'s field (same offset draw) copied into ``rects`` only; zeros
    elsewhere."""
    noise = _noise_field(shape, float(settings.background), float(settings.noise_sigma), 0)
    oy, ox = rng.integers(0, 2 * NOISE_FIELD_PAD + 1, size=2)
    out = np.zeros(shape, dtype=np.uint8)
    for xa, ya, xb, yb in rects:
        out[ya:yb, xa:xb] = noise[oy + ya : oy + yb, ox + xa : ox + xb]
    return out


# ----------------------------------------------------------------------------------------
# Geometry helpers
# ----------------------------------------------------------------------------------------
def _to_right(calib: StereoCalibration, xyz: FloatArray) -> FloatArray:
    return np.asarray((calib.R @ xyz.T).T + calib.T, dtype=np.float64)


def _sphere_shapes(cam: CameraIntrinsics, xyz_cam: FloatArray, radius_mm: FloatArray) -> FloatArray:
    """2×2 maps (N×2×2) from the unit disc to the px image of spheres at ``xyz_cam``.

    The sphere subtends a disc of radius r/Z in normalised coordinates; it is mapped with
    the local Jacobian of the distorted projection (K with skew, eq. 2; distortion, eq. 7).
    """
    n = len(xyz_cam)
    out = np.zeros((n, 2, 2))
    if n == 0:
        return out
    xn = xyz_cam[:, 0] / xyz_cam[:, 2]
    yn = xyz_cam[:, 1] / xyz_cam[:, 2]
    h = 1e-5
    pts = []
    for ddx, ddy in ((h, 0.0), (-h, 0.0), (0.0, h), (0.0, -h)):
        pts.append(np.column_stack([xn + ddx, yn + ddy, np.ones(n)]))
    px = project_camera(cam, np.vstack(pts)).reshape(4, n, 2)
    jx = (px[0] - px[1]) / (2 * h)  # d(px)/d(xn)
    jy = (px[2] - px[3]) / (2 * h)  # d(px)/d(yn)
    rho = radius_mm / xyz_cam[:, 2]
    out[:, :, 0] = jx * rho[:, None]
    out[:, :, 1] = jy * rho[:, None]
    return out


def _in_frame(px: FloatArray, size: tuple[int, int]) -> NDArray[np.bool_]:
    w, h = size
    ok = np.all(np.isfinite(px), axis=1)
    with np.errstate(invalid="ignore"):
        ok &= (px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
    return np.asarray(ok, dtype=bool)


def _project_checked(
    calib: StereoCalibration, xyz: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Project; NaN where a point is behind (or within 1 mm of) a camera. Returns
    (left px, right px, left depth mm, right depth mm)."""
    zl = xyz[:, 2].copy()
    zr = _to_right(calib, xyz)[:, 2] if len(xyz) else np.zeros(0)
    pl, pr = project_stereo(calib, xyz) if len(xyz) else (np.zeros((0, 2)), np.zeros((0, 2)))
    pl = pl.copy()
    pr = pr.copy()
    pl[zl < _MIN_DEPTH_MM] = np.nan
    pr[zr < _MIN_DEPTH_MM] = np.nan
    return pl, pr, zl, zr


# ----------------------------------------------------------------------------------------
# Clutter
# ----------------------------------------------------------------------------------------
@dataclass
class _Clutter:
    left: list[_Blob] = field(default_factory=list)
    right: list[_Blob] = field(default_factory=list)
    left_px: list[FloatArray] = field(default_factory=list)
    right_px: list[FloatArray] = field(default_factory=list)
    xyz: list[FloatArray] = field(default_factory=list)
    second_left: FloatArray | None = None
    second_right: FloatArray | None = None


class _Keepout:
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


def _make_clutter(
    calib: StereoCalibration,
    settings: RenderSettings,
    rng: np.random.Generator,
    range_mm: float,
    keep_left: _Keepout,
    keep_right: _Keepout,
    gray_bgr: NDArray[np.float32],
) -> _Clutter:
    w, h = calib.image_size
    out = _Clutter()
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
            pl, pr, zl, zr = _project_checked(calib, xyz)
            in_l = bool(_in_frame(pl, calib.image_size)[0])
            in_r = bool(_in_frame(pr, calib.image_size)[0])
            if not (in_l or in_r):
                continue
            rad = np.array([0.5 * size_mm])
            al = _sphere_shapes(calib.left, xyz, rad)[0] if in_l else None
            ar = _sphere_shapes(calib.right, _to_right(calib, xyz), rad)[0] if in_r else None
            if al is not None and not keep_left.ok(pl[0], float(np.linalg.norm(al, 2))):
                continue
            if ar is not None and not keep_right.ok(pr[0], float(np.linalg.norm(ar, 2))):
                continue
            pk, col = peak(), tint()
            if al is not None:
                out.left.append(_Blob(pl[0], al, pk, col))
            if ar is not None:
                out.right.append(_Blob(pr[0], ar, pk, col))
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
            b = _Blob(p, np.eye(2) * r_px, peak(), tint())
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
            pl, pr, _, _ = _project_checked(calib, xyz)
            if not (_in_frame(pl, calib.image_size)[0] and _in_frame(pr, calib.image_size)[0]):
                continue
            ang = rng.uniform(0, math.pi)
            rot = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
            A = rot @ np.diag([15.0, 4.0])
            if not (keep_left.ok(pl[0], 15.0) and keep_right.ok(pr[0], 15.0)):
                continue
            pk, col = peak(), tint()
            out.left.append(_Blob(pl[0], A, pk, col))
            out.right.append(_Blob(pr[0], A, pk, col))
            out.second_left, out.second_right = pl[0], pr[0]
            break
    return out


# ----------------------------------------------------------------------------------------
# Hostile extras: LED-like glints, monocular glints, rim reflections
# ----------------------------------------------------------------------------------------
@dataclass
class _Extras:
    left: list[_Blob] = field(default_factory=list)
    right: list[_Blob] = field(default_factory=list)
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

    def __init__(self, blobs: list[_Blob]) -> None:
        self.p = [b.center_px for b in blobs]
        self.r = [_spectral_norm(b.shape_px) for b in blobs]

    def ok(self, p: FloatArray, r_px: float) -> bool:
        if not self.p:
            return True
        gaps = np.linalg.norm(np.array(self.p) - p, axis=1) - np.array(self.r) - r_px
        return bool(np.all(gaps >= _GLINT_GAP_PX))

    def add(self, p: FloatArray, r_px: float) -> None:
        self.p.append(p)
        self.r.append(r_px)


def _disc_inside(p: FloatArray, r_px: float, size: tuple[int, int]) -> bool:
    """The whole disc (plus 1 px) lies inside the image, so it is drawn unclipped."""
    w, h = size
    m = r_px + 1.0
    return bool(m <= p[0] <= w - 1 - m and m <= p[1] <= h - 1 - m)


def _make_extras(
    calib: StereoCalibration,
    settings: RenderSettings,
    ring: LedRing,
    rng: np.random.Generator,
    center: FloatArray,
    normal: FloatArray,
    roll_rad: float,
    keep: tuple[_Keepout, _Keepout] | None,
    clutter: _Clutter,
    led_bgr: NDArray[np.float32],
) -> _Extras:
    """Draw the hostile extras of ``settings`` (own random stream ``rng``)."""
    out = _Extras()
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
        lo, hi = settings.glint_depth_mm or tuple(f * range_mm for f in _GLINT_DEPTH_FACTORS)
        fl = 0.5 * (calib.left.fx + calib.left.fy)
        rad = np.array([r_led])
        for _ in range(settings.glints):  # LED-like 3-D glints, seen by both cameras
            for _try in range(_GLINT_TRIES):
                z = rng.uniform(lo, hi)
                u, v = rng.uniform(0, w - 1), rng.uniform(0, h - 1)
                xyz = np.array([[(u - calib.left.u0) / fl * z, (v - calib.left.v0) / fl * z, z]])
                pl, pr, _, _ = _project_checked(calib, xyz)
                if not (np.all(np.isfinite(pl)) and np.all(np.isfinite(pr))):
                    continue
                al = _sphere_shapes(calib.left, xyz, rad)[0]
                ar = _sphere_shapes(calib.right, _to_right(calib, xyz), rad)[0]
                rl, rr = _spectral_norm(al), _spectral_norm(ar)
                if not (_disc_inside(pl[0], rl, size) and _disc_inside(pr[0], rr, size)):
                    continue
                if not (keep_l.ok(pl[0], rl) and keep_r.ok(pr[0], rr)):
                    continue
                if not (occ_l.ok(pl[0], rl) and occ_r.ok(pr[0], rr)):
                    continue
                pk, col = peak(), colour()
                out.left.append(_Blob(pl[0], al, pk, col))
                out.right.append(_Blob(pr[0], ar, pk, col))
                occ_l.add(pl[0], rl)
                occ_r.add(pr[0], rr)
                out.glint_xyz.append(xyz[0])
                out.glint_left_px.append(pl[0])
                out.glint_right_px.append(pr[0])
                break

        # monocular glints: a disc of the LEDs' image radius at the drogue's depth
        z_r = max(float(_to_right(calib, center[None, :])[0, 2]), 100.0)
        mono_r = (
            0.5 * (calib.left.fx + calib.left.fy) * r_led / range_mm,
            0.5 * (calib.right.fx + calib.right.fy) * r_led / z_r,
        )
        for i in range(settings.mono_glints):
            left_side = i % 2 == 0
            keep_i, occ_i = (keep_l, occ_l) if left_side else (keep_r, occ_r)
            r_px = mono_r[0] if left_side else mono_r[1]
            for _try in range(_GLINT_TRIES):
                p = np.array([rng.uniform(0, w - 1), rng.uniform(0, h - 1)])
                if not (_disc_inside(p, r_px, size) and keep_i.ok(p, r_px) and occ_i.ok(p, r_px)):
                    continue
                b = _Blob(p, np.eye(2) * r_px, peak(), colour())
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
        pl, pr, _, _ = _project_checked(calib, xyz)
        in_l, in_r = _in_frame(pl, size), _in_frame(pr, size)
        rad = np.full(len(xyz), r_led)
        al = _sphere_shapes(calib.left, xyz, rad)
        ar = _sphere_shapes(calib.right, _to_right(calib, xyz), rad)
        for k in range(len(xyz)):
            if in_l[k]:
                out.left.append(_Blob(pl[k], al[k], settings.led_peak, led_bgr))
            if in_r[k]:
                out.right.append(_Blob(pr[k], ar[k], settings.led_peak, led_bgr))
        out.refl_xyz, out.refl_left_px, out.refl_right_px = xyz, pl, pr
    return out


# ----------------------------------------------------------------------------------------
# Public entry point
# ----------------------------------------------------------------------------------------
def render_pair(
    calib: StereoCalibration,
    center_mm: object,
    normal: object,
    settings: RenderSettings | None = None,
    ring: LedRing | None = None,
    seed: int | None = 0,
    roll_rad: float = 0.0,
    windows: tuple[Sequence[Rect], Sequence[Rect]] | None = None,
) -> RenderedPair:
    """Render the LED ring at (centre mm, normal) into both cameras of ``calib``.

    Deterministic for a given ``seed`` (``None`` → fresh randomness). LEDs behind a camera
    or outside an image are not drawn there (``truth.visible`` False); poses partly out of
    view never raise. Raises ValueError for a non-finite pose, a zero normal or bad ids.

    The hostile extras of ``settings`` (``glints``, ``mono_glints``, ``rim_reflections``)
    use a second random stream derived from ``seed``: with them off, the images are exactly
    those of a renderer without them; with them on, the LEDs, clutter and noise are
    unchanged and only the extras' own pixels differ.

    ``windows``: (left rectangles, right rectangles), each ``(x0, y0, x1, y1)`` px, half-open
    (a tracker's windows). Only those pixels are rendered — every random draw is still made,
    and only the blobs reaching a window are drawn — so inside them the images are
    bit-identical to the full render with the same seed; pixels outside are 0. The truth is
    the full render's. With ``fast_noise`` this costs only the windows' pixels.
    """
    settings = settings or RenderSettings()
    wins = None if windows is None else _check_windows(windows)
    ring = ring or LedRing()
    c, n = check_pose(center_mm, normal)
    if not math.isfinite(float(roll_rad)):
        raise ValueError(f"roll_rad must be finite, got {roll_rad}")
    bad = [i for i in settings.occluded if not 1 <= i <= ring.count]
    if bad:
        raise ValueError(f"occluded LED ids must be in 1..{ring.count}, got {bad}")
    bad = [i for i, _ in settings.rim_reflections if not 1 <= i <= ring.count]
    if bad:
        raise ValueError(f"rim_reflections LED ids must be in 1..{ring.count}, got {bad}")
    rng = np.random.default_rng(seed)

    xyz = ring_points(c, n, ring, roll_rad)
    ids = ring.ids.astype(np.int64)
    pl, pr, _, _ = _project_checked(calib, xyz)
    in_l = _in_frame(pl, calib.image_size)
    in_r = _in_frame(pr, calib.image_size)
    occ = np.isin(ids, np.array(settings.occluded, dtype=np.int64))
    draw_l, draw_r = in_l & ~occ, in_r & ~occ

    r_led = np.full(len(xyz), 0.5 * ring.led_diameter_mm)
    a_l = np.full((len(xyz), 2, 2), np.nan)
    a_r = np.full((len(xyz), 2, 2), np.nan)
    if np.any(in_l):
        a_l[in_l] = _sphere_shapes(calib.left, xyz[in_l], r_led[in_l])
    xyz_r = _to_right(calib, xyz)
    if np.any(in_r):
        a_r[in_r] = _sphere_shapes(calib.right, xyz_r[in_r], r_led[in_r])
    rad_l = np.array(
        [np.sqrt(abs(np.linalg.det(a))) if k else np.nan for a, k in zip(a_l, in_l, strict=True)]
    )
    rad_r = np.array(
        [np.sqrt(abs(np.linalg.det(a))) if k else np.nan for a, k in zip(a_r, in_r, strict=True)]
    )

    color = settings.color
    led_bgr = LED_BGR if color else np.ones(3, dtype=np.float32)
    gray_bgr = np.ones(3, dtype=np.float32)
    blobs_l = [_Blob(pl[k], a_l[k], settings.led_peak, led_bgr) for k in np.flatnonzero(draw_l)]
    blobs_r = [_Blob(pr[k], a_r[k], settings.led_peak, led_bgr) for k in np.flatnonzero(draw_r)]

    clutter = _Clutter()
    keep: tuple[_Keepout, _Keepout] | None = None
    glinting = settings.glints > 0 or settings.mono_glints > 0
    if settings.clutter > 0 or settings.second_object or glinting:
        cl, cr, _, _ = _project_checked(calib, c[None, :])
        keep_l = _Keepout(cl[0], pl, np.nan_to_num(rad_l, nan=0.0))
        keep_r = _Keepout(cr[0], pr, np.nan_to_num(rad_r, nan=0.0))
        keep = (keep_l, keep_r)
    if settings.clutter > 0 or settings.second_object:
        range_mm = max(float(c[2]), 100.0)
        clutter = _make_clutter(calib, settings, rng, range_mm, keep_l, keep_r, gray_bgr)

    extras = _Extras()
    if glinting or settings.rim_reflections:
        # own stream, so the main one (clutter, noise) is the same with or without extras
        rng_x = np.random.default_rng(None if seed is None else [int(seed), _EXTRAS_STREAM])
        extras = _make_extras(
            calib,
            settings,
            ring,
            rng_x,
            c,
            n,
            float(roll_rad),
            keep if glinting else None,
            clutter,
            led_bgr,
        )

    w, h = calib.image_size
    shape: tuple[int, ...] = (h, w, 3) if color else (h, w)
    win_l, win_r = (None, None) if wins is None else wins
    all_l = blobs_l + clutter.left + extras.left
    all_r = blobs_r + clutter.right + extras.right
    if wins is not None and settings.fast_noise:  # only the blobs that reach a window
        box = settings.blur_sigma_px
        r_l, r_r = _clip_rects(win_l or [], shape), _clip_rects(win_r or [], shape)
        all_l = [b for b in all_l if _overlaps(_patch_box(b, box), r_l)]
        all_r = [b for b in all_r if _overlaps(_patch_box(b, box), r_r)]
    # the patches of both images in one batch (bit-identical to separate calls)
    made = _blob_patches(all_l + all_r, settings.supersample, settings.blur_sigma_px)
    pts = [(x0, y0, p, b.bgr) for (x0, y0, p), b in zip(made, all_l + all_r, strict=True)]
    left = _compose(shape, all_l, settings, rng, win_l, pts[: len(all_l)])
    right = _compose(shape, all_r, settings, rng, win_r, pts[len(all_l) :])

    def rows(items: list[FloatArray], dim: int) -> FloatArray:
        return np.array(items, dtype=np.float64).reshape(-1, dim)

    truth = RenderTruth(
        led_xyz_mm=xyz,
        led_ids=ids,
        visible=draw_l & draw_r,
        led_left_px=pl,
        led_right_px=pr,
        center_mm=c,
        normal=n,
        radius_mm=float(ring.radius_mm),
        clutter_left_px=rows(clutter.left_px, 2),
        clutter_right_px=rows(clutter.right_px, 2),
        in_left=draw_l,
        in_right=draw_r,
        led_left_radius_px=rad_l,
        led_right_radius_px=rad_r,
        clutter_xyz_mm=rows(clutter.xyz, 3),
        second_object_left_px=clutter.second_left,
        second_object_right_px=clutter.second_right,
        roll_rad=float(roll_rad),
        glint_xyz_mm=rows(extras.glint_xyz, 3),
        glint_left_px=rows(extras.glint_left_px, 2),
        glint_right_px=rows(extras.glint_right_px, 2),
        mono_glint_left_px=rows(extras.mono_left_px, 2),
        mono_glint_right_px=rows(extras.mono_right_px, 2),
        reflection_xyz_mm=rows(list(extras.refl_xyz), 3),
        reflection_left_px=rows(list(extras.refl_left_px), 2),
        reflection_right_px=rows(list(extras.refl_right_px), 2),
    )
    return RenderedPair(left=left, right=right, truth=truth)
