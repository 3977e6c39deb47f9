"""Replay the stereo pairs of an MCAP log (:mod:`app.streams.mcap_log`) as a frame source.

``aar-dock track --left REC.mcap`` and ``serve --source mcap:REC.mcap``: the images of
``/camera/left/image`` and ``/camera/right/image`` paired by log time, with the pair's own
frame number and times from ``/camera/stereo_frame`` (else the log time, s), and the exact
calibration of the run (the ``aar-dock`` metadata record), so a replay gives the live poses.
A file cut by a crash is read up to its last complete record.

A log is outside input, so everything read from it is bounded and checked
(:class:`ReplayLimits`): the reader's limits (:class:`~app.streams.mcap_log.ReadLimits`), at
most ``max_pending`` unpaired images and ``max_pending_bytes`` waiting for their other side
(the oldest dropped and counted in ``stats.dropped_skew``), an image's size read from its
header before decoding (at most ``max_image_pixels``), the frame times a JSON object of finite
numbers, the images decoded with Foxglove's own ``CompressedImage`` schema (never the file's),
and the calibration passed through the plausibility checks of ``PUT /calibration``
(:mod:`app.calibration.plausibility`). A file that cannot be opened is a
:class:`~app.streams.frames.SourceError`; corruption met after the first pair is a
:class:`~app.streams.frames.SourceCorrupt` (one line, never a normal end).
"""

from __future__ import annotations

import json
import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from app.geometry.calibration import CalibrationError, StereoCalibration
from app.model.frames import StereoFrame
from app.streams.frames import RecordedPairs, SourceCorrupt, SourceError, SourceStats
from app.streams.image_header import ImageHeaderError, env_max_image_pixels, peek_header
from app.streams.mcap_log import (
    TOPIC_FRAME,
    McapLogError,
    McapMessage,
    ReadLimits,
    iter_messages,
    read_metadata,
)
from app.vision.drogue import DrogueProfile, DrogueProfileError
from app.vision.io import decode_image
from app.vision.preprocess import ImageError

IMAGE_TOPICS = {"/camera/left/image": "left", "/camera/right/image": "right"}
IMAGE_SCHEMA = "foxglove.CompressedImage"
MiB = 1 << 20


@dataclass(frozen=True)
class ReplayLimits:
    """Bounds of one replay: the reader's (``read``), the unpaired images held (count and
    bytes), the frame-time records held, and an image's pixels (``None``: the
    ``AAR_MAX_IMAGE_PIXELS`` of the environment, 40 Mpx by default)."""

    read: ReadLimits = field(default_factory=ReadLimits)
    max_pending: int = 16
    max_pending_bytes: int = 192 * MiB
    max_frame_infos: int = 256
    max_image_pixels: int | None = None


@dataclass(frozen=True)
class FrameTimes:
    """A ``/camera/stereo_frame`` record, checked: the pair's number and times (s)."""

    seq: int | None = None
    t_s: float | None = None
    t_left_s: float | None = None
    t_right_s: float | None = None
    exposure_ms: float | None = None


def is_mcap(path: str | Path) -> bool:
    """A file named ``*.mcap`` (what the sources treat as an MCAP log)."""
    return str(path).lower().endswith(".mcap")


def mcap_calibration(
    path: str | Path, limits: ReadLimits | None = None
) -> StereoCalibration | None:
    """The exact calibration stored in an MCAP log's metadata, or ``None``; refused
    (:class:`SourceError` quoting the same message as ``PUT /calibration``) unless it passes
    :func:`app.calibration.plausibility.validated`."""
    from app.calibration.plausibility import DEFAULT_MAX_PIXELS, validated
    from app.streams.frame_log import exact_calibration

    try:
        meta = read_metadata(path, limits or ReadLimits())
    except McapLogError as exc:
        raise SourceError(str(exc)) from None
    text = meta.get("calibration")
    if not text:
        return None
    try:
        data = json.loads(text)
        validated(data, DEFAULT_MAX_PIXELS)
        return exact_calibration(data)
    except CalibrationError as exc:
        raise SourceError(f"{str(path)!r}: calibration in its metadata refused: {exc}") from None
    except (ValueError, TypeError, KeyError, RecursionError) as exc:
        raise SourceError(f"{str(path)!r}: bad calibration in its metadata ({exc})") from None


def mcap_drogue(path: str | Path) -> DrogueProfile | None:
    """The drogue profile in an MCAP log's metadata (``drogue``), or ``None``."""
    try:
        text = read_metadata(path).get("drogue")
    except McapLogError as exc:
        raise SourceError(str(exc)) from None
    if not text:
        return None
    try:
        return DrogueProfile.from_json(text, f"{str(path)!r}: its drogue metadata")
    except DrogueProfileError as exc:
        raise SourceError(str(exc)) from None


@cache
def _image_decoder() -> Callable[[bytes], object]:
    """``foxglove.CompressedImage`` from Foxglove's own schema (the file's is never parsed)."""
    from foxglove.messages import CompressedImage
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory

    s = CompressedImage.get_schema()
    decoder = DecoderFactory().decoder_for(
        "protobuf", Schema(id=1, name=s.name, encoding=s.encoding, data=bytes(s.data))
    )
    assert decoder is not None
    return decoder


def image_bytes(msg: McapMessage) -> bytes:
    """The encoded image of a ``foxglove.CompressedImage`` message (:class:`SourceError`)."""
    where = f"{msg.topic} at log time {msg.log_time_ns}"
    if msg.encoding != "protobuf" or msg.schema_name != IMAGE_SCHEMA:
        raise SourceError(
            f"{where}: not a protobuf {IMAGE_SCHEMA} "
            f"({msg.encoding or 'no encoding'}, {msg.schema_name or 'no schema'})"
        )
    try:
        data = getattr(_image_decoder()(msg.data), "data", None)
    except Exception as exc:  # protobuf's DecodeError and kin: the bytes are not the message
        raise SourceError(f"{where}: corrupt {IMAGE_SCHEMA} ({type(exc).__name__})") from None
    if not isinstance(data, bytes) or not data:
        raise SourceError(f"{where}: no image")
    return data


def frame_times(data: bytes, where: str) -> FrameTimes:
    """A ``/camera/stereo_frame`` record: a JSON object of finite numbers (or nulls)."""
    try:
        obj = json.loads(data)
    except (ValueError, RecursionError) as exc:  # not UTF-8, not JSON, nested too deep
        raise SourceError(f"{where}: not a JSON object ({type(exc).__name__})") from None
    if not isinstance(obj, dict):
        raise SourceError(f"{where}: not a JSON object (a {type(obj).__name__})")

    def number(key: str) -> float | None:
        v = obj.get(key)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise SourceError(f"{where}: {key} is not a finite number ({str(v)[:32]})")
        return float(v)

    seq = obj.get("seq")
    if seq is not None and (isinstance(seq, bool) or not isinstance(seq, int) or seq < 0):
        raise SourceError(f"{where}: seq is not a non-negative integer ({str(seq)[:32]})")
    if seq is not None and seq >= 2**62:
        raise SourceError(f"{where}: seq {seq} is out of range")
    return FrameTimes(
        seq, number("t_s"), number("t_left_s"), number("t_right_s"), number("exposure_ms")
    )


def checked_image(data: bytes, what: str, max_pixels: int) -> np.ndarray:
    """An image checked on its header (size, format) before OpenCV decodes it."""
    try:
        header = peek_header(data)
    except ImageHeaderError as exc:
        raise SourceError(f"{what}: {exc}") from None
    if header.pixels > max_pixels:
        raise SourceError(
            f"{what}: {header.describe()} exceeds the limit of {max_pixels / 1e6:.4g} Mpx "
            "(AAR_MAX_IMAGE_PIXELS); refused before decoding"
        )
    try:
        return decode_image(data, what)  # the one decoder (app.vision.io)
    except ImageError as exc:
        raise SourceError(f"cannot decode {what} ({exc})") from None


class PendingPairs:
    """Images waiting for their other side, by log time: at most ``max_pending`` log times
    and ``max_pending_bytes``; the oldest dropped first (``dropped``: images dropped)."""

    def __init__(self, max_pending: int, max_bytes: int) -> None:
        self.max_pending, self.max_bytes = max_pending, max_bytes
        self._parts: OrderedDict[int, dict[str, bytes]] = OrderedDict()
        self.bytes = 0
        self.dropped = 0

    def __len__(self) -> int:
        return len(self._parts)

    def add(self, log_ns: int, side: str, data: bytes) -> tuple[bytes, bytes] | None:
        """The (left, right) images once both sides of ``log_ns`` arrived, else ``None``."""
        part = self._parts.get(log_ns)
        if part is None:
            part = self._parts[log_ns] = {}
        if side in part:  # the same side twice: the newer replaces it
            self.bytes -= len(part[side])
            self.dropped += 1
        part[side] = data
        self.bytes += len(data)
        if len(part) == 2:
            del self._parts[log_ns]
            self.bytes -= len(part["left"]) + len(part["right"])
            return part["left"], part["right"]
        while len(self._parts) > self.max_pending or (
            self.bytes > self.max_bytes and len(self._parts) > 1
        ):
            _, old = self._parts.popitem(last=False)
            self.bytes -= sum(len(v) for v in old.values())
            self.dropped += len(old)
        return None


class McapRecordingSource(RecordedPairs):
    """The pairs of an MCAP log in order (``read_next``/``restart``/``close``, as
    :class:`~app.streams.frame_log.FrameRecordingSource`). ``read_next`` raises
    :class:`SourceCorrupt` for corruption met after the first pair, again on each later
    call (the error is final)."""

    def __init__(self, path: str | Path, limits: ReplayLimits | None = None) -> None:
        self.path = Path(path)
        self.spec = f"video:{self.path}"
        self.limits = limits or ReplayLimits()
        self.max_pixels = self.limits.max_image_pixels or env_max_image_pixels()
        if not self.path.is_file():
            raise SourceError(f"no such MCAP file: {str(path)!r}")
        self.calibration = mcap_calibration(self.path, self.limits.read)
        self.stats = SourceStats()
        self.error: str | None = None
        self._closed = threading.Event()
        self._it: Iterator[StereoFrame] | None = None
        first = self._pairs(self._closed)
        try:
            self._first: StereoFrame | None = next(first)
        except StopIteration:
            raise SourceError(f"MCAP {str(path)!r} holds no stereo pair") from None
        self._it = first

    def _pairs(self, closed: threading.Event) -> Iterator[StereoFrame]:
        lim = self.limits
        pending = PendingPairs(lim.max_pending, lim.max_pending_bytes)
        info: OrderedDict[int, bytes] = OrderedDict()  # parsed when its pair is complete
        n = 0
        try:
            for msg in iter_messages(self.path, [*IMAGE_TOPICS, TOPIC_FRAME], lim.read):
                if closed.is_set():
                    return
                if msg.topic == TOPIC_FRAME:
                    info[msg.log_time_ns] = msg.data
                    while len(info) > lim.max_frame_infos:
                        info.popitem(last=False)
                    continue
                dropped = pending.dropped
                pair = pending.add(msg.log_time_ns, IMAGE_TOPICS[msg.topic], image_bytes(msg))
                if pending.dropped > dropped:
                    self.stats.add("dropped_skew", pending.dropped - dropped)
                if pair is None:
                    continue
                at = f"at log time {msg.log_time_ns}"
                left = checked_image(pair[0], f"the left image {at}", self.max_pixels)
                right = checked_image(pair[1], f"the right image {at}", self.max_pixels)
                raw = info.pop(msg.log_time_ns, None)
                times = FrameTimes() if raw is None else frame_times(raw, f"{TOPIC_FRAME} {at}")
                yield _frame(left, right, times, msg, n)
                n += 1
        except McapLogError as exc:
            raise SourceError(str(exc)) from None

    def read_next(self) -> StereoFrame | None:
        if self.error is not None:
            raise SourceCorrupt(self.error)
        if self._first is not None:
            frame, self._first = self._first, None
            return frame
        if self._it is None:
            return None
        try:
            return next(self._it)
        except StopIteration:
            self._it = None
            return None
        except SourceError as exc:
            self._it = None
            where = "" if str(self.path) in str(exc) else f"MCAP {str(self.path)!r}: "
            self.error = f"{where}{exc}"
            raise SourceCorrupt(self.error) from None

    def restart(self) -> None:
        self._closed.set()  # a reader still running in another thread stops at its next message
        self._closed = threading.Event()
        self._it = self._pairs(self._closed)
        self._first = None

    def close(self) -> None:
        self._closed.set()
        self._it = None
        self._first = None


def _frame(
    left: np.ndarray, right: np.ndarray, times: FrameTimes, msg: McapMessage, n: int
) -> StereoFrame:
    return StereoFrame(
        left=left,
        right=right,
        t_s=times.t_s if times.t_s is not None else msg.log_time_ns / 1e9,
        seq=times.seq if times.seq is not None else n,
        t_left_s=times.t_left_s,
        t_right_s=times.t_right_s,
        exposure_ms=times.exposure_ms,
    )
