"""The raw side of a published tick as the tests make it up (``app.streams.frames.RawFrame``):
every member the subscribers read, ``None`` unless a test gives it."""

from __future__ import annotations

from dataclasses import dataclass

from app.model.frames import StereoFrame
from app.types import FloatArray, Rect, UInt8Array


@dataclass
class RawPair:
    left_image: UInt8Array | None = None
    right_image: UInt8Array | None = None
    stereo_frame: StereoFrame | None = None
    image_windows_px: tuple[list[Rect], list[Rect]] | None = None
    camera_pose_T: tuple[FloatArray, FloatArray] | None = None
