"""What a stereo render is asked for and what it returns: the image formation settings
(:class:`RenderSettings`, DN = 8-bit grey levels), the exact ground truth of a rendered pair
(:class:`RenderTruth`: left camera frame mm, distorted pixels px) and the pair itself
(:class:`RenderedPair`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.types import FloatArray

# (B, G, R) weights of an LED seen through the green filter (mostly green).
LED_BGR = np.array([0.45, 1.0, 0.30], dtype=np.float32)
MIN_DEPTH_MM = 1.0  # nearer than this to a camera (mm) a point is not projected


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
    if not (math.isfinite(lo) and math.isfinite(hi) and MIN_DEPTH_MM <= lo <= hi):
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
