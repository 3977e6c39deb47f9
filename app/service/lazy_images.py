"""A stereo pair made on first access: what the 3-D scene reads, at its own image rate."""

from __future__ import annotations

import threading

import numpy as np

from app.model.frames import StereoFrame
from app.types import FloatArray, Rect

ImagePair = tuple[np.ndarray | None, np.ndarray | None]


class LazyImagePair:
    """``left_image`` / ``right_image`` from :meth:`_load`, called once (thread-safe)."""

    def __init__(self, images: ImagePair | None = None) -> None:
        self._images = images
        self._lock = threading.Lock()

    def _load(self) -> ImagePair:
        raise NotImplementedError

    def _pair(self) -> ImagePair:
        with self._lock:
            if self._images is None:
                self._images = self._load()
            return self._images

    @property
    def left_image(self) -> np.ndarray | None:
        return self._pair()[0]

    @property
    def right_image(self) -> np.ndarray | None:
        return self._pair()[1]

    # the rest of :class:`app.streams.frames.RawFrame`: nothing by default
    @property
    def stereo_frame(self) -> StereoFrame | None:
        return None

    @property
    def image_windows_px(self) -> tuple[list[Rect], list[Rect]] | None:
        return None

    @property
    def camera_pose_T(self) -> tuple[FloatArray, FloatArray] | None:
        return None
