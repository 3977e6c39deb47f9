"""Compile the navigation core's compiled loops before real work starts.

The inner loops of the pipeline and the tracker are compiled by numba on first use and cached
on disk (a folder keyed by the kernels' sources, :mod:`app.numba_cache`, or ``NUMBA_CACHE_DIR``). On a fresh install the
first frame would otherwise take 15–30 s to compile on this class of machine; with the cache,
loading takes ≈ 0.1 s. :func:`compile_kernels` runs a few rendered stereo pairs through
:class:`~app.vision.pipeline.NavigationPipeline` and :class:`~app.vision.tracking.StereoTracker`
(acquisition, tracking, every compiled loop with the argument types real frames give), and
renders as the closed loop does (the renderer's compiled loops), so that a service, a campaign
or a benchmark starts with everything compiled.

    python -m app.sim.warmup        # e.g. at image build time
"""

from __future__ import annotations

import time

import numpy as np

from app.geometry.ring import RingParams, find_ring
from app.resources import load_default_calibration
from app.sim.led_ring import stereo_center_x_mm, tilted_normal
from app.sim.stereo_render import RenderSettings, render_pair
from app.vision.features import BlobGate, extract_blobs
from app.vision.pipeline import NavigationPipeline
from app.vision.preprocess import binarize, median_filter, to_gray
from app.vision.tracking import StereoTracker


def compile_kernels() -> float:
    """Compile (or load from the on-disk cache) every compiled loop of the navigation core;
    returns the seconds it took."""
    t0 = time.perf_counter()
    calib = load_default_calibration()
    x = stereo_center_x_mm(calib, 1000.0)
    pipeline = NavigationPipeline(calib)
    tracker = StereoTracker(calib)
    for i in range(3):
        centre = np.array([x + 3.0 * i, 0.0, 1000.0])
        pair = render_pair(calib, centre, tilted_normal(10.0, 30.0), RenderSettings(), seed=i)
        pipeline.process(pair.left, pair.right)
        tracker.update(pair.left, pair.right)
    # the closed loop's renders: fast noise, the blobs drawn straight into the tracker's
    # windows (app.sim.stereo_render.patch_kernels)
    w, h = calib.image_size
    window = (w // 4, h // 4, 3 * w // 4, 3 * h // 4)  # px
    fast = RenderSettings(fast_noise=True, clutter=2, glints=1)
    render_pair(calib, centre, tilted_normal(10.0, 30.0), fast, seed=0, windows=([window],) * 2)
    # the whole-frame formulation with a given mask (features.extract_blobs, public API)
    gray = to_gray(pair.left)
    extract_blobs(gray, median_filter(binarize(gray, 128)), 10.0, BlobGate())
    # a refusal (no ring among the candidates) runs the ring search's diagnosis loop
    find_ring(np.array([[0.0, 0.0, 1e3], [40.0, 0.0, 1e3], [0.0, 300.0, 1e3]]), RingParams())
    return time.perf_counter() - t0


def main() -> None:
    seconds = compile_kernels()
    print(f"navigation kernels ready ({seconds:.1f} s)")


if __name__ == "__main__":
    main()
