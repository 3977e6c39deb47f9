"""The frame-source interface: timestamped stereo pairs and the source's counters."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from app.model.frames import StereoFrame
from app.types import UInt8Array
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
