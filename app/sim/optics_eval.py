"""Scoring the navigation pipeline on the physically based optics set (:mod:`app.sim.optics_set`).

Each case is run through a fresh :class:`~app.vision.pipeline.NavigationPipeline` for a few
sensor-noise seeds and compared with the render's truth:

* **error**: each reported LED against the nearest true LED (mm, 3-D), the drogue centre
  against the true centre (mm);
* **wrong lock**: a lock whose centre or any LED is off by more than ``allowance_mm`` —
  max(10 mm, 1 % of the range); **loose**: beyond ``strict_mm`` — 5 mm within 2.5 m, 0.5 % of
  the range past it;
* **bound**: whether the true errors lie inside the lock's reported 99.9 % protection levels
  (:mod:`app.geometry.uncertainty`), when the result carries them.

The **baseline** is the plain local centroid at its best: for each *visible* LED (truth tells
which, and where: an oracle association no real system has), the pixels above half the blob's
own peak over its local background in a window around the true projection, weighted by their
brightness above that background, undistorted and triangulated with OpenCV only
(``cv2.undistortPoints``, ``cv2.triangulatePoints``; the skew removed by hand).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import CameraIntrinsics, StereoCalibration
from app.geometry.projection import project_stereo
from app.model.pose import PoseResult
from app.sim.optics_set import OpticsCase, sensor_pair
from app.types import FloatArray
from app.vision.pipeline import NavigationPipeline, PipelineConfig


def allowance_mm(range_mm: float) -> float:
    """The error beyond which a lock is wrong: max(10 mm, 1 % of the range)."""
    return max(10.0, 0.01 * range_mm)


def strict_mm(range_mm: float) -> float:
    """The error beyond which a lock is loose: 5 mm within 2.5 m, 0.5 % of the range past it."""
    return 5.0 if range_mm <= 2500.0 else 0.005 * range_mm


@dataclass(frozen=True)
class OpticsOutcome:
    """One case × noise seed: the pipeline's verdict and its errors against truth (mm)."""

    case: str
    condition: str
    sensor: str
    range_mm: float
    seed: int
    lock: bool
    reason: str | None
    led_errors_mm: tuple[float, ...]  # each reported LED vs the nearest true LED
    center_error_mm: float  # NaN without a lock
    baseline_errors_mm: tuple[float, ...]  # the OpenCV local-centroid baseline, visible LEDs
    # reported 99.9 % protection levels (mm): the centre, each LED; NaN where not reported
    center_pl_mm: float = float("nan")
    led_pl_mm: tuple[float, ...] = ()

    @property
    def worst_mm(self) -> float:
        return max((self.center_error_mm, *self.led_errors_mm)) if self.lock else float("nan")

    @property
    def wrong(self) -> bool:
        return self.lock and self.worst_mm > allowance_mm(self.range_mm)

    @property
    def loose(self) -> bool:
        return self.lock and self.worst_mm > strict_mm(self.range_mm)

    @property
    def within_bound(self) -> bool | None:
        """True errors inside the reported bounds (None: no lock or no bound reported)."""
        if not self.lock or not np.isfinite(self.center_pl_mm):
            return None
        if self.center_error_mm > self.center_pl_mm:
            return False
        return all(e <= pl for e, pl in zip(self.led_errors_mm, self.led_pl_mm, strict=True))


def _normalised(cam: CameraIntrinsics, px: FloatArray) -> FloatArray:
    """Undistorted normalised coordinates of distorted pixels with OpenCV (skew by hand)."""
    K = np.asarray(cam.K, dtype=np.float64)
    fx, gamma, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    yd = (px[:, 1] - cy) / fy
    xd = (px[:, 0] - cx - gamma * yd) / fx
    pts = np.stack([xd, yd], axis=1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(
        pts,
        np.eye(3),
        np.asarray(cam.dist, dtype=np.float64),
        R=None,
        P=None,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12),
    )
    return np.asarray(und, dtype=np.float64).reshape(-1, 2)


def triangulate_cv(
    calib: StereoCalibration, left_px: FloatArray, right_px: FloatArray
) -> FloatArray:
    """Points (N×3 mm, left camera frame) from distorted pixel pairs with OpenCV only."""
    xl = _normalised(calib.left, np.asarray(left_px, dtype=np.float64).reshape(-1, 2))
    xr = _normalised(calib.right, np.asarray(right_px, dtype=np.float64).reshape(-1, 2))
    P_l = np.hstack([np.eye(3), np.zeros((3, 1))])
    P_r = np.hstack([np.asarray(calib.R), np.asarray(calib.T, dtype=np.float64).reshape(3, 1)])
    X = cv2.triangulatePoints(P_l, P_r, xl.T, xr.T)
    return np.asarray((X[:3] / X[3]).T, dtype=np.float64)


def half_peak_centroid(
    gray: NDArray[np.uint8], guess: tuple[float, float], half: int
) -> FloatArray:
    """The plain local centroid: in a (2·half+1)² window at ``guess``, the pixels above half
    the blob's peak over the window border's median — the 8-connected component of them
    nearest ``guess`` (OpenCV's labelling), so that a neighbouring highlight is not counted —
    weighted by their excess over that median (px; NaN when there is none)."""
    h, w = gray.shape
    u0, v0 = int(round(guess[0])), int(round(guess[1]))
    x0, y0 = max(0, u0 - half), max(0, v0 - half)
    x1, y1 = min(w, u0 + half + 1), min(h, v0 + half + 1)
    win = gray[y0:y1, x0:x1].astype(np.float64)
    if win.shape[0] < 3 or win.shape[1] < 3:
        return np.array([np.nan, np.nan])
    border = np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])
    bg = float(np.median(border))
    ys, xs = np.mgrid[y0:y1, x0:x1]
    near = (xs - guess[0]) ** 2 + (ys - guess[1]) ** 2 <= (0.5 * half) ** 2
    peak = float(win[near].max()) if near.any() else float(win.max())
    mask = (win > bg + 0.5 * (peak - bg)).astype(np.uint8)
    count, labels = cv2.connectedComponents(mask, connectivity=8)
    if count < 2:
        return np.array([np.nan, np.nan])
    # the component nearest the guess
    d2 = np.where(labels > 0, (xs - guess[0]) ** 2 + (ys - guess[1]) ** 2, np.inf)
    sel = labels == labels.flat[int(np.argmin(d2))]
    wgt = np.where(sel, win - bg, 0.0)
    total = wgt.sum()
    if total <= 0:
        return np.array([np.nan, np.nan])
    return np.array([(wgt * xs).sum() / total, (wgt * ys).sum() / total])


def baseline_errors(
    calib: StereoCalibration,
    case: OpticsCase,
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
) -> tuple[float, ...]:
    """The baseline's 3-D error (mm) for each LED visible in both images."""
    # colour frames: the green channel (the LEDs are green; in gray they can vanish in the sky)
    gl = left if left.ndim == 2 else np.ascontiguousarray(left[:, :, 1])
    gr = right if right.ndim == 2 else np.ascontiguousarray(right[:, :, 1])
    truth = np.asarray(case.led_xyz_mm, dtype=np.float64)
    vis = np.asarray(case.led_visible, dtype=bool)
    if not vis.any():
        return ()
    pl, pr = project_stereo(calib, truth[vis])
    rho = calib.left.fx * 0.5 * case.led_diameter_mm / float(np.median(truth[vis, 2]))
    half = int(np.ceil(max(4.0, 2.5 * rho + 3.0)))
    cl = np.array([half_peak_centroid(gl, (float(u), float(v)), half) for u, v in pl])
    cr = np.array([half_peak_centroid(gr, (float(u), float(v)), half) for u, v in pr])
    ok = np.all(np.isfinite(cl), axis=1) & np.all(np.isfinite(cr), axis=1)
    if not ok.any():
        return ()
    X = triangulate_cv(calib, cl[ok], cr[ok])
    return tuple(float(e) for e in np.linalg.norm(X - truth[vis][ok], axis=1))


def score(
    case: OpticsCase, seed: int, result: PoseResult, baseline: tuple[float, ...]
) -> OpticsOutcome:
    """An outcome from a pipeline result on one case."""
    truth = np.asarray(case.led_xyz_mm, dtype=np.float64)
    led_err: tuple[float, ...] = ()
    centre_err = float("nan")
    centre_pl = float("nan")
    led_pl: tuple[float, ...] = ()
    if result.lock and result.drogue is not None:
        meas = np.array([led.xyz_mm for led in result.leds], dtype=np.float64).reshape(-1, 3)
        d = np.linalg.norm(meas[:, None, :] - truth[None, :, :], axis=2)
        led_err = tuple(float(e) for e in d.min(axis=1))
        centre_err = float(np.linalg.norm(np.asarray(result.drogue.center_mm) - case.center_mm))
        bound = result.drogue.protection_level_mm
        if bound is not None:
            centre_pl = float(bound)
            led_pl = tuple(
                float("nan") if led.protection_level_mm is None else float(led.protection_level_mm)
                for led in result.leds
            )
    return OpticsOutcome(
        case=case.name,
        condition=case.condition,
        sensor=case.sensor,
        range_mm=float(case.range_mm),
        seed=int(seed),
        lock=bool(result.lock),
        reason=result.reason,
        led_errors_mm=led_err,
        center_error_mm=centre_err,
        baseline_errors_mm=baseline,
        center_pl_mm=centre_pl,
        led_pl_mm=led_pl,
    )


def evaluate(
    calib: StereoCalibration,
    cases: Iterable[OpticsCase],
    seeds: Iterable[int],
    config: PipelineConfig | None = None,
    progress: Callable[[OpticsOutcome], None] | None = None,
) -> list[OpticsOutcome]:
    """Every case × seed through a fresh pipeline (and the baseline on the same frames)."""
    out = []
    seeds = list(seeds)
    base = config or PipelineConfig()
    for case in cases:
        # the drogue's own ring (the lab ring or the flight drogue's)
        cfg = replace(
            base,
            ring_radius_mm=case.ring_radius_mm,
            led_count=case.led_count,
            led_diameter_mm=case.led_diameter_mm,
        )
        pipeline = NavigationPipeline(calib, cfg)
        for seed in seeds:
            left, right = sensor_pair(case, seed)
            pipeline.reset()
            result = pipeline.process(left, right)
            outcome = score(case, seed, result, baseline_errors(calib, case, left, right))
            out.append(outcome)
            if progress is not None:
                progress(outcome)
    return out


@dataclass(frozen=True)
class OpticsSummary:
    """Aggregates of a group of outcomes (rates in [0, 1], errors mm)."""

    runs: int
    locks: int
    wrong: int
    loose: int
    led_error_mean_mm: float  # over LEDs of correct locks
    baseline_error_mean_mm: float  # over the same runs' visible LEDs
    led_error_median_mm: float
    baseline_error_median_mm: float
    bound_checked: int
    bound_held: int

    @property
    def lock_rate(self) -> float:
        return self.locks / self.runs if self.runs else float("nan")


def summarise(outcomes: list[OpticsOutcome], max_range_mm: float | None = None) -> OpticsSummary:
    """Counts and mean errors; LED means only over runs within ``max_range_mm`` if given."""
    near = [o for o in outcomes if max_range_mm is None or o.range_mm <= max_range_mm]
    good = [o for o in near if o.lock and not o.wrong]
    errs = [e for o in good for e in o.led_errors_mm]
    base = [e for o in good for e in o.baseline_errors_mm]  # the same frames
    checked = [o.within_bound for o in outcomes if o.within_bound is not None]
    return OpticsSummary(
        runs=len(outcomes),
        locks=sum(o.lock for o in outcomes),
        wrong=sum(o.wrong for o in outcomes),
        loose=sum(o.loose for o in outcomes),
        led_error_mean_mm=float(np.mean(errs)) if errs else float("nan"),
        baseline_error_mean_mm=float(np.mean(base)) if base else float("nan"),
        led_error_median_mm=float(np.median(errs)) if errs else float("nan"),
        baseline_error_median_mm=float(np.median(base)) if base else float("nan"),
        bound_checked=len(checked),
        bound_held=sum(bool(c) for c in checked),
    )
