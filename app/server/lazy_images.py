"""A stereo pair made on first access: what the 3-D scene reads, at its own image rate."""

from __future__ import annotations

import threading

import numpy as np

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
