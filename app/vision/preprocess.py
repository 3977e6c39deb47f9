"""Image preprocessing (paper §4.1): graying (eq. 9), binarisation (eq. 10), median filter."""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from app.types import UInt8Array
from app.vision.preprocess_kernels import difference_histogram, subsampled_histogram

ThresholdMode = Literal["auto", "otsu"] | int


class ImageError(ValueError):
    """An input image that cannot be processed (wrong type, shape or size)."""


def validate_image(image: object, name: str = "image") -> UInt8Array:
    """Check that ``image`` is a non-empty uint8 gray (H×W) or colour (H×W×3/4) array."""
    if not isinstance(image, np.ndarray):
        raise ImageError(f"{name}: expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ImageError(f"{name}: expected dtype uint8, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] not in (3, 4):
        raise ImageError(f"{name}: expected 1, 3 or 4 channels, got {image.shape[2]}")
    if image.ndim not in (2, 3):
        raise ImageError(f"{name}: expected a 2-D gray or 3-D colour image, got {image.ndim}-D")
    if image.shape[0] < 16 or image.shape[1] < 16:
        raise ImageError(f"{name}: image too small ({image.shape[1]}×{image.shape[0]} px)")
    # row-major (a view, e.g. one channel of H×W×1 or a strided crop, is copied): the
    # compiled loops are prepared for C-contiguous images
    return np.ascontiguousarray(image)


def to_gray(image: UInt8Array) -> UInt8Array:
    """Eq. 9: Gray = 0.299 R + 0.587 G + 0.114 B (BGR channel order); gray passes through."""
    if image.ndim == 2:
        return image
    if image.shape[2] == 4:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), dtype=np.uint8)
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), dtype=np.uint8)


ColourDetect = Literal["gray", "green"]


def green_excess(image: UInt8Array, saturated_dn: int = 250) -> UInt8Array:
    """The LED image of a colour frame: G − max(B, R) per pixel (clipped at 0; DN), and 255
    where all three channels are saturated (a core with no colour left). The LEDs are green
    (paper §3.1): their light stands out here while white or yellow sun glints, grey metal,
    canopy and sky vanish (a glint's fully saturated core stays as a small blob; its white
    flanks fail the colour test). In a sunlit frame a green LED can be no brighter than the
    sky in eq. 9's gray, so gray alone misses it."""
    b, g, r = cv2.split(image[:, :, :3])
    brighter = cv2.max(b, r)
    excess = cv2.subtract(g, brighter)
    _, sat = cv2.threshold(cv2.min(g, brighter), saturated_dn - 1, 255, cv2.THRESH_BINARY)
    return np.asarray(cv2.max(excess, sat), dtype=np.uint8)


def detection_image(image: UInt8Array, mode: ColourDetect = "green") -> UInt8Array:
    """The single-channel image the LEDs are found and measured on: a gray frame as it is; a
    colour frame by eq. 9 (``"gray"``, the paper) or :func:`green_excess` (``"green"``)."""
    if image.ndim == 2 or mode == "gray":
        return to_gray(image)
    return green_excess(image)


def local_contrast(gray: UInt8Array, kernel_px: int) -> UInt8Array:
    """Each pixel's excess over its surroundings: the white top-hat I − open(I) with a
    ``kernel_px`` square (DN). A spot narrower than the kernel keeps its height above the
    darker ground around it (an LED in its black bezel: ≈ 150 DN), while a bright area
    wider than the kernel (a sunlit sky, the drogue's lit canopy) drops to 0: the LEDs of a
    sunlit drogue that are no brighter than the sky, which eq. 10's global threshold cannot
    separate from it, stand out here. Thin bright lines (a polished rim) stay, and the
    blob gate's shape tests refuse them."""
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (kernel_px, kernel_px))
    return np.asarray(cv2.morphologyEx(gray, cv2.MORPH_TOPHAT, kernel), dtype=np.uint8)


BACKGROUND_ROW_STEP = 8  # the background's subsample: every 8th row ...
BACKGROUND_COL_STEP = 4  # ... and every 4th column (1/32 of the pixels)


def noise_sigma(gray: UInt8Array) -> float:
    """The pixel noise σ (DN) of an image, robust to the scene: 1.4826·median|ΔI|/√2 of the
    differences of horizontally neighbouring pixels (every 8th row, every 4th column), the
    median interpolated within its integer bin; at least 0.5 DN. On a flat background it is
    the MAD σ of :func:`background_level`; on a sunlit scene (sky gradients, canopy, metal)
    it stays the sensor's noise where the MAD of the values measures the scene."""
    return noise_from_histogram(
        difference_histogram(gray, BACKGROUND_ROW_STEP, BACKGROUND_COL_STEP)
    )


def noise_from_histogram(hist: np.ndarray) -> float:
    """:func:`noise_sigma` from the 256-bin histogram of the differences |ΔI| (DN)."""
    total = float(hist.sum())
    if total == 0:
        return 0.5
    cdf = np.cumsum(hist)
    half = 0.5 * total
    k = int(np.searchsorted(cdf, half))
    below = float(cdf[k - 1]) if k > 0 else 0.0
    frac = (half - below) / max(float(hist[k]), 1.0)
    median = 0.5 * frac if k == 0 else k - 0.5 + frac
    return max(1.4826 * median / np.sqrt(2.0), 0.5)


def background_from_histogram(hist: np.ndarray) -> tuple[float, float]:
    """Robust background level and noise σ (DN) of a 256-bin histogram: the median and
    1.4826·MAD, both read off the histogram (no sort)."""
    half = hist.sum() / 2.0
    med = int(np.searchsorted(np.cumsum(hist), half))
    # histogram of |x − med|: fold the histogram about the median
    dev = np.zeros(256, dtype=np.int64)
    dev[0] = hist[med]
    up = hist[med + 1 :]
    down = hist[:med][::-1]
    dev[1 : 1 + len(up)] += up
    dev[1 : 1 + len(down)] += down
    mad = int(np.searchsorted(np.cumsum(dev), half))
    return float(med), max(1.4826 * mad, 0.5)


def background_level(gray: UInt8Array) -> tuple[float, float]:
    """Robust background level and noise σ (DN) from a 1/32 subsample (every 8th row, every 4th
    column: one eighth of the memory traffic): :func:`background_from_histogram`."""
    hist = subsampled_histogram(gray, BACKGROUND_ROW_STEP, BACKGROUND_COL_STEP)
    return background_from_histogram(hist)


def choose_threshold(
    gray: UInt8Array,
    mode: ThresholdMode = "auto",
    background: tuple[float, float] | None = None,
    peak: float | None = None,
) -> int:
    """Threshold T_s of eq. 10 (DN).

    * an ``int``: fixed threshold (the paper's choice);
    * ``"otsu"``: Otsu's method (OpenCV);
    * ``"auto"``: T = bg + max(0.25·(peak − bg), 6σ) above the robust background level,
      robust when the LEDs cover < 0.1 % of the frame (where Otsu drifts into the noise)
      and low enough (a quarter of the peak) that a 2-px LED at 5 m survives the median filter.

    ``background`` is ``background_level(gray)`` and ``peak`` the image's maximum (DN) if the
    caller already has them.
    """
    if isinstance(mode, bool) or not isinstance(mode, int | str):
        raise ValueError(f"threshold must be an int 1..255, 'auto' or 'otsu', got {mode!r}")
    if isinstance(mode, int):
        if not 1 <= mode <= 255:
            raise ValueError(f"threshold must be in 1..255, got {mode}")
        return mode
    if mode == "otsu":
        t, _ = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        return max(int(t), 1)
    if mode == "auto":
        bg, sigma = background if background is not None else background_level(gray)
        if peak is None:
            peak = float(cv2.minMaxLoc(gray)[1])
        return auto_threshold(bg, sigma, peak)
    raise ValueError(f"threshold must be an int 1..255, 'auto' or 'otsu', got {mode!r}")


def auto_threshold(background: float, sigma: float, peak: float) -> int:
    """Eq. 10's "auto" threshold T = bg + max(0.25·(peak − bg), 6σ), clipped to 1..255 (DN)."""
    t = round(background + max(0.25 * (peak - background), 6.0 * sigma))
    return int(min(255, max(1, t)))


def binarize(gray: UInt8Array, threshold: int) -> UInt8Array:
    """Eq. 10: 255 where I ≥ T_s, else 0."""
    _, out = cv2.threshold(gray, threshold - 1, 255, cv2.THRESH_BINARY)  # > T−1 ⇔ ≥ T
    return np.asarray(out, dtype=np.uint8)


def median_filter(binary: UInt8Array, ksize: int = 3) -> UInt8Array:
    """Median filter removing the granular noise and jagged LED edges (§4.1 (3))."""
    if ksize <= 1:
        return binary
    return np.asarray(cv2.medianBlur(binary, ksize), dtype=np.uint8)
