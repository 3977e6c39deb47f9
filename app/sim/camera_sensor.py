"""The stereo camera in the docking loop: render the LED ring, track it, report the drogue.

:class:`StereoCameraSensor` renders a frame pair of the ring at its true pose through the
*true* calibration (:func:`app.sim.stereo_render.render_pair`) and processes it with a
:class:`~app.vision.tracking.StereoTracker` built on the *navigation* calibration (the same
one, or a perturbed one: :mod:`app.sim.imperfections`).

Render modes:

* ``"full"``: every frame is rendered whole (the reference for tests);
* ``"windows"``: while the tracker tracks, only the rectangles it will read
  (:meth:`StereoTracker.next_windows`) are rendered — bit-identical there to the full render
  with the same seed — and a full render is made only when the tracker acquires or falls
  back (``update(..., full_frame=...)``). Both modes give the same poses.

The tracker is built with ``exact_peak=False`` in both modes: the threshold's peak is taken
over the windows, which a windowed render knows (the whole frame's peak it does not).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import StereoCalibration
from app.model.pose import PoseResult
from app.sim.led_ring import LedRing
from app.sim.stereo_render import RenderedPair, RenderSettings, render_pair
from app.types import FloatArray, Rect
from app.vision.pipeline import PipelineConfig
from app.vision.tracking import StereoTracker

RenderMode = Literal["full", "windows"]
RENDER_MODES: tuple[str, ...] = ("full", "windows")


@dataclass
class CameraFrame:
    """One processed stereo frame (left camera frame, mm; images uint8)."""

    pose: PoseResult
    left: NDArray[np.uint8]
    right: NDArray[np.uint8]
    led_truth_cam_mm: FloatArray
    # the rectangles rendered (left, right), or None for a full render
    windows: tuple[list[Rect], list[Rect]] | None


class StereoCameraSensor:
    """Render + :class:`StereoTracker` for one docking run (reset per run)."""

    def __init__(
        self,
        render_calibration: StereoCalibration,
        settings: RenderSettings,
        ring: LedRing,
        pipeline_config: PipelineConfig,
        mode: str = "full",
        nav_calibration: StereoCalibration | None = None,
    ) -> None:
        if mode not in RENDER_MODES:
            raise ValueError(f"render mode must be one of {RENDER_MODES}, got {mode!r}")
        self.mode = mode
        self.render_calibration = render_calibration
        self.nav_calibration = nav_calibration or render_calibration
        self.settings = settings
        self.ring = ring
        self.tracker = StereoTracker(self.nav_calibration, pipeline_config, exact_peak=False)
        self.full_renders = 0
        self.window_renders = 0

    def set_nav_calibration(self, calibration: StereoCalibration) -> None:
        """The calibration the tracker uses (a perturbed one: calibration error); a new
        tracker when it changes."""
        if calibration is not self.nav_calibration:
            self.nav_calibration = calibration
            self.tracker = StereoTracker(calibration, self.tracker.config, exact_peak=False)

    def reset(self) -> None:
        """A new run: no lock, no LED history."""
        self.tracker.reset()
        self.full_renders = 0
        self.window_renders = 0

    def _render(
        self,
        center_mm: FloatArray,
        normal: FloatArray,
        seed: int,
        windows: tuple[list[Rect], list[Rect]] | None = None,
    ) -> RenderedPair:
        if windows is None:
            self.full_renders += 1
        else:
            self.window_renders += 1
        return render_pair(
            self.render_calibration,
            center_mm,
            normal,
            settings=self.settings,
            ring=self.ring,
            seed=seed,
            windows=windows,
        )

    def capture(self, center_mm: FloatArray, normal: FloatArray, seed: int) -> CameraFrame:
        """Render the ring (centre mm and unit normal in the left camera frame) and track it."""
        windows = self.tracker.next_windows() if self.mode == "windows" else None
        pair = self._render(center_mm, normal, seed, windows)
        if windows is None:
            pose = self.tracker.update(pair.left, pair.right)
            return CameraFrame(pose, pair.left, pair.right, pair.truth.led_xyz_mm, None)
        full: list[RenderedPair] = []

        def full_frame() -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
            full.append(self._render(center_mm, normal, seed))
            return full[0].left, full[0].right

        pose = self.tracker.update(pair.left, pair.right, full_frame=full_frame)
        if full:  # the tracker fell back to the full frame: report what it saw
            return CameraFrame(pose, full[0].left, full[0].right, pair.truth.led_xyz_mm, None)
        return CameraFrame(pose, pair.left, pair.right, pair.truth.led_xyz_mm, windows)
