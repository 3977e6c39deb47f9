"""Everything after the source: stereo tracker → drogue filter → guidance, per pair.

:class:`StreamProcessor` is shared by ``aar-dock track`` and the service's stream loop, so a
recorded sequence gives the same results offline as live; the service turns a
:class:`StreamTick` into its telemetry record with ``app.service.records.from_stream``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from app.geometry.calibration import StereoCalibration
from app.model.frames import StereoFrame
from app.model.pose import PoseResult
from app.streams.frames import SourceKind
from app.streams.guidance import GuidanceState, StreamGuidance, StreamGuidanceConfig
from app.types import UInt8Array
from app.vision.pipeline import PipelineConfig
from app.vision.tracking import StereoTracker


@dataclass
class StreamTick:
    """One pair's result: the tracker's pose, the drogue filter's guidance, the frame itself."""

    source: SourceKind
    frame: StereoFrame
    pose: PoseResult
    guidance: GuidanceState
    mode: str  # tracker mode: acquired / tracked / lost / error
    track_epoch: int  # increments when the tracker is reset (a recording starts fresh)
    processor: StreamProcessor | None = field(default=None, repr=False)  # what made it
    extra_timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def t_s(self) -> float:
        """Capture time on the source's clock (s)."""
        return self.frame.t_s

    @property
    def lock(self) -> bool:
        return self.pose.lock

    @property
    def lock_reason(self) -> str | None:
        return self.pose.reason

    @property
    def left_image(self) -> UInt8Array:
        return self.frame.left

    @property
    def right_image(self) -> UInt8Array:
        return self.frame.right

    @property
    def stereo_frame(self) -> StereoFrame:
        """The pair with the source's own times and counter."""
        return self.frame

    @property
    def image_windows_px(self) -> None:
        """A stream's frames are whole images (the tracker's windows are its own)."""
        return None

    @property
    def camera_pose_T(self) -> None:
        """A real camera's pose in the tanker frame is not known."""
        return None


class StreamProcessor:
    def __init__(
        self,
        calibration: StereoCalibration,
        pipeline: PipelineConfig | None = None,
        guidance: StreamGuidanceConfig | None = None,
    ) -> None:
        self.calibration = calibration
        self.pipeline_config = pipeline or PipelineConfig()
        if guidance is None:
            guidance = StreamGuidanceConfig(
                focal_px=float(calibration.left.fx), baseline_mm=float(calibration.baseline_mm)
            )
        self.guidance_config = guidance
        self.tracker = StereoTracker(calibration, self.pipeline_config)
        self.guidance = StreamGuidance(guidance)
        self.epoch = 0
        self._reset_requested = False

    def request_reset(self) -> int:
        """Reset the track before the next pair (thread-safe flag); returns the epoch that
        pair will carry."""
        self._reset_requested = True
        return self.epoch + 1

    def set_calibration(self, calibration: StereoCalibration) -> None:
        self.calibration = calibration
        self.tracker = StereoTracker(calibration, self.pipeline_config)
        self.guidance.reset()
        self.epoch += 1

    def process(self, frame: StereoFrame, source: SourceKind = "video") -> StreamTick:
        if self._reset_requested:
            self._reset_requested = False
            self.tracker.reset()
            self.guidance.reset()
            self.epoch += 1
        t0 = time.perf_counter()
        try:
            pose = self.tracker.update(frame.left, frame.right)
            mode: str = self.tracker.last_mode
        except ValueError as exc:  # ImageError: wrong size/type for the calibration
            pose = PoseResult(lock=False, reason=f"bad frame: {exc}")
            mode = "error"
        track_ms = (time.perf_counter() - t0) * 1e3
        state = self.guidance.update(frame.t_s, pose)
        return StreamTick(
            source=source,
            frame=frame,
            pose=pose,
            guidance=state,
            mode=mode,
            track_epoch=self.epoch,
            processor=self,
            extra_timings_ms={"track": track_ms},
        )
