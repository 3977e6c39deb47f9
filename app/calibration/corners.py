"""Checkerboard corners in one image (paper §3.2: the CCP pictures of Zhang's method).

Detection per image (:func:`detect_corners_detail`) tries, in order, until one finds the
whole grid:

1. ``cv2.findChessboardCorners`` (the classic quad detector, adaptive threshold) — fast;
2. ``cv2.findChessboardCornersSB`` (plain), then ``findChessboardCornersSB`` with
   ``CALIB_CB_EXHAUSTIVE`` — slower, finds boards the classic detector misses (blur, low
   contrast, partly lit).

Every found grid is refined in two steps (:func:`refine_subpix`): ``cv2.cornerSubPix`` over a
window sized to the board's square in the image (half-window ``round(0.25 · min corner
spacing)`` px, clipped to [2, 11]; a corner that moves by more than half a square is refused
and the next detector tried), then a saddle-point fit (:func:`refine_saddle`: a quadratic
surface fitted to the lightly smoothed image around each corner; skipped for squares under
``SADDLE_MIN_SPACING_PX``). The choice was measured (``benchmarks/bench_calibration.py``,
docs/calibration.md): on Bouguet's real stereo photographs it gives the lowest stereo RMS and
held-out scale residual (0.19 px, 0.14 mm) and lands within 0.08 % of the published focal
lengths, where ``findChessboardCornersSB``'s own corners (with or without
``CALIB_CB_ACCURACY``) are 0.4 % off and a fixed 11 px half-window makes corners jump by
several px; on the rendered sample set it gives 0.03 px RMS against the true corners and
focal lengths within 0.002 % (``cornerSubPix`` alone: +0.03 %).

Stereo pairs and the process pool are :mod:`app.calibration.detection`. Pure numpy/OpenCV;
bad input raises :class:`~app.calibration.board.CheckerboardError`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.calibration.board import CheckerboardError
from app.types import FloatArray

SUBPIX_FRACTION = 0.25  # cornerSubPix half-window / smallest corner spacing (px / px)
SUBPIX_HALF_RANGE = (2, 11)  # px
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
SADDLE_FRACTION = 0.2  # saddle-fit half-window / smallest corner spacing
SADDLE_SIGMA_PX = 1.0  # smoothing before the saddle fit (px)
SADDLE_MIN_SPACING_PX = 15.0  # smaller squares: cornerSubPix only (measured, see docs)
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
METHODS = ("classic", "sb", "sb-exhaustive")
REFINE_MODES = ("saddle", "subpix", "none")


def to_gray(image: NDArray[Any]) -> NDArray[np.uint8]:
    """8-bit grey from grey/BGR/BGRA (uint8 or uint16) input."""
    img = np.asarray(image)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise CheckerboardError(f"images must be 8- or 16-bit, got {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2:
        raise CheckerboardError(f"unsupported image shape {img.shape}")
    return np.ascontiguousarray(img)


def corner_spacing_px(corners: FloatArray, pattern_size: tuple[int, int]) -> float:
    """Smallest distance between neighbouring corners of a row-major grid (px)."""
    grid = np.asarray(corners, dtype=np.float64).reshape(pattern_size[1], pattern_size[0], 2)
    return min(
        float(np.min(np.linalg.norm(np.diff(grid, axis=1), axis=2))),
        float(np.min(np.linalg.norm(np.diff(grid, axis=0), axis=2))),
    )


def subpix_half_window(spacing_px: float) -> int:
    """cornerSubPix half-window for a grid whose smallest corner spacing is ``spacing_px``."""
    lo, hi = SUBPIX_HALF_RANGE
    return int(np.clip(round(SUBPIX_FRACTION * spacing_px), lo, hi))


def refine_subpix(
    gray: NDArray[np.uint8],
    corners: FloatArray,
    pattern_size: tuple[int, int],
    refine: str = "saddle",
) -> FloatArray | None:
    """``cornerSubPix`` with the window of :func:`subpix_half_window`, then (``refine`` =
    ``"saddle"``, the default) :func:`refine_saddle`; ``"subpix"``: cornerSubPix only;
    ``"none"``: the detector's corners as they are. None if a corner moved by more than half
    the corner spacing (it jumped to another corner or an edge)."""
    if refine not in REFINE_MODES:
        raise CheckerboardError(f"unknown refinement {refine!r}; expected one of {REFINE_MODES}")
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    spacing = corner_spacing_px(pts, pattern_size)
    if refine == "none":
        return pts
    if not spacing > 2.0:
        return None
    half = subpix_half_window(spacing)
    refined = cv2.cornerSubPix(
        gray, pts.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), SUBPIX_CRITERIA
    )
    out = np.asarray(refined, dtype=np.float64).reshape(-1, 2)
    if float(np.max(np.linalg.norm(out - pts, axis=1))) > 0.5 * spacing:
        return None
    if refine == "saddle" and spacing >= SADDLE_MIN_SPACING_PX:
        return refine_saddle(gray, out, spacing)
    return out


def refine_saddle(
    gray: NDArray[np.uint8], corners: FloatArray, spacing_px: float, iterations: int = 3
) -> FloatArray:
    """Saddle-point refinement: fit ``z = a·x² + b·xy + c·y² + d·x + e·y + f`` (Gaussian
    weighted, half-window ``SADDLE_FRACTION`` × spacing, ≥ 2 px) to the image smoothed with
    σ = ``SADDLE_SIGMA_PX`` around each corner and move the corner to the fitted saddle.
    A step that leaves the window or a fit that is not a saddle keeps the corner as it was.

    Measured (docs/calibration.md): ``cornerSubPix`` alone biases the focal lengths of the
    rendered sample set by +0.03 % (LED error 0.31 mm at 1 m); this step brings it to
    < 0.01 % (0.05 mm) and keeps Bouguet's real set within 0.08 % of the published values."""
    half = max(2, int(round(SADDLE_FRACTION * spacing_px)))
    out = np.asarray(corners, dtype=np.float64).reshape(-1, 2).copy()
    # smooth only the board's bounding box (+ window + kernel margin)
    pad = 2 * half + int(4 * SADDLE_SIGMA_PX) + 2
    h, w = gray.shape[:2]
    x0 = int(max(0, np.floor(out[:, 0].min()) - pad))
    y0 = int(max(0, np.floor(out[:, 1].min()) - pad))
    x1 = int(min(w, np.ceil(out[:, 0].max()) + pad + 1))
    y1 = int(min(h, np.ceil(out[:, 1].max()) + pad + 1))
    img = cv2.GaussianBlur(gray[y0:y1, x0:x1].astype(np.float32), (0, 0), SADDLE_SIGMA_PX)
    origin = np.array([x0, y0], dtype=np.float64)
    out -= origin
    yy, xx = np.mgrid[-half : half + 1, -half : half + 1].astype(np.float64)
    x, y = xx.ravel(), yy.ravel()
    w = np.exp(-(x**2 + y**2) / (2 * (half / 1.5) ** 2))
    A = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    fit = np.linalg.solve(A.T @ (A * w[:, None]), (A * w[:, None]).T)  # (6, P)
    n, side = len(out), 2 * half + 1
    for _ in range(iterations):
        mx = (out[:, 0, None, None] + xx[None]).reshape(n * side, side).astype(np.float32)
        my = (out[:, 1, None, None] + yy[None]).reshape(n * side, side).astype(np.float32)
        patches = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        a, b, c, d, e, _ = fit @ patches.reshape(n, side * side).astype(np.float64).T
        det = 4 * a * c - b * b
        ok = det < -1e-12  # a saddle: the Hessian [[2a, b], [b, 2c]] is indefinite
        safe = np.where(ok, det, -1.0)
        step = np.column_stack([(b * e - 2 * c * d) / safe, (b * d - 2 * a * e) / safe])
        ok &= np.hypot(step[:, 0], step[:, 1]) < 0.5 * half
        out[ok] += step[ok]
    return out + origin


def _find(gray: NDArray[np.uint8], pattern_size: tuple[int, int], method: str) -> Any:
    if method == "classic":
        ok, c = cv2.findChessboardCorners(gray, pattern_size, flags=CLASSIC_FLAGS)
    elif method == "sb":
        ok, c = cv2.findChessboardCornersSB(gray, pattern_size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
    elif method == "sb-exhaustive":
        ok, c = cv2.findChessboardCornersSB(
            gray, pattern_size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE
        )
    else:
        raise CheckerboardError(f"unknown detector {method!r}; expected one of {METHODS}")
    if not ok or c is None or len(c) != pattern_size[0] * pattern_size[1]:
        return None
    return c


@dataclass(frozen=True)
class CornerResult:
    """Refined corners (N×2 px, row-major; pixel centres at integers) and the detector used."""

    corners: FloatArray
    method: str


def detect_corners_detail(
    image: NDArray[Any],
    pattern_size: tuple[int, int],
    methods: Sequence[str] = METHODS,
    refine: str = "saddle",
) -> CornerResult | None:
    """Try the detectors of ``methods`` in order; the first grid that survives the sub-pixel
    refinement (:func:`refine_subpix` with ``refine``) is returned. If every grid found was refused by the
    refinement (tiny squares), the first one is returned unrefined (method ``"<name>-raw"``);
    None if no detector finds the board."""
    gray = to_gray(image)
    first_raw: CornerResult | None = None
    for method in methods:
        c = _find(gray, pattern_size, method)
        if c is None:
            continue
        refined = refine_subpix(gray, c, pattern_size, refine)
        if refined is not None:
            return CornerResult(refined, method)
        if first_raw is None:
            raw = np.asarray(c, dtype=np.float64).reshape(-1, 2)
            first_raw = CornerResult(raw, f"{method}-raw")
    return first_raw


def detect_corners(
    image: NDArray[Any], pattern_size: tuple[int, int], methods: Sequence[str] = METHODS
) -> FloatArray | None:
    """Inner corners (N×2, px, row-major) or None if not found (:func:`detect_corners_detail`)."""
    res = detect_corners_detail(image, pattern_size, methods)
    return None if res is None else res.corners


def suggest_board(image: NDArray[Any], pattern_size: tuple[int, int]) -> tuple[int, int] | None:
    """A nearby inner-corner count that *is* found in ``image`` (to explain a wrong --board)."""
    gray = to_gray(image)
    small = cv2.resize(gray, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    c, r = pattern_size
    candidates = [(c - 1, r - 1), (c + 1, r + 1), (c - 1, r), (c, r - 1), (c + 1, r), (c, r + 1)]
    candidates += [(c - 2, r - 2), (c + 2, r + 2)]
    for cand in candidates:
        if min(cand) < 3 or cand[0] == cand[1]:
            continue
        ok, _ = cv2.findChessboardCornersSB(small, cand, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            return cand
    return None
