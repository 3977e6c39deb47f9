"""Checkerboard corners in stereo pairs (paper §3.2: the CCP pictures of Zhang's method).

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

Images are processed in parallel (a ``spawn`` process pool) when the estimated work is
large enough to pay for starting the workers (:func:`detect_pairs`).

This module is pure (numpy/OpenCV); bad input raises :class:`CheckerboardError`.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import FloatArray

SUBPIX_FRACTION = 0.25  # cornerSubPix half-window / smallest corner spacing (px / px)
SUBPIX_HALF_RANGE = (2, 11)  # px
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
SADDLE_FRACTION = 0.2  # saddle-fit half-window / smallest corner spacing
SADDLE_SIGMA_PX = 1.0  # smoothing before the saddle fit (px)
SADDLE_MIN_SPACING_PX = 15.0  # smaller squares: cornerSubPix only (measured, see docs)
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
# rough cost of one detector pass, ns per pixel (measured here on 640x480 and 1280x1024):
# classic ≈ 3, SB ≈ 120; used only to decide whether a process pool pays off
_NS_PER_PX = {"classic": 3.0, "fallback": 250.0}
POOL_MIN_WORK_S = 1.5  # estimated single-process work above which images go to a pool
METHODS = ("classic", "sb", "sb-exhaustive")
REFINE_MODES = ("saddle", "subpix", "none")


class CheckerboardError(ValueError):
    """A checkerboard set cannot be calibrated; the message says why, in one line."""


# ---------------------------------------------------------------------------------------
# board description
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Board:
    """``cols`` × ``rows`` inner corners (OpenCV's patternSize), squares of ``square_mm``."""

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise CheckerboardError(
                f"board {self.cols}x{self.rows}: need at least 3x3 inner corners "
                "(the board size counts inner corners, i.e. squares - 1)"
            )
        if self.cols == self.rows:
            raise CheckerboardError(
                f"board {self.cols}x{self.rows}: a square board's orientation is ambiguous; "
                "use a board with different inner-corner counts per row and column"
            )
        if not (math.isfinite(self.square_mm) and self.square_mm > 0):
            raise CheckerboardError(
                f"square size must be a positive number of mm, got {self.square_mm}"
            )

    @property
    def pattern_size(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    def object_points(self) -> NDArray[np.float32]:
        """Inner corners in the board frame (N×3, mm), row-major: corner (i, j) at (i·s, j·s, 0)."""
        jj, ii = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.column_stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)]) * self.square_mm
        return pts.astype(np.float32)


def parse_board(text: str) -> tuple[int, int]:
    """``"9x6"`` → (9, 6) inner corners per row × per column."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX×*,]\s*(\d+)\s*", str(text))
    if not m:
        raise CheckerboardError(f"board {text!r}: expected COLSxROWS inner corners, e.g. 9x6")
    return int(m.group(1)), int(m.group(2))


def pair_name(left_file: str, right_file: str) -> str:
    """Short name of a stereo pair from its file names: ``left_03.png``/``right_03.png`` → ``03``."""
    ls, rs = Path(left_file).stem, Path(right_file).stem
    for lp, rp in (("left", "right"), ("l", "r")):
        if ls.lower().startswith(lp) and rs.lower().startswith(rp):
            rest_l, rest_r = ls[len(lp) :], rs[len(rp) :]
            if rest_l == rest_r and rest_l.strip("_-. "):
                return rest_l.strip("_-. ")
    return ls if ls == rs else f"{ls}|{rs}"


# ---------------------------------------------------------------------------------------
# corner detection
# ---------------------------------------------------------------------------------------
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


def match_orientation(left: FloatArray, right: FloatArray) -> FloatArray:
    """``right`` in the corner order that matches ``left``: the grid is 180°-ambiguous, and on
    a near-parallel rig the right corners are the left ones shifted by a smoothly varying
    disparity (the rig check of :mod:`app.geometry.stereo_calibrate` verifies it)."""
    flipped = right[::-1]
    spread = float(np.var(right - left, axis=0).sum())
    spread_f = float(np.var(flipped - left, axis=0).sum())
    return flipped.copy() if spread_f < spread else right


@dataclass
class PairDetection:
    """Corners found in one stereo pair (None where not found) and why a pair is unusable.

    ``left_method``/``right_method``: the detector that found each grid (``METHODS``);
    ``rejected``: set when the two grids are not the same physical corners (rig check)."""

    name: str
    image_size: tuple[int, int]  # (w, h) px
    left: FloatArray | None
    right: FloatArray | None
    left_method: str | None = None
    right_method: str | None = None
    rejected: str | None = None

    @property
    def usable(self) -> bool:
        return self.left is not None and self.right is not None and self.rejected is None

    @property
    def reason(self) -> str | None:
        if self.usable:
            return None
        if self.rejected is not None:
            return self.rejected
        if self.left is None and self.right is None:
            return "board not found in either image"
        if self.left is None:
            return "board found in the right image only"
        return "board found in the left image only"


def image_size_of(image: NDArray[Any]) -> tuple[int, int]:
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise CheckerboardError(f"not an image (array shape {arr.shape})")
    return (int(arr.shape[1]), int(arr.shape[0]))


def check_image_sizes(
    names: Sequence[str], lefts: Sequence[NDArray[Any]], rights: Sequence[NDArray[Any]]
) -> tuple[int, int]:
    """All images must share one size; returns it (w, h) or raises with the first offender."""
    if len(lefts) != len(rights):
        raise CheckerboardError(f"{len(lefts)} left images but {len(rights)} right images")
    if not lefts:
        raise CheckerboardError("no images given")
    ref = image_size_of(lefts[0])
    for name, li, ri in zip(names, lefts, rights, strict=True):
        for side, img in (("left", li), ("right", ri)):
            size = image_size_of(img)
            if size != ref:
                raise CheckerboardError(
                    f"image sizes differ: {side} image of pair {name} is {size[0]}x{size[1]} px, "
                    f"the first left image is {ref[0]}x{ref[1]} px"
                )
    return ref


def _detect_task(
    task: tuple[NDArray[Any], tuple[int, int], tuple[str, ...]],
) -> CornerResult | None:
    image, pattern_size, methods = task
    return detect_corners_detail(image, pattern_size, methods)


def _run_tasks(
    tasks: list[tuple[NDArray[Any], tuple[int, int], tuple[str, ...]]],
    workers: int,
    bar: Any,
) -> list[CornerResult | None]:
    """Run detection tasks, in a spawn process pool when ``workers`` > 1."""
    if workers <= 1 or len(tasks) <= 1:
        out = []
        for t in tasks:
            out.append(_detect_task(t))
            if bar is not None:
                bar.update(1)
        return out
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    results: list[CornerResult | None] = [None] * len(tasks)
    done = [False] * len(tasks)
    ctx = multiprocessing.get_context("spawn")
    try:
        with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=ctx) as pool:
            futures = {pool.submit(_detect_task, t): k for k, t in enumerate(tasks)}
            for fut in as_completed(futures):
                k = futures[fut]
                results[k], done[k] = fut.result(), True
                if bar is not None:
                    bar.update(1)
    except (BrokenProcessPool, OSError, RuntimeError):
        # no worker could start (e.g. a script without ``if __name__ == "__main__"`` under
        # spawn, or no process slots left): finish in this process
        for k, t in enumerate(tasks):
            if not done[k]:
                results[k] = _detect_task(t)
                if bar is not None:
                    bar.update(1)
    return results


def _pool_workers(n_px: float, ns_per_px: float, workers: int | None) -> int:
    """Worker count for a pass: ``workers`` if given, else the CPU count when the estimated
    single-process time exceeds :data:`POOL_MIN_WORK_S` (a spawn worker costs ≈ 0.5 s)."""
    if workers is not None:
        return max(1, int(workers))
    cpus = os.cpu_count() or 1
    if cpus < 2 or n_px * ns_per_px * 1e-9 < POOL_MIN_WORK_S:
        return 1
    return min(cpus, 8)


def detect_pairs(
    names: Sequence[str],
    lefts: Sequence[NDArray[Any]],
    rights: Sequence[NDArray[Any]],
    pattern_size: tuple[int, int],
    progress: bool = False,
    workers: int | None = None,
) -> list[PairDetection]:
    """Detect the board in every image of every pair (sizes checked first).

    Two passes: the classic detector on every image, then the SB fallbacks on the images it
    missed. Each pass runs in a spawn process pool when its estimated work pays for the
    workers' start (``workers``: force a count; 1 = in this process). ``progress``: a tqdm
    bar on stderr (one step per image and pass)."""
    size = check_image_sizes(names, lefts, rights)
    images = [img for pair in zip(lefts, rights, strict=True) for img in pair]
    px = float(size[0] * size[1])
    bar: Any = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(images), desc="corners", unit="img")
    try:
        first = _run_tasks(
            [(img, pattern_size, ("classic",)) for img in images],
            _pool_workers(px * len(images), _NS_PER_PX["classic"], workers),
            bar,
        )
        missed = [k for k, r in enumerate(first) if r is None]
        if bar is not None and missed:
            bar.total += len(missed)
            bar.refresh()
        second = _run_tasks(
            [(images[k], pattern_size, METHODS[1:]) for k in missed],
            _pool_workers(px * len(missed), _NS_PER_PX["fallback"], workers),
            bar,
        )
    finally:
        if bar is not None:
            bar.close()
    found = list(first)
    for k, r in zip(missed, second, strict=True):
        found[k] = r
    out: list[PairDetection] = []
    for i, name in enumerate(names):
        rl, rr = found[2 * i], found[2 * i + 1]
        cl = None if rl is None else rl.corners
        cr = None if rr is None else rr.corners
        if cl is not None and cr is not None:
            cr = match_orientation(cl, cr)
        out.append(
            PairDetection(
                name,
                size,
                cl,
                cr,
                None if rl is None else rl.method,
                None if rr is None else rr.method,
            )
        )
    return out


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
