"""How long a recording can run: its write rate (bytes/s over the recording), the time left at
that rate against each bound (``max_s``, the frames' budget, the telemetry's size bound, the
free space above the floor), and, before a recording starts, an estimate of the same from a
typical frame of the current stream encoded with the chosen options (or the last measured
size of a pair).

:func:`time_left` is the arithmetic; :class:`RateProbe` watches the ticks while no recording
runs (how often a pair comes, how large a telemetry line is, a sample image) so that an
estimate is at hand before the operator presses start.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from app.streams.frame_encoding import FrameEncoding

Bound = Literal["max_s", "frames budget", "size bound", "free space"]
SAMPLE_PERIOD_S = 5.0  # how often the probe copies a sample image of the stream
ENCODE_CACHE_S = 30.0  # how long an encoded sample's size is reused
RATE_WINDOW_S = 2.0  # the probe's pair rate is counted over windows this long


@dataclass(frozen=True)
class Rates:
    """Bytes per second of each part of a recording (measured, or estimated)."""

    telemetry_bps: float
    frames_bps: float
    mcap_bps: float

    @property
    def total_bps(self) -> float:
        return self.telemetry_bps + self.frames_bps + self.mcap_bps


@dataclass(frozen=True)
class Written:
    """Bytes a recording holds so far, by part."""

    telemetry: int = 0
    frames: int = 0
    mcap: int = 0


@dataclass(frozen=True)
class Limits:
    """A recording's bounds: seconds, the frames' bytes, telemetry + scene bytes, and the free
    space (bytes) that must stay on the disk (``free_bytes``: now, None if unknown)."""

    max_s: float
    max_frames_bytes: int
    max_telemetry_bytes: int
    floor_bytes: int
    free_bytes: int | None


def time_left(
    elapsed_s: float, written: Written, rates: Rates, limits: Limits, frames: bool
) -> tuple[float, Bound]:
    """Seconds until the first bound is reached at ``rates`` (from ``elapsed_s`` with
    ``written`` on disk), and which bound it is."""
    out: list[tuple[float, Bound]] = [(limits.max_s - elapsed_s, "max_s")]

    def at(rate: float, room: float, bound: Bound) -> None:
        if rate > 0:
            out.append((room / rate, bound))

    if frames:
        at(rates.frames_bps, limits.max_frames_bytes - written.frames, "frames budget")
        if limits.free_bytes is not None:
            at(rates.total_bps, limits.free_bytes - limits.floor_bytes, "free space")
    at(rates.telemetry_bps, limits.max_telemetry_bytes - written.telemetry, "size bound")
    seconds, bound = min(out, key=lambda x: x[0])
    return max(0.0, seconds), bound


class RecordingProgress(BaseModel):
    """``GET /recording``: the active recording's write rate and time left, or (none active)
    an estimate of how long one with the chosen options can run."""

    active: bool = Field(description="a recording is in progress")
    id: str | None = None
    frames: bool = Field(description="frames are (or would be) recorded")
    encoding: str | None = Field(None, description="the frames' codec, e.g. png-huffman")
    lossless: bool | None = None
    elapsed_s: float = 0.0
    telemetry_bytes: int = 0
    frames_bytes: int = 0
    mcap_bytes: int = 0
    rate_bytes_per_s: float | None = Field(
        None, description="all files together: measured over the recording, or estimated"
    )
    frames_bytes_per_s: float | None = None
    mb_per_min: float | None = Field(None, description="rate_bytes_per_s in MB (1e6) a minute")
    time_left_s: float | None = Field(
        None, description="until the first bound at this rate (before a start: the whole run)"
    )
    limited_by: Bound | None = None
    basis: str = Field(description="where the rate comes from")
    pair_bytes: float | None = Field(None, description="a typical stereo pair, encoded")
    pairs_per_s: float | None = None
    free_mb: float | None = None
    min_free_mb: float = 0.0
    max_s: float = 0.0
    max_mb: float = 0.0
    max_frames_mb: float = 0.0


class RateProbe:
    """What the ticks say: their rate, a telemetry line's size and a sample image (a copy,
    every ``SAMPLE_PERIOD_S``), and the measured size of a pair per encoding (from finished
    recordings)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._sample: np.ndarray | None = None
        self._sample_t = -math.inf
        self._window_t0 = time.monotonic()
        self._window_ticks = 0
        self.ticks_per_s = 0.0
        self.has_images = False
        self.line_bytes = 0
        self.measured_pair_bytes: dict[str, float] = {}
        self._encoded: dict[tuple[str, tuple[int, ...]], tuple[float, float]] = {}

    def on_tick(self) -> bool:
        """Count one tick; True when a sample is due (then call :meth:`take_sample`)."""
        now = time.monotonic()
        with self._lock:
            self._window_ticks += 1
            dt = now - self._window_t0
            if dt >= RATE_WINDOW_S:
                self.ticks_per_s = self._window_ticks / dt
                self._window_t0, self._window_ticks = now, 0
            return now - self._sample_t >= SAMPLE_PERIOD_S

    def take_sample(self, line_bytes: int, image: np.ndarray | None) -> None:
        """A tick's telemetry line size and its left image (None: this tick has none)."""
        with self._lock:
            self._sample_t = time.monotonic()
            self.line_bytes = line_bytes
            self.has_images = image is not None
            if image is not None:
                self._sample = np.array(image, copy=True)

    @property
    def pairs_per_s(self) -> float:
        """Pairs a second the ticks bring (the tick rate while they carry images)."""
        return self.ticks_per_s if self.has_images else 0.0

    def measured(self, encoding: FrameEncoding, pair_bytes: float) -> None:
        """A finished recording's bytes per pair with ``encoding``."""
        with self._lock:
            self.measured_pair_bytes[encoding.label] = pair_bytes

    def pair_bytes(self, encoding: FrameEncoding) -> tuple[float | None, str]:
        """A typical pair's bytes with ``encoding`` and where that figure comes from: the
        current stream's sample image encoded (twice its size: left and right), else the last
        recording's measured size, else None."""
        with self._lock:
            sample = self._sample
            measured = self.measured_pair_bytes.get(encoding.label)
        if sample is not None:
            key = (encoding.label, sample.shape)
            now = time.monotonic()
            hit = self._encoded.get(key)
            if hit is None or now - hit[1] > ENCODE_CACHE_S:
                hit = (2.0 * len(encoding.encode(sample)), now)
                self._encoded[key] = hit
            h, w = sample.shape[:2]
            return hit[0], f"a frame of the current stream ({w}×{h} px) encoded as {encoding.label}"
        if measured is not None:
            return measured, f"the last recording with {encoding.label} (measured)"
        return None, "no frame seen yet"


@dataclass(frozen=True)
class Bounds:
    """A recorder's configured bounds (for the report)."""

    max_s: float
    max_mb: float
    max_frames_mb: float
    min_free_mb: float

    def limits(self, free_mb: float | None) -> Limits:
        return Limits(
            max_s=self.max_s,
            max_frames_bytes=int(self.max_frames_mb * 1e6),
            max_telemetry_bytes=int(self.max_mb * 1e6),
            floor_bytes=int(self.min_free_mb * 1e6),
            free_bytes=None if free_mb is None else int(free_mb * 1e6),
        )


def measured_progress(
    rec_id: str,
    encoding: FrameEncoding | None,
    elapsed_s: float,
    written: Written,
    bounds: Bounds,
    free_mb: float | None,
) -> RecordingProgress:
    """The active recording: its bytes/s over the recording so far and the time left at it."""
    rates = None
    if elapsed_s > 0:
        rates = Rates(
            written.telemetry / elapsed_s, written.frames / elapsed_s, written.mcap / elapsed_s
        )
    frames = encoding is not None
    left: tuple[float, Bound] | None = None
    if rates is not None:
        left = time_left(elapsed_s, written, rates, bounds.limits(free_mb), frames)
    return RecordingProgress(
        active=True,
        id=rec_id,
        frames=frames,
        encoding=None if encoding is None else encoding.label,
        lossless=None if encoding is None else encoding.lossless,
        elapsed_s=elapsed_s,
        telemetry_bytes=written.telemetry,
        frames_bytes=written.frames,
        mcap_bytes=written.mcap,
        rate_bytes_per_s=None if rates is None else rates.total_bps,
        frames_bytes_per_s=None if rates is None else rates.frames_bps,
        mb_per_min=None if rates is None else rates.total_bps * 60.0 / 1e6,
        time_left_s=None if left is None else left[0],
        limited_by=None if left is None else left[1],
        basis=f"measured over the recording ({elapsed_s:.1f} s)",
        free_mb=free_mb,
        **_bounds(bounds),
    )


def estimated_progress(
    probe: RateProbe,
    encoding: FrameEncoding | None,
    mcap: bool,
    bounds: Bounds,
    free_mb: float | None,
) -> RecordingProgress:
    """No recording active: how long one with ``encoding`` (None: without frames) can run,
    at the current tick rate and a typical pair's size; the MCAP log holds the frames and
    the telemetry again (counted as their sum)."""
    telemetry_bps = probe.line_bytes * probe.ticks_per_s
    pair_bytes: float | None = None
    basis = "the telemetry's current rate"
    frames_bps = 0.0
    if encoding is not None:
        pair_bytes, basis = probe.pair_bytes(encoding)
        if pair_bytes is None:
            return RecordingProgress(
                active=False, frames=True, encoding=encoding.label, lossless=encoding.lossless,
                basis=basis, free_mb=free_mb, **_bounds(bounds),
            )  # fmt: skip
        frames_bps = pair_bytes * probe.pairs_per_s
    rates = Rates(telemetry_bps, frames_bps, telemetry_bps + frames_bps if mcap else 0.0)
    seconds, bound = time_left(0.0, Written(), rates, bounds.limits(free_mb), encoding is not None)
    return RecordingProgress(
        active=False,
        frames=encoding is not None,
        encoding=None if encoding is None else encoding.label,
        lossless=None if encoding is None else encoding.lossless,
        rate_bytes_per_s=rates.total_bps,
        frames_bytes_per_s=frames_bps,
        mb_per_min=rates.total_bps * 60.0 / 1e6,
        time_left_s=seconds,
        limited_by=bound,
        basis=basis,
        pair_bytes=pair_bytes,
        pairs_per_s=probe.pairs_per_s if encoding is not None else None,
        free_mb=free_mb,
        **_bounds(bounds),
    )


def _bounds(bounds: Bounds) -> dict[str, float]:
    return {
        "max_s": bounds.max_s,
        "max_mb": bounds.max_mb,
        "max_frames_mb": bounds.max_frames_mb,
        "min_free_mb": bounds.min_free_mb,
    }
