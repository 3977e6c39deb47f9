"""One camera's frames with their times: a video file, an image folder/glob, a capture device.

Times (s): video files use the container's frame time (``CAP_PROP_POS_MSEC``, else index/fps);
image sequences use a ``timestamps.txt`` beside the images (one time in seconds a line) when
present, else index/fps; devices use ``time.monotonic()`` when the frame was grabbed.
"""

from __future__ import annotations

import glob
import time
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from app.streams.frames import SourceError, ensure_gray_or_bgr
from app.types import UInt8Array
from app.vision.io import read_image
from app.vision.preprocess import ImageError

IMAGE_SUFFIXES = (".png", ".bmp", ".tif", ".tiff", ".jpg", ".jpeg", ".pgm", ".ppm")


class MonoReader(Protocol):
    name: str

    def read(self) -> tuple[float, UInt8Array] | None:
        """(time s, image) of the next frame; ``None`` at the end."""
        ...

    def close(self) -> None: ...


def _is_int(text: str) -> bool:
    return text.strip().lstrip("-").isdigit()


def image_files(spec: str) -> list[Path]:
    """A folder's images (sorted by name) or a glob's matches (sorted); ``[]`` if neither."""
    path = Path(spec)
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if any(c in spec for c in "*?["):
        return [Path(p) for p in sorted(glob.glob(spec))]
    return []


class ImageSequenceReader:
    """Images of a folder or glob, in name order."""

    def __init__(self, spec: str, fps: float = 30.0, times: list[float] | None = None) -> None:
        self.name = spec
        self.files = image_files(spec)
        if not self.files:
            raise SourceError(f"no images in {spec!r}")
        self.fps = fps
        self.times = times
        if times is None:
            stamp = Path(spec) / "timestamps.txt" if Path(spec).is_dir() else None
            if stamp is not None and stamp.is_file():
                self.times = [float(x) for x in stamp.read_text().split()]
        if self.times is not None and len(self.times) < len(self.files):
            raise SourceError(f"{spec!r}: fewer timestamps than images")
        self.index = 0

    def read(self) -> tuple[float, UInt8Array] | None:
        if self.index >= len(self.files):
            return None
        i = self.index
        self.index += 1
        try:
            img = read_image(self.files[i])
        except ImageError as exc:
            raise SourceError(f"cannot decode {self.files[i]} ({exc})") from None
        t = self.times[i] if self.times is not None else i / self.fps
        return t, img

    def close(self) -> None:
        self.index = len(self.files)


class CaptureReader:
    """``cv2.VideoCapture`` on a video file (file times) or a device index (grab times)."""

    def __init__(self, spec: str, fps: float = 30.0) -> None:
        self.name = spec
        self.device = _is_int(spec)
        if not self.device and not Path(spec).is_file():
            raise SourceError(f"no such video file {spec!r}")
        self.cap = cv2.VideoCapture(int(spec) if self.device else spec)
        if not self.cap.isOpened():
            raise SourceError(f"OpenCV cannot open {spec!r}")
        file_fps = float(self.cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = file_fps if file_fps > 0 else fps
        self.index = 0
        self._grab_t: float | None = None

    def grab(self) -> bool:
        """Grab only (fast): a stereo pair of devices grabs both, then retrieves both."""
        ok = bool(self.cap.grab())
        self._grab_t = time.monotonic() if ok else None
        return ok

    def retrieve(self) -> tuple[float, UInt8Array] | None:
        if self._grab_t is None:
            return None
        ok, img = self.cap.retrieve()
        grab_t, self._grab_t = self._grab_t, None
        if not ok or img is None:
            return None
        i = self.index
        self.index += 1
        if self.device:
            t = grab_t
        else:
            msec = float(self.cap.get(cv2.CAP_PROP_POS_MSEC))
            t = msec / 1e3 if msec > 0 or i == 0 else i / self.fps
        return t, ensure_gray_or_bgr(np.asarray(img))

    def read(self) -> tuple[float, UInt8Array] | None:
        if not self.grab():
            return None
        return self.retrieve()

    def close(self) -> None:
        self.cap.release()


def open_reader(spec: str, fps: float = 30.0) -> MonoReader:
    """A folder or glob → :class:`ImageSequenceReader`; a file or device → :class:`CaptureReader`."""
    spec = spec.strip()
    if not spec:
        raise SourceError("empty source")
    if image_files(spec):
        return ImageSequenceReader(spec, fps)
    if Path(spec).is_dir():
        raise SourceError(f"no images in folder {spec!r}")
    return CaptureReader(spec, fps)
