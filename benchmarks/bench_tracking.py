"""Windowed tracking vs the full-frame pipeline vs a minimal OpenCV-only baseline.

Over a rendered 1280×1024 sequence of a moving, rolling drogue (0 and 30 LED-like glints), per
stereo pair: the full-frame :class:`~app.vision.pipeline.NavigationPipeline`, the
:class:`~app.vision.tracking.StereoTracker` (full-frame acquisition on the first frame, then
windows) and, in the same run, an OpenCV-only baseline (threshold + ``connectedComponents
WithStats`` + nearest-epipolar matching + ``cv2.triangulatePoints``: no descriptors, no
integrity, no ring). Prints a Markdown table (median and p99 ms per pair; ratios to the
full-frame pipeline) and the largest tracked-vs-full-frame difference (mm).

    .venv/bin/python benchmarks/bench_tracking.py [--frames 40] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import cv2
import numpy as np

from app.geometry.calibration import StereoCalibration
from app.sim.led_ring import stereo_center_x_mm, tilted_normal
from app.sim.paths import load_default_calibration
from app.sim.stereo_render import RenderedPair, RenderSettings, render_pair
from app.vision.pipeline import NavigationPipeline
from app.vision.result import PoseResult
from app.vision.tracking import StereoTracker


def sequence(calib: StereoCalibration, depth: float, n: int, glints: int) -> list[RenderedPair]:
    """A drogue moving ≈ 10 px/frame, tilting and rolling 3.4°/frame."""
    x = stereo_center_x_mm(calib, depth)
    out = []
    for i in range(n):
        t = i % 20 if (i // 20) % 2 == 0 else 20 - i % 20  # back and forth: stays in view
        centre = np.array([x + 4.0 * t, -3.0 + 2.5 * t, depth + 8.0 * t])
        normal = tilted_normal(8.0 + 0.5 * t, 30.0)
        out.append(
            render_pair(
                calib, centre, normal, RenderSettings(glints=glints), seed=i, roll_rad=0.06 * i
            )
        )
    return out


class OpenCvBaseline:
    """Minimal OpenCV-only stereo LED points: what one would write with stock calls."""

    def __init__(self, calib: StereoCalibration) -> None:
        self.calib = calib
        self.F = calib.fundamental

    def _points(self, img: np.ndarray, cam) -> np.ndarray:  # type: ignore[no-untyped-def]
        gray = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        peak = cv2.minMaxLoc(gray)[1]
        _, binary = cv2.threshold(gray, 0.5 * peak, 255, cv2.THRESH_BINARY)
        n, _, stats, cents = cv2.connectedComponentsWithStats(binary, connectivity=8)
        keep = stats[1:, cv2.CC_STAT_AREA] >= 3
        pts = cents[1:][keep].astype(np.float64)
        if len(pts) == 0:
            return np.zeros((0, 2))
        und = cv2.undistortPoints(pts.reshape(-1, 1, 2), cam.K, cam.dist, P=cam.K)
        return np.asarray(und.reshape(-1, 2))

    def process(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        xl = self._points(left, self.calib.left)
        xr = self._points(right, self.calib.right)
        if len(xl) == 0 or len(xr) == 0:
            return np.zeros((0, 3))
        lines = cv2.computeCorrespondEpilines(xl.reshape(-1, 1, 2), 1, self.F).reshape(-1, 3)
        d = np.abs(lines @ np.column_stack([xr, np.ones(len(xr))]).T)  # (NL, NR) px
        j = np.argmin(d, axis=1)
        ok = d[np.arange(len(xl)), j] <= 2.0
        if not np.any(ok):
            return np.zeros((0, 3))
        X = cv2.triangulatePoints(self.calib.P_left, self.calib.P_right, xl[ok].T, xr[j[ok]].T)
        return np.asarray((X[:3] / X[3]).T)


def run(fn: Callable[[RenderedPair], object], frames: list[RenderedPair]) -> list[float]:
    ts = []
    for pair in frames:
        t0 = time.perf_counter()
        fn(pair)
        ts.append((time.perf_counter() - t0) * 1e3)
    return ts


def max_diff(a: PoseResult, b: PoseResult) -> float:
    if not (a.lock and b.lock and a.drogue and b.drogue):
        return 0.0 if a.lock == b.lock else float("inf")
    if [led.id for led in a.leds] != [led.id for led in b.leds]:
        return float("inf")
    d = float(np.max(np.abs(np.subtract(a.drogue.center_mm, b.drogue.center_mm))))
    for la, lb in zip(a.leds, b.leds, strict=True):
        d = max(d, float(np.max(np.abs(np.subtract(la.xyz_mm, lb.xyz_mm)))))
    return d


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--depth", type=float, default=1000.0)
    args = ap.parse_args()
    calib = load_default_calibration()
    rows = []
    for glints in (0, 30):
        frames = sequence(calib, args.depth, args.frames, glints)
        full_t: list[float] = []
        track_t: list[float] = []
        tracked_t: list[float] = []
        base_t: list[float] = []
        nodesc_t: list[float] = []
        worst = 0.0
        modes: dict[str, int] = {}
        for _ in range(args.repeats):
            pipe = NavigationPipeline(calib)
            tracker = StereoTracker(calib)
            base = OpenCvBaseline(calib)
            ref: list[PoseResult] = []
            full_t += run(
                lambda p, pipe=pipe, ref=ref: ref.append(pipe.process(p.left, p.right)), frames
            )
            got: list[PoseResult] = []
            for pair in frames:
                t0 = time.perf_counter()
                got.append(tracker.update(pair.left, pair.right))
                dt = (time.perf_counter() - t0) * 1e3
                track_t.append(dt)
                modes[tracker.last_mode] = modes.get(tracker.last_mode, 0) + 1
                if tracker.last_mode == "tracked":
                    tracked_t.append(dt)
            worst = max(worst, max(max_diff(a, b) for a, b in zip(ref, got, strict=True)))
            base_t += run(lambda p, base=base: base.process(p.left, p.right), frames)
            # the tracker without IHWT descriptors (descriptor_distance −1; pose identical)
            lean = StereoTracker(calib, describe=False)
            for pair in frames:
                t0 = time.perf_counter()
                lean.update(pair.left, pair.right)
                if lean.last_mode == "tracked":
                    nodesc_t.append((time.perf_counter() - t0) * 1e3)
        rows.append((glints, full_t, track_t, tracked_t, base_t, nodesc_t, worst, modes))
    med = np.median

    def p99(x: list[float]) -> float:
        return float(np.percentile(x, 99))

    print(
        f"\n{args.frames} frames × {args.repeats} repeats, 1280×1024 gray pairs at "
        f"{args.depth / 1000:.1f} m (ms per stereo pair)\n"
    )
    print(
        "| glints | full-frame pipeline med / p99 | tracker (all frames) med / p99 "
        "| tracked frames med / p99 | tracked, no descriptors med / p99 "
        "| OpenCV-only baseline med / p99 "
        "| full ÷ tracked (median) | baseline ÷ tracked (median) | tracked / acquired / lost "
        "| max abs tracked − full (mm) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for glints, full_t, track_t, tracked_t, base_t, nodesc_t, worst, modes in rows:
        tm = med(tracked_t) if tracked_t else float("nan")
        print(
            f"| {glints} | {med(full_t):.2f} / {p99(full_t):.2f} "
            f"| {med(track_t):.3f} / {p99(track_t):.2f} "
            f"| {tm:.3f} / {p99(tracked_t) if tracked_t else float('nan'):.3f} "
            f"| {med(nodesc_t):.3f} / {p99(nodesc_t):.3f} "
            f"| {med(base_t):.2f} / {p99(base_t):.2f} "
            f"| {med(full_t) / tm:.1f}× | {med(base_t) / tm:.1f}× "
            f"| {modes.get('tracked', 0)} / {modes.get('acquired', 0)} / {modes.get('lost', 0)} "
            f"| {worst:.2e} |"
        )


if __name__ == "__main__":
    main()
