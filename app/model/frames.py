"""The stereo frame: one timestamped pair of a camera stream, and the raw side of a published
tick (what a tick's subscribers may read besides its record: the images, the rendered windows,
the camera's true pose)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from app.types import FloatArray, Rect, UInt8Array


@dataclass
class StereoFrame:
    """One stereo pair. Times in seconds on the source's clock (file time, device monotonic
    clock or the pusher's clock); ``t_s`` is the pair's time (mean of both sides)."""

    left: UInt8Array
    right: UInt8Array
    t_s: float
    seq: int  # frame counter of the source (pushed pairs: the pusher's sequence number)
    t_left_s: float | None = None
    t_right_s: float | None = None
    exposure_ms: float | None = None

    @property
    def skew_s(self) -> float:
        """|t_left − t_right| (s); 0 when the sides carry no own time."""
        if self.t_left_s is None or self.t_right_s is None:
            return 0.0
        return abs(self.t_left_s - self.t_right_s)


class RawFrame(Protocol):
    """The raw side of a published tick, what the subscribers may read besides its record.

    ``left_image`` / ``right_image``: the pair (``None`` when not kept or already overwritten;
    read on first access where they are lazy); ``stereo_frame``: a camera stream's pair with
    its own times and counter (``None`` for the simulation and uploads);
    ``image_windows_px``: the rectangles rendered or searched in the left/right image;
    ``camera_pose_T``: the left camera's true pose in the tanker frame (R_TC, origin m), where
    a simulation knows it."""

    @property
    def left_image(self) -> UInt8Array | None: ...
    @property
    def right_image(self) -> UInt8Array | None: ...
    @property
    def stereo_frame(self) -> StereoFrame | None: ...
    @property
    def image_windows_px(self) -> tuple[list[Rect], list[Rect]] | None: ...
    @property
    def camera_pose_T(self) -> tuple[FloatArray, FloatArray] | None: ...
