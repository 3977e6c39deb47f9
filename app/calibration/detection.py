"""Checkerboard corners in every image of a set of stereo pairs (:func:`detect_pairs`).

Two passes: the classic detector on every image, then the SB fallbacks on the images it missed
(:mod:`app.calibration.corners`). Images are processed in parallel (a ``spawn`` process pool)
when the estimated work is large enough to pay for starting the workers; a tqdm bar shows the
progress on request. The right grid is put in the left grid's corner order
(:func:`match_orientation`); the rig check of :mod:`app.calibration.rig_consistency` verifies
it.

Pure numpy/OpenCV; bad input raises :class:`~app.calibration.board.CheckerboardError`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.calibration.board import CheckerboardError
from app.calibration.corners import METHODS, CornerResult, detect_corners_detail
from app.types import FloatArray

# rough cost of one detector pass, ns per pixel (measured here on 640x480 and 1280x1024):
# classic ≈ 3, SB ≈ 120; used only to decide whether a process pool pays off
_NS_PER_PX = {"classic": 3.0, "fallback": 250.0}
POOL_MIN_WORK_S = 1.5  # estimated single-process work above which images go to a pool


def match_orientation(left: FloatArray, right: FloatArray) -> FloatArray:
    """``right`` in the corner order that matches ``left``: the grid is 180°-ambiguous, and on
    a near-parallel rig the right corners are the left ones shifted by a smoothly varying
    disparity (the rig check of :mod:`app.calibration.rig_consistency` verifies it)."""
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
