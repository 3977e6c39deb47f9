"""The frame-source interface: timestamped stereo pairs and the source's counters."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from app.types import FloatArray, Rect, UInt8Array
from app.vision.io import sensor_image
from app.vision.preprocess import ImageError

SourceKind = Literal["video", "camera", "push"]


class SourceError(ValueError):
    """A source spec that cannot be opened (missing file, no device, bad syntax)."""


class SourceCorrupt(SourceError):
    """A finite source whose data turns out corrupt after it was opened (a message of an MCAP
    log that does not parse): final, reopening it would meet the same bytes again."""


class EndOfStream(Exception):
    """Raised by ``read`` when a finite source (files, a recording) has no more pairs."""


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


@dataclass
class SourceStats:
    """Counters of one source (thread-safe updates through :meth:`add`)."""

    pairs: int = 0  # pairs delivered
    dropped_skew: int = 0  # frames dropped by the pairing (|Δt| > max skew, or unmatched)
    dropped_backpressure: int = 0  # pairs overwritten before being read (push: keep newest)
    rejected: int = 0  # pushed messages refused (bad header, undecodable image)
    seq_duplicate: int = 0  # pushed pairs whose seq equals the previous one (dropped)
    seq_out_of_order: int = 0  # pushed pairs whose seq is below the previous one (dropped)
    last_skew_ms: float | None = None
    max_skew_ms: float = 0.0
    _times: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def delivered(self, frame: StereoFrame) -> None:
        with self._lock:
            self.pairs += 1
            skew_ms = frame.skew_s * 1e3
            self.last_skew_ms = skew_ms
            self.max_skew_ms = max(self.max_skew_ms, skew_ms)
            self._times.append(time.monotonic())

    def add(self, name: str, n: int = 1) -> None:
        with self._lock:
            setattr(self, name, getattr(self, name) + n)

    def fps(self, window_s: float = 2.0) -> float:
        """Delivered pairs per second over the last ``window_s`` (wall clock)."""
        with self._lock:
            times = list(self._times)
        now = time.monotonic()
        recent = [t for t in times if t >= now - window_s]
        if len(recent) < 2:
            return 0.0
        span = recent[-1] - recent[0]
        return (len(recent) - 1) / span if span > 0 else 0.0

    def as_dict(self) -> dict[str, float | int | None]:
        with self._lock:
            return {
                "pairs": self.pairs,
                "dropped_skew": self.dropped_skew,
                "dropped_backpressure": self.dropped_backpressure,
                "rejected": self.rejected,
                "seq_duplicate": self.seq_duplicate,
                "seq_out_of_order": self.seq_out_of_order,
                "last_skew_ms": self.last_skew_ms,
                "max_skew_ms": self.max_skew_ms,
            }


class FrameSource(Protocol):
    """What the stream loop consumes."""

    kind: SourceKind
    spec: str
    stats: SourceStats

    def read(self, timeout_s: float | None = None) -> StereoFrame | None:
        """The next pair; ``None`` if none arrived within ``timeout_s`` (live sources);
        raises :class:`EndOfStream` at the end of a finite source."""
        ...

    def close(self) -> None: ...


def ensure_gray_or_bgr(image: NDArray[np.generic]) -> UInt8Array:
    """8-bit gray or BGR as the pipeline takes it (:func:`app.vision.io.sensor_image`: a BGR
    frame whose three channels are equal becomes gray; BGRA loses alpha); ``SourceError``
    otherwise."""
    try:
        return sensor_image(image, "frame")
    except ImageError as exc:
        raise SourceError(str(exc)) from None


class RecordedPairs:
    """A source of stored pairs in order (a frame recording, an MCAP log): subclasses give
    ``spec``, ``stats`` and :meth:`read_next` (``None`` at the end); :meth:`read` is the
    source interface (``EndOfStream`` at the end, each pair counted)."""

    kind: SourceKind = "video"
    spec: str
    stats: SourceStats

    def read_next(self) -> StereoFrame | None:
        raise NotImplementedError

    def read(self, timeout_s: float | None = None) -> StereoFrame | None:
        frame = self.read_next()
        if frame is None:
            raise EndOfStream(self.spec)
        self.stats.delivered(frame)
        return frame
